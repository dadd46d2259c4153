"""The controller: one ``tick(state) -> ControlOutput`` per control period, ROS-free.

It owns the tasks, the FSM and the whole-body QP, and composes the parts the FSM talks to: the
active contact set (contact_set.ContactSet), the F/T monitor (ft_monitor.FtMonitor), impact
detection (impact.ImpactMonitor), the line-contact locator (line_contact.LineContactLocator), and
failure handling and recovery (recovery.Recovery: the brace, lost contacts, QP failures, the
fallback). A tick:

1. Pinocchio terms for the measured state (:class:`WholeBodyQP.update`);
2. F/T forces rotated to the world and low-pass filtered (guarded motion);
3. the FSM runs (it may change task targets, ask for contact ramps / releases / additions and
   gripper commands);
4. force ramps advance; the QP is built and solved; torques recovered;
5. qp mode: torques; compliance mode: PWM duty from eq. (1) with the QP torques as feed-forward.

A QP failure is counted, the problem saved (``qp.failure_dir``, up to ``qp.max_saved_failures``
files), the FSM goes to ``failure`` (hold tasks at the configuration at failure) and the command
comes from the fallback chain: the QP with the hold tasks when it solves; else the same problem
without torque / joint limits and dampers (cones and grips kept), then with its equality rows
only (dynamics, held contacts; a KKT solve that always has an answer), with the torques
saturated at the effort limits; else a joint PD scaled by the joint-space inertia plus the last
good feed-forward. Never NaN, never garbage.
"""
from __future__ import annotations

import math
import pathlib
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from climb_core.contact import HANDS, Hold, Stance, Transition, WholeBodyPlan

from .compliance import ComplianceLaw, MotorArrays, PwmGainArrays
from .constraints import ActiveContact, CollisionAvoidance, contact_from_hold
from .contact_set import ContactSet
from .estimator import RobotState
from .fsm import Fsm, FsmTable, limb_kind, load_fsm_table
from .ft_monitor import FtMonitor, ft_sensor_frames
from .impact import ImpactMonitor
from .line_contact import LineContactLocator, LineEstimate
from .params import ControllerParams
from .qp import QpFailure
from .recovery import Brace, Recovery
from .reference import PathReference
from .tracking import PathTracker
from .tasks import BaseOrientationTask, ComTask, FrameTask, PostureTask, Task
from .wholebody import WholeBodyQP, WholeBodyResult

QP_OK, QP_FAILED, QP_NOT_RUN = 0, 1, 2


@dataclass
class GripperRequest:
    hand: str  # left_hand | right_hand
    command: str  # open | close | position
    position: float = 0.0  # [-] 0 open .. 1 closed (position only)
    time: float = 0.0  # [s] controller time of the request


@dataclass
class TickStatus:
    time: float  # [s]
    fsm_state: str
    mode: str
    transition_index: int
    active_contacts: tuple[str, ...]
    task_names: tuple[str, ...]
    task_errors: tuple[float, ...]  # [m or rad]
    qp_status: int  # QP_OK | QP_FAILED | QP_NOT_RUN
    qp_solve_time_ms: float  # [ms]
    tick_time_ms: float  # [ms]
    qp_failures: int
    fallback: bool  # command from the fallback PD
    replan_needed: bool


@dataclass
class ControlOutput:
    time: float  # [s]
    stamp_ns: int  # [ns] stamp of the state this answers
    joint_names: tuple[str, ...]
    mode: str  # torque | pwm
    values: np.ndarray  # [N m] or duty [-]
    tau: np.ndarray  # [N m] torque behind the command (QP or fallback)
    grippers: list[GripperRequest]
    status: TickStatus
    contact_wrenches: dict[str, np.ndarray] = field(default_factory=dict)  # limb -> (6,) world [N, N m]


@dataclass
class ControllerEvent:
    time: float  # [s]
    kind: str
    values: dict[str, Any]


class HoldRefused(RuntimeError):
    """:meth:`Controller.hold_plan` cannot hold now (the message says why)."""


class PlanRefused(RuntimeError):
    """:meth:`Controller.set_plan` cannot take a plan now (the message says why)."""


#: FSM states a new plan may start from: nothing half done (a transition in progress is finished,
#: or abandoned with :meth:`Controller.hold_plan`, first)
PLAN_READY_STATES = ("idle", "hold", "replan_needed")


def _limb_links(robot, limb_frame: str) -> set[str]:
    """Links (collision geometry parents) in the subtree of the limb frame's parent joint."""
    model = robot.model
    root = model.frames[model.getFrameId(limb_frame)].parentJoint
    subtree = set(model.subtrees[root])
    return {model.frames[obj.parentFrame].name for obj in robot.collision_model.geometryObjects
            if obj.parentJoint in subtree}


class Controller:
    """Whole-body QP + contact FSM + compliance controller for one robot in one environment."""

    def __init__(self, robot, params: ControllerParams, environment=None, fsm_table: FsmTable | None = None):
        self.robot = robot
        self.params = params
        self.environment = environment
        self.model: pin.Model = robot.model
        self.joint_names = tuple(robot.joint_names)
        self.na = self.model.nv - 6
        self.effort_limits = robot.effort_limits()
        self._neg_effort_limits = -self.effort_limits
        collision = self._make_collision(robot, environment) if environment is not None else None
        self.wb = WholeBodyQP(self.model, self.effort_limits, params, collision)
        self.ref_data = self.model.createData()
        self.table = fsm_table if fsm_table is not None else load_fsm_table(params.fsm_table)
        self.fsm = Fsm(self.table)
        self.limbs = robot.config.limbs
        self.limb_frame_ids = {name: robot.frame_id(limb.surface.frame) for name, limb in self.limbs.items()}
        self.limb_surface = {name: np.asarray(limb.surface.T_frame_surface, float) for name, limb in self.limbs.items()}
        self.limb_links = {name: _limb_links(robot, limb.surface.frame) for name, limb in self.limbs.items()}
        self.ft = FtMonitor(ft_sensor_frames(robot.model, robot.config.ft_sensors),
                            [(limb, spec.ft_sensor) for limb, spec in self.limbs.items()], params.guarded,
                            params.control_period_s)
        self.impact = ImpactMonitor(params.impact, params.control_period_s)
        self.line_locator = LineContactLocator(
            robot.model, {limb: (spec.ft_sensor, self.ft.frames[spec.ft_sensor]) for limb, spec in self.limbs.items()
                          if spec.ft_sensor in self.ft.frames}, params.line_contact, params.control_period_s)
        gains = PwmGainArrays.from_robot_config(robot.config, self.joint_names)
        scale = params.compliance.gain_scale
        self.compliance = ComplianceLaw(PwmGainArrays(gains.kp * scale, gains.kd * scale),
                                        MotorArrays.from_robot_config(robot.config, self.joint_names),
                                        params.compliance.current_margin)
        self.limb_joint_v = {name: np.array([robot.joint_index_v(j) for j in limb.joints if j in self.joint_names])
                             for name, limb in self.limbs.items()}
        # tasks
        t = params.tasks
        nv = self.model.nv
        self.com_task = ComTask(t.com)
        self.posture_task = PostureTask(t.posture, nv)
        self.base_task = BaseOrientationTask(t.base_orientation, nv)
        self.contact_body_tasks = {
            name: FrameTask(t.contact_body, self.limb_frame_ids[name], self.limb_surface[name][:3, 3],
                            name=f"contact_body:{name}") for name in self.limbs}
        self.active_tasks: list[Task] = [self.com_task, self.posture_task, self.base_task]
        # contacts (owned here)
        self.contact_set = ContactSet()
        # plan
        self.plan: WholeBodyPlan | None = None
        self.plan_pending = False
        self._finished = False
        self.transition_index = -1
        self.transition: Transition | None = None
        self.moving_limb = ""
        self.moving_kind = ""  # fsm.limb_kind of the moving limb and its hold (hand / palm / foot)
        self.target_surface = ""
        self.path = PathTracker(self)  # the transition's path -> task targets, the guarded search
        self.guard_off: set[tuple[str, str]] = set()
        self._disabled_key: tuple | None = None
        self._disabled_cache: frozenset[tuple[str, str]] = frozenset()
        self.replan_needed = False
        self.replan_reason = ""  # why the FSM is in replan_needed: contact_offset | no_contact
        #: the last placement's surface offset: (limb, surface, world translation [m] of the surface
        #: from where the plan had it: along the approach, plus across it where a line contact was
        #: located on it; signed distance along the approach [m], < 0 early)
        self.placement_offset: tuple[str, str, np.ndarray, float] | None = None
        # outputs / bookkeeping
        self.grippers_out: list[GripperRequest] = []
        self._queued_grippers: list[GripperRequest] = []  # requested between two ticks (hold_plan)
        self.events: list[ControllerEvent] = []
        self.dampers_released = 0  # ticks solved only after releasing dampers (within the security distance, or pushing)
        #: the plan index to run again once a contact lost in a brace is put back (replace_lost)
        self._replacing: int | None = None
        self._released_pairs: list[tuple[str, str]] = []
        self.recovery = Recovery(self)  # impacts, the brace, QP failures and the fallback
        self.last_result: WholeBodyResult | None = None
        self._qdd_held: np.ndarray | None = None  # [m/s^2, rad/s^2] last solved qdd (latency prediction)
        self.state: RobotState | None = None
        self.time = 0.0
        self.tick_count = 0

    # ------------------------------------------------------------------ construction helpers
    def _make_collision(self, robot, environment) -> CollisionAvoidance:
        c = self.params.collision
        geometries: dict[str, list] = {}
        for obj in robot.collision_model.geometryObjects:
            link = robot.model.frames[obj.parentFrame].name
            geometries.setdefault(link, []).append((obj.geometry, obj.parentJoint, obj.placement))
        roles = set(c.env_roles)
        objects = [(name, geom, tf) for name, geom, tf in environment.collision_objects()
                   if environment.surfaces[name].role in roles]
        return CollisionAvoidance(geometries, c.env_links, objects, c.self_pair_tuples, c.influence_distance,
                                  c.security_distance, c.damping, c.broadphase_margin, c.max_braking,
                                  c.broadphase_slack)

    # ------------------------------------------------------------------ public API
    def reset(self, state: RobotState, stance: Stance | None = None) -> None:
        """Start from ``state`` with the holds of ``stance`` active (feet only when None)."""
        self.state = state
        self.time = state.time
        self.wb.update(state.q, state.v)
        self.contact_set.clear()
        if stance is not None:
            for hold in stance.holds:
                self._activate(hold.limb, hold, engage=False)
        self.fsm = Fsm(self.table)
        self.plan = None
        self.plan_pending = False
        self.transition = None
        self.transition_index = -1
        self.moving_limb = ""
        self.moving_kind = ""
        self.replan_needed = False
        self.replan_reason = ""
        self.placement_offset = None
        self.recovery.reset()
        self._qdd_held = None
        self.guard_off.clear()
        self.ft.update(self.wb.data.oMf, state.ft)
        self._replacing = None
        self.impact = ImpactMonitor(self.params.impact, self.params.control_period_s)
        self.impact.mute_until(state.time + self.params.impact.startup_s)  # the filters start; the feet settle
        self.fsm.begin(self)

    def set_plan(self, plan: WholeBodyPlan) -> None:
        """Execute ``plan`` from the next tick; PlanRefused while a transition is in progress
        (its state would lose the transition it runs) or in failure (reset first)."""
        state = self.fsm.state
        if state not in PLAN_READY_STATES:
            raise PlanRefused(f"the controller is in {state!r}: a plan starts from "
                              f"{', '.join(PLAN_READY_STATES)} (hold first: controller/hold)")
        self.plan = plan
        self.plan_pending = True
        self._replacing = None
        self.transition_index = -1
        self.transition = None
        self.replan_needed = False  # idle / hold / replan_needed raise `plan` on their next run
        self.replan_reason = ""

    def hold_plan(self) -> str:
        """Abandon the plan now and hold the active contacts where they are (an external cancel):
        the FSM goes to ``hold`` (event ``hold``) from any state but ``failure``; a contact being
        released keeps its full load (ramp cancelled), a contact being engaged finishes its ramp,
        a free limb stays where it is (no contact-body task), a hand whose gripper was opening
        closes again. A new plan (:meth:`set_plan`) starts from there. Returns the state left;
        raises HoldRefused with the reason (no state yet, in failure, no table row)."""
        if self.state is None:
            raise HoldRefused("no robot state yet (the controller has not ticked)")
        before = self.fsm.state
        if before == "failure":
            raise HoldRefused("in failure: the fallback already holds; send the reset event first")
        if self.table.next_state(before, "hold", self.moving_limb, self.moving_kind) is None:
            raise HoldRefused(f"the FSM table has no row for the event hold from {before!r}")
        contacts, holds = dict(self.contacts), dict(self.holds)
        limb = self.moving_limb
        self.plan = None
        self.plan_pending = False
        self._replacing = None
        self.fsm.fire(self, "hold")  # the state left tears down (stiffness, a foot's unload, ...)
        self.contact_set.restore(contacts, holds)  # the contact set stays what it was
        self.contact_set.cancel(("release",))
        if before == "open_gripper" and limb in HANDS and limb in self.contacts:
            self.queue_gripper(limb, "close")
        self.transition = None
        self.transition_index = -1
        self.moving_limb = ""
        self.moving_kind = ""
        self.target_surface = ""
        self.replan_needed = False
        self.hold_here()
        self.emit("plan_abandoned", state=before, limb=limb, contacts=sorted(self.contacts))
        return before

    def reset_failure(self) -> bool:
        """Leave the failure state (external `reset` event)."""
        self.recovery.clear_fallback()
        return self.fsm.fire(self, "reset")

    # ------------------------------------------------------------------ tick
    def tick(self, state: RobotState) -> ControlOutput:
        t0 = time.perf_counter()
        if self.params.actuation_latency_s > 0.0:  # the command acts from t + L: compute it for then
            state = self.predict(state, self.params.actuation_latency_s)
        self.state = state
        self.time = state.time
        self.grippers_out, self._queued_grippers = self._queued_grippers, []
        self.wb.update(state.q, state.v)
        self.ft.update(self.wb.data.oMf, state.ft)
        hit = self.impact.update(self.time, self.ft, state.v[6:],
                                 self._qdd_held[6:] if self._qdd_held is not None else None)
        if hit is not None:
            self.recovery.on_impact(hit)
        if self.params.line_contact.enabled:
            # a free limb's reading is its sensor's bias; a placement on a round rung is located,
            # not from the wrenches of a blow (its tick, a brace, the cooldown after it) nor while
            # the QP fails (the torques then are the fallback's, not a balance on the planned line)
            self.line_locator.observe(state.ft, [limb for limb in self.limbs if not self.contact_set.has(limb)])
            r = self.recovery
            if (self.line_locator.pending and hit is None and r.brace is None and not self.impact.quiet(self.time)
                    and r.failing_since is None and not r.fallback_active):
                for estimate in self.line_locator.update(self.time, self.wb.data.oMf, state.ft):
                    self._move_contact_line(estimate)
        self.fsm.step(self)
        self.contact_set.advance(self.time)
        contacts = self.contact_set.ordered()
        disabled = self._disabled_pairs()
        qp_status, solve_ms = QP_NOT_RUN, 0.0
        result = None
        try:
            try:
                result = self.wb.solve(contacts, self.active_tasks, disabled)
            except QpFailure:
                result = self._solve_without_blocked_dampers(contacts, disabled)
                if result is None:
                    raise
            qp_status, solve_ms = QP_OK, result.solution.solve_time * 1e3
        except QpFailure as failure:
            qp_status = QP_FAILED
            if self.recovery.qp_failed(failure):
                # one retry with the hold tasks (and contact set) the failure state just set
                contacts = self.contact_set.ordered()
                try:
                    result = self.wb.solve(contacts, self.active_tasks, self._disabled_pairs())
                except QpFailure:
                    result = None
        self.recovery.qp_solved(result is not None and qp_status == QP_OK)
        fallback = False
        if result is None:  # the hold QP fails too: relaxed QP (no torque / joint limits), then
            fallback = True  # the equality-only KKT solve; torques saturated below. Bracing: the
            # joint PD around the configuration at the impact instead (measured on 7 kg balls:
            # the relaxed solve's saturated torques threw the robot off in two cases of three)
            for relaxed in ((self.wb.solve_relaxed, self.wb.solve_equalities) if self.recovery.brace is None else ()):
                try:
                    candidate = relaxed(contacts, self.active_tasks)
                except (QpFailure, np.linalg.LinAlgError):
                    continue
                if np.all(np.isfinite(candidate.tau)):
                    result = candidate
                    break
        self._qdd_held = result.qdd if result is not None and not fallback else None
        if result is not None and not fallback:
            tau = result.tau
            self.recovery.tau_ff = tau.copy()
            self.last_result = result
            for limb, c in result.contacts.items():
                self.contact_set.last_loads[limb] = c.wrench_in_world
        elif result is not None:
            tau = result.tau
        else:
            tau = self.recovery.fallback_torque(state)
        tau = np.minimum(np.maximum(tau, self._neg_effort_limits), self.effort_limits)  # == np.clip, cheaper
        if self.params.mode == "compliance":
            values = self._pwm(state, tau)
            mode = "pwm"
        else:
            values = tau
            mode = "torque"
        if not np.isfinite(values).all():  # never send garbage
            values = np.zeros(self.na)
        self.tick_count += 1
        tick_ms = (time.perf_counter() - t0) * 1e3
        status = TickStatus(
            state.time, self.fsm.state, self.params.mode, max(self.transition_index, 0),
            self.contact_set.limbs(),
            tuple(t.name for t in self.active_tasks), tuple(t.last_error for t in self.active_tasks),
            qp_status, solve_ms, tick_ms, self.qp_failures, fallback, self.replan_needed)
        wrenches = {limb: c.wrench_in_world for limb, c in result.contacts.items()} if result is not None else {}
        return ControlOutput(state.time, state.stamp_ns, self.joint_names, mode, values, tau,
                             list(self.grippers_out), status, wrenches)

    def _solve_without_blocked_dampers(self, contacts: list[ActiveContact], disabled: frozenset):
        """Retries after an infeasible QP: a damper can demand a separating acceleration the held
        contacts forbid (both knees within 1-5 mm of rung 2 while both feet hold; a knee 6 mm
        under the next rung while one foot carries the robot on a 32 cm-spaced ladder). First the
        pairs already within the security distance are released for this tick, then, if that is
        not enough, also every pair whose damper demands a separating acceleration (lower > 0); event
        ``dampers_released``. Every other constraint (dynamics, contacts, cones, torque limits)
        stays: this is a better answer than the relaxed fallback, which drops all of them but the
        equalities. None if neither helps."""
        ds = self.params.collision.security_distance
        rows = [r for r in self.wb.last_dampers() if "|" in r.name]
        within = [tuple(r.name.split("|", 1)) for r in rows if r.distance <= ds + 1e-9]
        pushing = [tuple(r.name.split("|", 1)) for r in rows if r.lower > 0.0]
        widened = sorted(set(within) | set(pushing))
        for blocked in (within, widened if len(widened) > len(within) else []):
            if not blocked:
                continue
            try:
                result = self.wb.solve(contacts, self.active_tasks, frozenset(disabled) | frozenset(blocked))
            except QpFailure:
                continue
            self.dampers_released += 1
            if self._released_pairs != blocked:
                self._released_pairs = blocked
                self.emit("dampers_released", pairs=[f"{a}|{b}" for a, b in blocked])
            return result
        return None

    # ------------------------------------------------------------------ compliance
    def _pwm(self, state: RobotState, tau: np.ndarray) -> np.ndarray:
        """Eq. (1) toward the posture reference; with an actuation latency L the state is the one
        predicted at t + L (:meth:`predict`) and the reference is taken at t + L too."""
        ff = tau if self.params.compliance.feedforward == "qp" else None
        q_ref, v_ref = self.posture_task.q_joints, self.posture_task.v_joints
        latency = self.params.actuation_latency_s
        if latency > 0.0:
            q_ref = q_ref + latency * v_ref
        return self.compliance.duty(q_ref, state.q[7:], v_ref, state.v[6:], ff)

    def predict(self, state: RobotState, horizon: float) -> RobotState:
        """The state ``horizon`` [s] after ``state`` at the last solved QP's accelerations
        (constant; none before the first solve or after a fallback): v + a L and q integrated on
        the configuration manifold by v L + a L^2 / 2. Time, stamp and F/T stay the measured ones."""
        a = self._qdd_held
        dq = state.v * horizon if a is None else state.v * horizon + (0.5 * horizon * horizon) * a
        v = state.v if a is None else state.v + horizon * a
        return RobotState(state.time, pin.integrate(self.model, state.q, dq), v, state.ft, state.stamp_ns)

    # ------------------------------------------------------------------ F/T (FtMonitor)
    def tare_ft(self, limb: str) -> None:
        self.ft.tare(limb)
        self.line_locator.tare(limb, self.wb.data.oMf)

    def contact_threshold(self, limb: str) -> float:
        """[N] the F/T force change that means contact (FtMonitor.threshold)."""
        return self.ft.threshold(limb)

    def ft_force_change(self, limb: str) -> float:
        """Contact force [N] the limb's F/T has seen since the tare, against its approach
        direction when one is known (FtMonitor.change)."""
        return self.ft.change(limb, self.path.approach.get(limb))

    def search_stalled(self, limb: str) -> bool:
        """Search: the limb lags its creeping target by ``guarded.stall_lag`` along the approach
        (something holds it back) and the slow-filtered F/T confirms a push (FtMonitor)."""
        g, creep = self.params.guarded, self.path.creep_dir
        if g.stall_lag <= 0 or limb != self.moving_limb or creep is None or not np.any(creep):
            return False
        task = self.contact_body_tasks[limb]
        lag = float(creep @ (task.T_world_target.translation - task.current(self.wb.view).translation))
        return lag > g.stall_lag and self.ft.confirms_stall(limb, self.path.approach.get(limb))

    def limb_tilted(self, limb: str) -> bool:
        """A foot on its guarded approach or search turned more than ``guarded.tilt_limit_deg``
        from its task's target orientation: it pivots on something it touches (the joints say so
        before a noisy F/T does). Hands are left out (a grasp's wrist tracks less tightly)."""
        limit = self.params.guarded.tilt_limit_deg
        if limit <= 0.0 or limb != self.moving_limb or self.moving_kind != "foot":
            return False
        task = self.contact_body_tasks[limb]
        R = task.T_world_target.rotation.T @ self.wb.data.oMf[task.frame_id].rotation
        # the rotation angle from the trace (cheaper than log3 per tick)
        cos = min(1.0, max(-1.0, 0.5 * (float(np.trace(R)) - 1.0)))
        return math.degrees(math.acos(cos)) > limit

    def search_travel(self, limb: str) -> float:
        """[m] how far the limb itself has moved past the search's origin (its last planned target)
        along the search direction (0 before the search creeps)."""
        creep, origin = self.path.creep_dir, self.path.creep_origin
        if limb != self.moving_limb or creep is None or origin is None or not np.any(creep):
            return 0.0
        return float(creep @ (self.contact_body_tasks[limb].current(self.wb.view).translation - origin.translation))

    # ------------------------------------------------------------------ contacts (ContactSet)
    @property
    def contacts(self) -> dict[str, ActiveContact]:
        """limb -> the QP's active contact (the ContactSet's, in place)."""
        return self.contact_set.active

    @property
    def holds(self) -> dict[str, Hold]:
        """limb -> the hold each active contact was made from."""
        return self.contact_set.holds

    def has_contact(self, limb: str) -> bool:
        return self.contact_set.has(limb)

    def _activate(self, limb: str, hold: Hold, engage: bool) -> None:
        engage_s = self.params.contacts.engage_ramp_s if engage else 0.0
        self.contact_set.put(limb, hold, self._contact_of(limb, hold), self.time, engage_s)
        self.emit("contact_added", limb=limb, surface=hold.env_surface)

    def _contact_of(self, limb: str, hold: Hold) -> ActiveContact:
        """The QP's contact for ``hold`` at the limb's current pose."""
        c = self.params.contacts
        fid = self.limb_frame_ids[limb]
        torque_limit = c.grasp_torque_limit
        grip = self.robot.config.grip_strength * c.grip_force_fraction
        if hold.bilateral and hold.grip_force_limit > 0:
            grip = hold.grip_force_limit * c.grip_force_fraction
        hold_for_qp = hold if not hold.bilateral else Hold(hold.limb, hold.robot_surface, hold.env_surface,
                                                           hold.points, hold.friction, True, grip)
        push_limit = c.unilateral_force_limit_ft_range * self.robot.config.ft_ranges[self.limbs[limb].ft_sensor][0]
        contact = contact_from_hold(hold_for_qp, fid, self.wb.data.oMf[fid], self.limb_surface[limb],
                                    force_limit=grip if hold.bilateral else push_limit,
                                    torque_limit=torque_limit, min_normal_force=c.min_normal_force,
                                    friction_margin=c.friction_margin,
                                    generators_per_point=c.generators_per_point)
        return contact

    def _locate_line(self, limb: str, hold: Hold) -> None:
        """A sole put on a round rung: its line located from the F/T from now on, while it holds."""
        c = self.contacts.get(limb)
        if not self.params.line_contact.enabled or c is None or not self._is_line_hold(hold):
            return
        self.line_locator.start(limb, self.limb_frame_ids[limb], c.points_in_frame, c.normals_in_world.mean(axis=0),
                                self.wb.data.oMf)

    def _move_contact_line(self, estimate: LineEstimate) -> None:
        """Move a line contact to where the F/T located it, its normals the sole's now (event
        ``contact_line_located``)."""
        limb = estimate.limb
        hold = self.holds.get(limb)
        if hold is None or limb not in self.contacts:
            return
        self.emit("contact_line_located", limb=limb, surface=hold.env_surface, shift=estimate.shift,
                  total=estimate.total, samples=estimate.samples, std=estimate.std)
        shift_world = self.wb.data.oMf[self.limb_frame_ids[limb]].rotation @ estimate.shift_in_frame
        self.contact_set.shift(limb, estimate.shift_in_frame, shift_world, self.params.contacts.friction_margin,
                               self.params.contacts.generators_per_point, normal=estimate.normal_world)
        p = self.placement_offset
        if p is not None and p[0] == limb and p[1] == hold.env_surface:
            # the approach saw the rung along its direction only; the line under the sole says
            # where it is across it (a pitched sole's approach is not the rung's own offset: a
            # rung 3 cm low found 5 mm off along x without this, measured)
            self.placement_offset = (limb, p[1], p[2] + shift_world, p[3])

    def begin_release(self, limb: str) -> None:
        self.line_locator.cancel(limb)
        if self.contact_set.begin_release(limb, self.time, self.params.contacts.release_ramp_s):
            self.emit("release_started", limb=limb)

    def release_done(self, limb: str) -> bool:
        return self.contact_set.release_done(limb, self.time)

    def remove_contact(self, limb: str) -> None:
        self.line_locator.cancel(limb)
        if self.contact_set.remove(limb):
            self.emit("contact_removed", limb=limb)

    def add_contact(self, limb: str) -> None:
        """The moving limb's planned hold, moved to where the limb actually is (rung offsets)."""
        self._measure_placement_offset(limb)
        hold = self._hold_at_actual_pose(limb)
        self._activate(limb, hold, engage=True)
        self._locate_line(limb, hold)
        self.set_guard(limb, hold.env_surface, True)

    def _measure_placement_offset(self, limb: str) -> None:
        """Where the guarded move found the target surface against the plan: the limb's contact
        surface now minus at the end of its planned path, along the approach direction (event
        ``contact_offset``; ``placement_offset``). Nothing without a path (a plan starting with
        the limb free) or an approach direction."""
        a = self.path.approach.get(limb)
        if self.reference is None or a is None or self.transition is None:
            self.placement_offset = None
            return
        planned = self.transition.target_stance.hold(limb)
        _, T_plan = self.path.reference_quantities(self.reference.end, limb)
        T_now = self.contact_body_tasks[limb].current(self.wb.view)
        d = float(a @ (T_now.translation - T_plan.translation))
        offset = d * a
        surface = planned.env_surface if planned is not None else self.target_surface
        self.placement_offset = (limb, surface, offset, d)
        self.emit("contact_offset", limb=limb, surface=surface, distance=d, offset=offset.tolist())

    def contact_off_plan(self, limb: str) -> bool:
        """The limb's placement found its surface farther than ``guarded.replan_offset`` from where
        the plan has it (early or late): the plan's next poses assume the planned surface. Not at
        the plan's last transition (no pose of the plan comes after it)."""
        p = self.placement_offset
        last = self.plan is None or self.transition_index >= len(self.plan.transitions) - 1
        return p is not None and p[0] == limb and abs(p[3]) > self.params.guarded.replan_offset and not last

    def contact_ready(self, limb: str) -> bool:
        return self.contact_set.ready(limb, self.time)

    def _hold_at_actual_pose(self, limb: str) -> Hold:
        planned = self.transition.target_stance.hold(limb) if self.transition is not None else None
        if planned is None:
            planned = self.holds.get(limb)
        if planned is None:
            raise RuntimeError(f"no hold known for {limb}")
        if planned.bilateral or self.reference is None:
            return planned
        fid = self.limb_frame_ids[limb]
        pin.framesForwardKinematics(self.model, self.ref_data, self.reference.end)
        T_plan = self.ref_data.oMf[fid]
        T_now = self.wb.data.oMf[fid]
        # the contact points move with the limb (a rung off its planned place); the normals are
        # the environment's and stay as planned
        T = T_now * T_plan.inverse()
        if self._is_line_hold(planned):
            # a sole on a round rung touches it along the rung's top line, wherever the sole is
            # along the plan: the guarded approach measured how far the rung is along its normal,
            # not where it is across (the limb's own tracking error). The line moves along the
            # normal only.
            n = np.asarray(planned.normals, float).mean(axis=0)
            n /= np.linalg.norm(n)
            shift = n * float(n @ (T_now.translation - T_plan.translation))
            points = tuple(type(p)(np.asarray(p.position, float) + shift, p.normal) for p in planned.points)
        else:
            points = tuple(type(p)(T.act(p.position), p.normal) for p in planned.points)
        return Hold(planned.limb, planned.robot_surface, planned.env_surface, points, planned.friction,
                    planned.bilateral, planned.grip_force_limit)

    def _is_line_hold(self, hold: Hold) -> bool:
        """A unilateral hold on a cylinder (a foot on a round rung): a line contact."""
        env = self.environment
        surface = env.surfaces.get(hold.env_surface) if env is not None else None
        return surface is not None and surface.shape == "cylinder" and not hold.bilateral

    def _disabled_pairs(self) -> frozenset[tuple[str, str]]:
        """(link, surface) pairs without dampers: limbs holding a surface, guards switched off.
        Cached on what it depends on (the same frozenset object while nothing changed)."""
        key = (tuple((limb, hold.env_surface) for limb, hold in self.holds.items() if limb in self.contacts),
               tuple(self.guard_off))
        if key == self._disabled_key:
            return self._disabled_cache
        out = set()
        for limb, surface in key[0]:
            for link in self.limb_links[limb]:
                out.add((link, surface))
        for limb, surface in key[1]:
            for link in self.limb_links[limb]:
                out.add((link, surface))
        self._disabled_key, self._disabled_cache = key, frozenset(out)
        return self._disabled_cache

    def set_guard(self, limb: str, surface: str, on: bool) -> None:
        """Collision dampers between the limb's links and ``surface`` on (True) or off."""
        if on:
            self.guard_off.discard((limb, surface))
        elif surface:
            self.guard_off.add((limb, surface))

    @property
    def reference(self) -> PathReference | None:
        """The path under way (tracking.PathTracker), None when holding."""
        return self.path.reference

    # ------------------------------------------------------------------ recovery (Recovery)
    @property
    def brace(self) -> Brace | None:
        """The brace under way (recovery.Brace), None outside it."""
        return self.recovery.brace

    @property
    def qp_failures(self) -> int:
        return self.recovery.qp_failures

    @property
    def saved_failures(self) -> list[pathlib.Path]:
        return self.recovery.saved_failures

    @property
    def fallback_active(self) -> bool:
        return self.recovery.fallback_active

    # ------------------------------------------------------------------ grippers
    def queue_gripper(self, hand: str, command: str, position: float = 0.0) -> None:
        """A gripper request sent with the next tick's output."""
        self._queued_grippers.append(GripperRequest(hand, command, position, self.time))

    def gripper(self, hand: str, command: str, position: float = 0.0) -> None:
        if hand not in HANDS:
            return
        self.grippers_out.append(GripperRequest(hand, command, position, self.time))
        self.emit("gripper", hand=hand, command=command, position=position)

    # ------------------------------------------------------------------ plan / references
    def next_transition(self) -> Transition | None:
        if self.plan is None:
            return None
        if self.plan_pending:
            self.plan_pending = False
            self.transition_index = 0
        if self.transition is not None and self._finished:
            self.transition_index += 1
        self._finished = False
        if self.transition_index >= len(self.plan.transitions):
            self.transition = None
            self.moving_limb = ""
            self.moving_kind = ""
            return None
        self.transition = self.plan.transitions[self.transition_index]
        self.moving_limb = self.transition.moving_limb
        hold = self.transition.target_stance.hold(self.moving_limb) if self.moving_limb else None
        self.target_surface = hold.env_surface if hold is not None else ""
        # the hold made (add) or broken (remove): a hand's palm push has no gripper states
        made_or_broken = hold if hold is not None else self.holds.get(self.moving_limb)
        self.moving_kind = limb_kind(self.moving_limb, made_or_broken) if self.moving_limb else ""
        self.emit("transition_started", index=self.transition_index, primitive=self.transition.primitive,
                  limb=self.moving_limb)
        return self.transition

    def finish_transition(self) -> None:
        self._track_end()
        self._finished = True
        if self._replacing is not None:  # a lost contact put back: the interrupted transition runs again
            self._finished = False
            self.emit("replace_done", limb=self.moving_limb, transition=self._replacing)
            self._replacing = None
        if self.moving_limb:
            self.set_guard(self.moving_limb, self.target_surface, True)

    def _track_end(self) -> None:
        """Event ``transition_finished``: how far the measured configuration ended from the end of
        the transition's path (base position [m], the joint farthest off [rad])."""
        t, state = self.transition, self.state
        if t is None or state is None or not len(t.path):
            return
        end = np.asarray(t.path[-1], dtype=float)
        err = np.abs(np.asarray(state.q[7:], dtype=float) - end[7:])
        j = int(np.argmax(err))
        self.emit("transition_finished", index=self.transition_index, primitive=t.primitive, limb=t.moving_limb,
                  base_error=float(np.linalg.norm(state.q[:3] - end[:3])), joint_error=float(err[j]),
                  joint=self.joint_names[j])

    def hold_here(self) -> None:
        """Targets = the measured state now (CoM, joints, base orientation); no contact-body task."""
        data = self.wb.data
        q = self.state.q
        self.com_task.set_target(data.com[0].copy())
        self.posture_task.set_target(q[7:].copy())
        self.base_task.set_target(pin.Quaternion(q[3:7]).normalized().toRotationMatrix())
        self._set_contact_body(None)
        self.path.reference = None

    def _set_contact_body(self, limb: str | None) -> None:
        base = [self.com_task, self.posture_task, self.base_task]
        self.active_tasks = base + ([self.contact_body_tasks[limb]] if limb else [])

    # ------------------------------------------------------------------ events
    def emit(self, kind: str, **values: Any) -> None:
        self.events.append(ControllerEvent(self.time, kind, values))

    def events_of(self, kind: str) -> list[ControllerEvent]:
        return [e for e in self.events if e.kind == kind]
