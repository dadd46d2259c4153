"""Failure handling and recovery of the controller: impacts and the brace, a lost contact put
back, QP failures (counted, saved), the fallback hold and leaving it.

:class:`Recovery` is one controller's: the FSM's brace and failure states talk to it
(``ctx.recovery``: fsm.BraceState, fsm.FailureState), the tick reports each QP failure and success
to it (:meth:`Recovery.qp_failed`, :meth:`Recovery.qp_solved`) and takes the fallback torque from
it. It reads and changes the controller's contact set, tasks and plan index through the
controller it belongs to.

:class:`Brace` is the record of one brace (fsm.BraceState drives it through ``begin_brace`` /
``end_brace`` / ``brace_settled`` / ``lost_contacts`` / ``replace_lost`` / ``resume_after_brace``):

- at the start: the state it interrupted, every active contact's reference point in the world
  (from the measured joints and base: what "lost" is measured against), the posture task's
  stiffness and the grasps' force limits (both raised while bracing);
- at the end: those restored, and the impact monitor muted for ``impact.cooldown_s`` (the robot's
  own recovery motion must not read as a second blow).
"""
from __future__ import annotations

import pathlib
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from climb_core.ros_env import project_root

from .estimator import RobotState
from .fsm import limb_kind
from .qp import QpFailure, save_problem

if TYPE_CHECKING:
    from .controller import Controller


@dataclass
class Brace:
    since: float  # [s] sim time of the impact
    interrupted: str  # FSM state the impact interrupted
    anchors: dict[str, np.ndarray]  # limb -> contact reference point at the impact [m, world]
    posture_stiffness: float  # [1/s^2] restored at the end
    force_limits: dict[str, float] = field(default_factory=dict)  # grasp limb -> force limit [N] restored
    displacement: dict[str, float] = field(default_factory=dict)  # limb -> [m] at the check
    lost_holds: dict = field(default_factory=dict)  # limb -> the Hold it lost


def contact_point(oMf, contact) -> np.ndarray:
    """[m] world position of an active contact's reference point (its frame's placement now)."""
    M = oMf[contact.frame_id]
    return M.translation + M.rotation @ contact.reference_in_frame


class Recovery:
    """What the controller does when things go wrong (module docstring)."""

    def __init__(self, controller: "Controller"):
        self.c = controller
        self.brace: Brace | None = None  # the brace under way (fsm.BraceState), None outside it
        self.qp_failures = 0
        self.saved_failures: list[pathlib.Path] = []
        self.failing_since: float | None = None  # [s] first tick of the current run of infeasible QPs
        self.solved_since: float | None = None  # [s] first tick of the current run of solved QPs
        self.fallback_active = False
        self.q_hold: np.ndarray | None = None  # the joint PD's target (failure, brace)
        self.tau_ff = np.zeros(controller.na)  # [N m] the last good QP torques (the PD's feed-forward)

    def reset(self) -> None:
        self.brace = None
        self.fallback_active = False

    # -- the tick's QP outcome
    def qp_failed(self, failure: QpFailure) -> bool:
        """A tick's QP is infeasible: counted and saved; past ``qp.failure_grace_s`` (or the
        brace's ``impact.brace_max_s``) the FSM gets ``qp_failure``. True when the tick should
        retry with the hold tasks the failure state set (outside the grace, or in failure)."""
        c = self.c
        self.on_failure(failure)
        self.solved_since = None
        if self.failing_since is None:
            self.failing_since = c.time
        in_grace = c.time - self.failing_since < c.params.qp.failure_grace_s - 1e-9
        if self.brace is not None:  # a blow can leave no feasible QP for a while: bracing rides it out
            in_grace = in_grace or c.time - self.brace.since < c.params.impact.brace_max_s
        if c.fsm.state != "failure" and not in_grace:
            c.fsm.fire(c, "qp_failure")
        return not in_grace or c.fsm.state == "failure"

    def qp_solved(self, solved: bool) -> None:
        """The tick ended with a solved QP (True) or without one."""
        if solved:
            self.failing_since = None
            if self.solved_since is None:
                self.solved_since = self.c.time
        else:
            self.solved_since = None

    def on_impact(self, hit) -> None:
        """An impact seen on the F/T or the joints (impact.py): brace, unless in failure (the
        fallback already holds) or bracing already."""
        c = self.c
        state = c.fsm.state
        if state in ("brace", "failure") or c.state is None:
            return
        brace = state in c.params.impact.brace_states
        c.emit("impact_detected", source=hit.source, value=round(hit.value, 3),
               threshold=round(hit.threshold, 3), state=state, braced=brace)
        if brace:
            c.fsm.fire(c, "impact")
        else:  # a limb on its way: the transition goes on (its guarded approach finds the contact)
            c.impact.mute_until(c.time + c.params.impact.cooldown_s)

    def begin_brace(self) -> None:
        """Hold every contact at full load (a release cancelled; grasps allowed
        ``impact.grip_force_fraction`` of the grip strength, their grippers closed), the posture
        task's target the configuration now (stiffness scaled by ``impact.posture_stiffness_scale``),
        the joint PD's target too while the QP is infeasible (fsm.BraceState)."""
        c = self.c
        interrupted = c.fsm.history[-1][1] if c.fsm.history else ""
        oMf = c.wb.data.oMf
        brace = Brace(c.time, interrupted, {limb: contact_point(oMf, k) for limb, k in c.contacts.items()},
                      c.posture_task.stiffness)
        c.contact_set.cancel(("release",))
        for limb, contact in c.contacts.items():
            if contact.bilateral:
                brace.force_limits[limb] = contact.force_limit
                contact.force_limit = (contact.force_limit * c.params.impact.grip_force_fraction
                                       / max(c.params.contacts.grip_force_fraction, 1e-6))
                c.queue_gripper(limb, "close")
        c.hold_here()
        self.q_hold = c.state.q.copy()  # the joint PD's target while the QP is infeasible
        c.posture_task.stiffness = brace.posture_stiffness * c.params.impact.posture_stiffness_scale
        self.brace = brace
        c.emit("brace_started", interrupted=interrupted, transition=c.transition_index,
               contacts=sorted(c.contacts))

    def end_brace(self) -> None:
        c = self.c
        brace = self.brace
        if brace is None:
            return
        c.posture_task.stiffness = brace.posture_stiffness
        for limb, limit in brace.force_limits.items():
            if limb in c.contacts:
                c.contacts[limb].force_limit = limit
        c.impact.mute_until(c.time + c.params.impact.cooldown_s)
        if not self.fallback_active:
            self.q_hold = None
        c.emit("brace_ended", duration=round(c.time - brace.since, 3), displacement=dict(brace.displacement))
        self.brace = None

    def brace_settled(self) -> bool:
        """Every joint slower than ``impact.settle_joint_speed``."""
        c = self.c
        return bool(np.max(np.abs(c.state.v[6:])) < c.params.impact.settle_joint_speed)

    def lost_contacts(self) -> list[str]:
        """Active contacts whose reference point moved more than ``impact.contact_lost_distance``
        since the impact (a foot knocked off its rung, a grasp slid along it): they leave the
        contact set (the QP must not push on them) and are returned."""
        c = self.c
        brace = self.brace
        if brace is None:
            return []
        oMf = c.wb.data.oMf
        lost = []
        for limb, anchor in brace.anchors.items():
            contact = c.contacts.get(limb)
            if contact is None:
                continue
            moved = float(np.linalg.norm(contact_point(oMf, contact) - anchor))
            brace.displacement[limb] = round(moved, 4)
            if moved > c.params.impact.contact_lost_distance:
                lost.append(limb)
        for limb in lost:
            brace.lost_holds[limb] = c.holds[limb]
            c.remove_contact(limb)
            c.emit("contact_lost", limb=limb, moved=brace.displacement[limb])
        return lost

    def replace_lost(self, lost: list[str]) -> bool:
        """One contact lost: make the plan's transition that last placed that limb on that surface
        the one to run (fsm: ``replace -> transfer``), without moving the plan's index; the
        interrupted transition runs again once it is placed (:meth:`finish_transition`). False (a
        replan instead) with several contacts lost, no plan, or no such transition."""
        c = self.c
        if not c.params.impact.replace_lost or len(lost) != 1 or c.plan is None or self.brace is None:
            return False
        limb = lost[0]
        surface = self.brace.lost_holds[limb].env_surface
        for k in range(min(c.transition_index, len(c.plan.transitions) - 1), -1, -1):
            t = c.plan.transitions[k]
            if t.moving_limb != limb:
                continue
            hold = t.target_stance.hold(limb)
            if hold is None or hold.env_surface != surface:
                return False  # the limb's last move went elsewhere
            c._replacing = c.transition_index
            c.transition, c.moving_limb, c.target_surface = t, limb, surface
            c.moving_kind = limb_kind(limb, hold)
            c.emit("replace_started", limb=limb, surface=surface, transition=k)
            return True
        return False

    def resume_after_brace(self) -> None:
        """The interrupted transition goes on from where the robot is: ``select`` picks it again
        (not finished) and its state blends from the measured configuration; a placement whose
        contact was being loaded counts as made."""
        c = self.c
        brace = self.brace
        if brace is not None and brace.interrupted == "load" and c.moving_limb in c.contacts:
            c.finish_transition()
        c.emit("brace_resumed", interrupted=brace.interrupted if brace else "", transition=c.transition_index)

    def on_failure(self, failure: QpFailure) -> None:
        c = self.c
        self.qp_failures += 1
        p = c.params.qp
        if len(self.saved_failures) < p.max_saved_failures:
            folder = pathlib.Path(p.failure_dir)
            if not folder.is_absolute():
                folder = project_root() / folder
            path = folder / f"qp_failure_{int(time.time() * 1e3)}_{self.qp_failures:04d}.npz"
            failure.saved_path = save_problem(
                failure.problem, path, solver=failure.solver, status=failure.status, time=c.time,
                fsm_state=c.fsm.state, contacts=",".join(c.contacts),
                dampers=";".join(f"{d.name}:d={d.distance:.4f}:rate={d.distance_rate:.3f}:lower={d.lower:.2f}"
                                 for d in c.wb.last_dampers()))
            self.saved_failures.append(path)
        c.emit("qp_failure", status=failure.status, solver=failure.solver,
               saved=str(failure.saved_path or ""))

    def enter_fallback(self) -> None:
        """Failure state: hold the configuration at failure (QP hold tasks, PD if that fails too)."""
        c = self.c
        self.fallback_active = True
        self.q_hold = c.state.q.copy()
        if c.last_result is None:  # never solved: static equilibrium feed-forward instead
            self.tau_ff = self.static_torques()
        c.active_tasks = [c.com_task, c.posture_task, c.base_task]
        c.hold_here()
        # a contact still engaging carries little load and is the likely culprit: drop it
        for limb in [limb for limb, ramp in c.contact_set.ramps.items() if ramp.kind == "engage"]:
            c.remove_contact(limb)
        c.contact_set.cancel(("release", "engage"))

    def failure_recovered(self) -> bool:
        """In failure: the QP (hold tasks, the contacts kept) has solved for ``qp.recover_after_s``
        without a break and the joints have settled."""
        c = self.c
        after = c.params.qp.recover_after_s
        return (after > 0.0 and self.solved_since is not None and c.time - self.solved_since >= after - 1e-9
                and self.brace_settled())

    def clear_fallback(self) -> None:
        """The external ``reset``: the QP's torques drive again (the failure's hold target stays)."""
        self.fallback_active = False

    def leave_failure(self) -> None:
        c = self.c
        self.fallback_active = False
        self.q_hold = None
        c.emit("failure_recovered", contacts=sorted(c.contacts))

    def static_torques(self) -> np.ndarray:
        """Joint torques [N m] holding the current configuration still on the active contacts:
        the least-norm contact wrenches balancing gravity on the base rows (no friction or torque
        limits: a feed-forward for the fallback PD, not a QP)."""
        c = self.c
        g = pin.computeGeneralizedGravity(c.model, c.ref_data, c.state.q)
        contacts = c.contact_set.ordered()
        if not contacts:
            return g[6:].copy()
        J = np.vstack([c.wb._contact_kinematics(k)[0] for k in contacts])  # (6k, nv)
        wrenches = np.linalg.pinv(J[:, :6].T) @ g[:6]
        return g[6:] - J[:, 6:].T @ wrenches

    def fallback_torque(self, state: RobotState) -> np.ndarray:
        c = self.c
        f = c.params.fallback
        q_hold = self.q_hold if self.q_hold is not None else state.q
        inertia = np.diag(c.wb.data.M)[6:]  # [kg m^2] joint-space inertia of each joint
        kp = inertia * f.natural_frequency ** 2
        kd = inertia * 2.0 * f.damping_ratio * f.natural_frequency
        return self.tau_ff + kp * (q_hold[7:] - state.q[7:]) - kd * state.v[6:]


__all__ = ["Brace", "Recovery", "contact_point"]
