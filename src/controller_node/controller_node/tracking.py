"""Path tracking of the controller: the executed transition's whole-body path turned into task
targets, tick by tick.

:class:`PathTracker` is one controller's. The FSM's states talk to it (``ctx.path``): ``start``
a transition's path (the offset of the measured state from its first way-point blended out over
the path), ``track`` it (CoM, posture, base orientation and the moving limb's contact-body
targets, with their velocities; the damper between the limb and its target surface off on the
last segment, the approach), ``in_approach``, ``freeze_limb`` where it is (a contact seen), and
``creep`` past the planned end pose along ``approach_direction`` (the guarded search). It sets
the controller's tasks through the controller it belongs to.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

from climb_core.contact import Transition

from .reference import PathReference

if TYPE_CHECKING:
    from .controller import Controller


class PathTracker:
    """The path of the transition under way and the moving limb's guarded search (module
    docstring)."""

    def __init__(self, controller: "Controller"):
        self.c = controller
        self.reference: PathReference | None = None
        self.start_time = 0.0  # [s] when the path started
        self.limb = ""  # the limb whose contact-body task follows the path ("" for a CoM shift)
        self.blend: dict[str, Any] = {}  # offsets of the measured state from the path's start
        self.creep_base: pin.SE3 | None = None  # the limb's last tracked target (the search's origin)
        self.creep_origin: pin.SE3 | None = None
        self.creep_dir = np.zeros(3)
        self.creep_posture = np.zeros(controller.na)
        self.approach: dict[str, np.ndarray] = {}  # limb -> unit approach direction (world)

    def reference_quantities(self, q_ref: np.ndarray, limb: str) -> tuple[np.ndarray, pin.SE3 | None]:
        c = self.c
        com = pin.centerOfMass(c.model, c.ref_data, q_ref, False).copy()
        if not limb:
            return com, None
        fid = c.limb_frame_ids[limb]
        pin.updateFramePlacement(c.model, c.ref_data, fid)
        M = c.ref_data.oMf[fid]
        offset = c.limb_surface[limb][:3, 3]
        return com, pin.SE3(M.rotation.copy(), M.translation + M.rotation @ offset)

    def reference_motion(self, q_ref: np.ndarray, v_ref: np.ndarray, limb: str
                          ) -> tuple[np.ndarray, np.ndarray, pin.SE3 | None, np.ndarray | None]:
        """CoM [m] and its velocity [m/s], and the limb's contact surface pose and twist (world
        axes, at the surface point: linear [m/s], angular [rad/s]) along the reference, from one
        kinematics pass with velocity."""
        c = self.c
        model, data = c.model, c.ref_data
        com = pin.centerOfMass(model, data, q_ref, v_ref, False).copy()
        vcom = data.vcom[0].copy()
        if not limb:
            return com, vcom, None, None
        fid = c.limb_frame_ids[limb]
        pin.updateFramePlacement(model, data, fid)
        M = data.oMf[fid]
        r = M.rotation @ c.limb_surface[limb][:3, 3]
        vx, vy, vz, wx, wy, wz = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).vector.tolist()
        rx, ry, rz = r.tolist()
        # v + w x r at the surface point (np.cross costs ~25 us on 3-vectors; same arithmetic)
        twist = np.array([vx + (wy * rz - wz * ry), vy + (wz * rx - wx * rz), vz + (wx * ry - wy * rx), wx, wy, wz])
        return com, vcom, pin.SE3(M.rotation.copy(), M.translation + r), twist

    def start(self, transition: Transition, moving_limb: str = "") -> None:
        """Track ``transition.path`` from now; blend out today's offset from its first way-point."""
        c = self.c
        self.reference = PathReference(c.model, transition.times, transition.path)
        self.start_time = c.time
        self.limb = moving_limb
        q0 = self.reference.start
        com0, T0 = self.reference_quantities(q0, moving_limb)
        q = c.state.q
        blend = {
            "com": c.wb.data.com[0] - com0,
            "joints": q[7:] - q0[7:],
            "base": pin.log3(pin.Quaternion(q[3:7]).normalized().toRotationMatrix()
                             @ pin.Quaternion(q0[3:7]).normalized().toRotationMatrix().T),
        }
        if moving_limb:
            task = c.contact_body_tasks[moving_limb]
            T_now = task.current(c.wb.view)
            blend["limb_p"] = T_now.translation - T0.translation
            blend["limb_R"] = pin.log3(T_now.rotation @ T0.rotation.T)
        self.blend = blend
        c._set_contact_body(moving_limb or None)
        if moving_limb:
            self.approach[moving_limb] = self.approach_direction(moving_limb)
            self.creep_dir = np.zeros(3)
        self.track()

    def in_approach(self, fraction: float = 0.0) -> bool:
        """True once the path progress is ``fraction`` into its last segment (the approach)."""
        ref = self.reference
        if ref is None:
            return True
        s, _ = ref.progress(self.elapsed())
        start = ref.last_segment_start
        return s >= start + fraction * (1.0 - start)

    def elapsed(self) -> float:
        c = self.c
        return c.time - self.start_time

    def duration(self) -> float:
        return self.reference.duration if self.reference is not None else 0.0

    def track(self) -> bool:
        """Set task targets from the path at the current time; True once the path is finished."""
        c = self.c
        ref = self.reference
        if ref is None:
            return True
        t = self.elapsed()
        q_ref, v_ref = ref.sample(t)
        s, sdot = ref.progress(t)
        w = 1.0 - s
        limb = self.limb
        com, vcom, T, twist = self.reference_motion(q_ref, v_ref, limb)
        b = self.blend
        c.com_task.set_target(com + w * b["com"], vcom - sdot * b["com"])
        c.posture_task.set_target(q_ref[7:] + w * b["joints"], v_ref[6:] - sdot * b["joints"])
        R_base = pin.exp3(w * b["base"]) @ pin.Quaternion(q_ref[3:7]).normalized().toRotationMatrix()
        c.base_task.set_target(R_base)
        if limb:
            p = T.translation + w * b["limb_p"]
            R = pin.exp3(w * b["limb_R"]) @ T.rotation
            lin = twist[:3] - sdot * b["limb_p"]
            T_target = pin.SE3(R, p)  # never mutated: the task's target and the creep origin share it
            c.contact_body_tasks[limb].set_target(T_target, np.concatenate([lin, twist[3:]]))
            self.creep_base = T_target
            if s >= ref.last_segment_start and c.target_surface:
                # approach: the damper between the limb and its target surface goes off
                c.set_guard(limb, c.target_surface, False)
        return t >= ref.duration

    def freeze_limb(self) -> None:
        """Stop the moving limb where it is (contact seen): its target = its current pose."""
        c = self.c
        limb = c.moving_limb
        if not limb:
            return
        task = c.contact_body_tasks[limb]
        T_now = task.current(c.wb.view)
        task.set_target(T_now)
        q = c.state.q
        idx = c.limb_joint_v[limb] - 6
        q_post = c.posture_task.q_joints.copy()
        q_post[idx] = q[7:][idx]
        v_post = c.posture_task.v_joints.copy()
        v_post[:] = 0.0
        c.posture_task.set_target(q_post, v_post)
        com = c.com_task.position.copy()
        c.com_task.set_target(com)
        c.emit("limb_frozen", limb=limb, position=T_now.translation.copy())

    def creep(self, distance: float) -> None:
        """Search: move the limb target ``distance`` [m] past the planned end pose along the approach."""
        c = self.c
        limb = c.moving_limb
        if not limb or self.reference is None:
            return
        first_step = distance <= c.params.guarded.approach_speed * c.params.control_period_s * 1.01
        if self.creep_dir is None or not np.any(self.creep_dir) or first_step:
            self.creep_dir = self.approach_direction(limb)
            self.creep_posture = c.posture_task.q_joints.copy()
            self.creep_origin = self.creep_base
        T0 = self.creep_origin
        T = pin.SE3(T0.rotation, T0.translation + distance * self.creep_dir)
        c.contact_body_tasks[limb].set_target(T, np.concatenate([c.params.guarded.approach_speed * self.creep_dir,
                                                                 np.zeros(3)]))
        # joint reference for the limb follows by one damped least-squares step (compliance mode)
        J = pin.getFrameJacobian(c.model, c.wb.data, c.limb_frame_ids[limb], pin.LOCAL_WORLD_ALIGNED)[:3]
        idx = c.limb_joint_v[limb]
        Jl = J[:, idx]
        step = c.params.guarded.approach_speed * c.params.control_period_s * self.creep_dir
        dq = Jl.T @ np.linalg.solve(Jl @ Jl.T + 1e-4 * np.eye(3), step)
        q_post = c.posture_task.q_joints.copy()
        q_post[idx - 6] += dq
        c.posture_task.set_target(q_post)

    def approach_direction(self, limb: str) -> np.ndarray:
        """Unit direction [world] of the guarded search past the planned end pose: into the target
        surface (minus its mean normal) for a unilateral hold (a foot pushes down onto a rung even
        when the plan's last way-points slide sideways onto it); for a grasp, out of the palm at
        the planned end pose (the grasp surface's z: the palm closes in on the bar). Measured on
        the coarse grid's 84 deg / 23 cm ladder: the mount's last 20 % ran mostly along the rung
        (0.11, 0.86, -0.51), the hand lagged 2 cm below the rung, and a search along the path
        slid it 5 cm along the rung without touching it (``no_contact``, then a replan that did
        not plan); along the palm normal it touched after 1 cm and the ladder was climbed.
        The direction of the path's last 20 % is the fallback."""
        c = self.c
        hold = c.transition.target_stance.hold(limb) if c.transition is not None else None
        if hold is not None and not hold.bilateral and len(hold.points):
            n = np.asarray(hold.normals, float).mean(axis=0)
            if np.linalg.norm(n) > 1e-6:
                return -n / np.linalg.norm(n)
        ref = self.reference
        end_com, T_end = self.reference_quantities(ref.end, limb)
        if hold is not None and hold.bilateral and T_end is not None:
            n = T_end.rotation @ c.limb_surface[limb][:3, 2]
            if np.linalg.norm(n) > 1e-6:
                return n / np.linalg.norm(n)
        q_before, _ = ref.sample(0.8 * ref.duration)
        _, T_before = self.reference_quantities(q_before, limb)
        d = T_end.translation - T_before.translation
        if np.linalg.norm(d) < 1e-3:
            hold = c.transition.target_stance.hold(limb) if c.transition is not None else None
            d = -hold.normals.mean(axis=0) if hold is not None and len(hold.points) else np.array([0.0, 0.0, -1.0])
        return d / np.linalg.norm(d)
