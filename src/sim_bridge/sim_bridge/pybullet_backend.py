"""PyBullet backend: the robot, the ladder and the ground in one private PyBullet client.

One client per instance (``p.connect(p.DIRECT)``, GUI on request); every call passes
``physicsClientId``. The robot is the bridge's simulation URDF (sim_urdf.py: absolute meshes, tiny
inertials, foot boxes, armature, fingers kept), loaded with its URDF inertias; the environment is
``sim_bridge.world_bodies.add_environment``. Physics runs at ``physics.dt_s`` (1 kHz),
``step()`` advances one control period (default 5 ms = 5 physics steps) and the actuator models
(actuation.py) compute fresh torques before every physics step. Modelling assumptions are in
docs/sim_bridge.md.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from climb_core.contact import HANDS, LIMBS
from climb_core.errors import SpecError

from . import frames
from .actuation import ActuatorBank
from .backend import Backend, BallState, BaseTruth, ImuReading, ResetRequest, SimState, Wrench
from .commands import (GRIPPER_CLOSE, GRIPPER_OPEN, POSITION, ActuatorCommand, GripperRequest, PerturbRequest,
                       drop_request)
from .grasp import GraspManager
from .motor import MotorParams
from .params import BridgeParams, load_bridge_params
from .sim_urdf import sim_urdf_path
from .world import initial_configuration, resolve_scenario
from . import world_bodies


def _import_pybullet():
    try:
        import pybullet
    except ImportError as exc:  # pragma: no cover - pybullet is a project dependency
        raise ImportError("the PyBullet backend needs pybullet: pip install pybullet") from exc
    return pybullet


_YZX = np.array([1, 2, 0])  # cyclic shifts of a 3-vector's components (cross products)
_ZXY = np.array([2, 0, 1])
_IDENTITY_4 = np.eye(4)  # copied: cheaper than np.eye(4)


@dataclass
class _Ball:
    body: int
    mass: float  # [kg]
    launch_time: float  # [s]
    launch_velocity: np.ndarray  # (3,) [m/s]
    impulse_on_robot: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [N s]
    touching: bool = False


class PyBulletBackend(Backend):
    """Backend on PyBullet. ``reset()`` builds the world; ``close()`` disconnects the client."""

    def __init__(self, params: BridgeParams | None = None):
        super().__init__()
        self.p = _import_pybullet()
        self.params = params or load_bridge_params()
        self.control_period_ns = self.params.physics.control_period_ns
        self.client: int | None = None
        self.robot = None  # climb_core.robot.RobotModel
        self.env = None  # climb_core.environment.Environment
        self.scenario = None
        self.robot_name = ""
        self.ladder_source: Any = None
        self.body = -1
        self.env_bodies: dict[str, int] = {}
        self.ground_body = -1
        self.balls: list[_Ball] = []
        self.rng = np.random.default_rng(self.params.seed)
        self.fell = False
        self.fall_reason = ""
        self.grip_strength = 0.0  # [N] current grip strength of both hands (robot config at reset)
        self._imu_velocity_prev = np.zeros(3)
        self._imu_acc = np.zeros(3)
        self.physics_time_s = 0.0  # [s] wall time of the last tick's stepSimulation calls
        self._kinematics = None  # base kinematics of the current physics state
        self._contact_scan = None  # _scan_contacts() of the current physics state
        self._joint_states = None  # observe()'s getJointStates rows of the current physics state
        self._built: tuple | None = None  # the last world built (_build's arguments): a failed build restores it

    # ============================================================================ world building
    def _connect(self) -> None:
        p = self.p
        if self.client is None:
            self.client = p.connect(p.GUI if self.params.gui else p.DIRECT)
            if self.client < 0:
                raise RuntimeError("PyBullet could not connect (GUI needs a display)")
        else:
            p.resetSimulation(physicsClientId=self.client)
        ph = self.params.physics
        p.setGravity(0.0, 0.0, -ph.gravity, physicsClientId=self.client)
        p.setPhysicsEngineParameter(fixedTimeStep=ph.dt_s, numSolverIterations=ph.solver_iterations,
                                    numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=self.client)

    def reset(self, request: ResetRequest | None = None) -> SimState:
        """Build the world (robot, environment, ground) and put the robot in its initial posture.

        Everything the request names is loaded and checked first (robot, ladder, posture or q):
        a request that cannot be carried out raises SpecError before anything changes (the world,
        the sim time, the queued requests and the last good robot / ladder stay as they were)."""
        request = request or ResetRequest()
        plan = self._prepare_reset(request)
        previous = self._built
        try:
            return self._build(*plan)
        except Exception:
            if previous is not None:  # rebuilt as it was: a failed reset must not leave half a world
                self._build(*previous)
            raise

    def _prepare_reset(self, request: ResetRequest) -> tuple:
        """(robot name, robot, ladder source, scenario, env, q0, hands to latch, seed) of a reset
        request, every part loaded and validated; nothing of the running world is touched."""
        from climb_core.robot import load_robot

        robot_name = request.robot or self.robot_name or self.params.robot
        ladder_source = self.ladder_source if request.ladder is None else request.ladder
        if ladder_source is None:
            ladder_source = self.params.ladder
        try:
            robot = self.robot if (robot_name == self.robot_name and self.robot is not None) else load_robot(robot_name)
        except (OSError, KeyError, ValueError) as err:  # not a SpecError: say which field
            raise SpecError("robot", f"cannot load robot {robot_name!r}: {err}") from None
        scenario, env = resolve_scenario(ladder_source, self.params.apply_perturbation)
        if request.seed is not None and int(request.seed) < 0:
            raise SpecError("seed", f"must be >= 0, got {request.seed}")
        seed = self.params.seed if request.seed is None else int(request.seed)
        q0, hands = initial_configuration(robot, env, request.q, request.initial_posture or self.params.initial_posture)
        return robot_name, robot, ladder_source, scenario, env, q0, hands, seed

    def _build(self, robot_name, robot, ladder_source, scenario, env, q0, hands_to_latch, seed) -> SimState:
        self._clear_requests()
        self.stamp_ns = 0
        self.robot, self.robot_name, self.ladder_source = robot, robot_name, ladder_source
        self.scenario, self.env = scenario, env
        self.rng = np.random.default_rng(seed)
        self._connect()
        cid = self.client
        self.env_bodies = world_bodies.add_environment(self.env, cid)
        self._replace_ground_plane()
        self.ground_body = self.env_bodies.get("ground", -1)
        self._env_body_set = set(self.env_bodies.values())
        self._load_robot()
        self._set_configuration(q0)
        self.actuators.reset()
        self.balls = []
        self.fell, self.fall_reason = False, ""
        self.grip_strength = float(self.robot.config.grip_strength)
        self.grasps = GraspManager(self, self.params.grasp)
        for hand in hands_to_latch:
            self.grasps.close(hand, 1.0)
        for drop in (self.scenario.perturbation.drops if self.params.apply_perturbation else ()):
            if drop.on_transition:  # thrown by the climb session when the transition starts
                continue
            self.request_perturbation(drop_request(drop))
        self._imu_velocity_prev = self._base_kinematics()[2]
        self._imu_acc = np.zeros(3)
        self._built = (robot_name, robot, ladder_source, scenario, env, q0, hands_to_latch, seed)
        return self.observe()

    def _load_robot(self) -> None:
        p, cid = self.p, self.client
        robot = self.robot
        cfg = robot.config
        flags = p.URDF_USE_INERTIA_FROM_FILE
        if not self.params.gui:
            flags |= p.URDF_IGNORE_VISUAL_SHAPES
        if self.params.physics.self_collision:
            flags |= p.URDF_USE_SELF_COLLISION | p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT
        q_ref = robot.q_reference()
        self.body = p.loadURDF(str(sim_urdf_path(robot)), basePosition=q_ref[:3].tolist(), flags=flags,
                               physicsClientId=cid)
        body = self.body
        n = p.getNumJoints(body, physicsClientId=cid)
        self.joint_index: dict[str, int] = {}
        self.link_index: dict[str, int] = {p.getBodyInfo(body, physicsClientId=cid)[0].decode(): -1}
        self.parent_of: dict[int, int] = {}
        self.joint_info: dict[str, tuple] = {}
        for j in range(n):
            info = p.getJointInfo(body, j, physicsClientId=cid)
            name = info[1].decode()
            self.joint_index[name] = j
            self.link_index[info[12].decode()] = j
            self.parent_of[j] = info[16]
            self.joint_info[name] = info
        self.root_link = next(name for name, idx in self.link_index.items() if idx == -1)
        missing = [name for name in robot.joint_names if name not in self.joint_index]
        if missing:
            raise SpecError("robot", f"simulation URDF lacks whole-body joints {missing}")
        self.joint_names = tuple(robot.joint_names)
        self._act = [self.joint_index[name] for name in self.joint_names]
        self.finger_names = tuple(name for name in cfg.locked_joints
                                  if name in self.joint_index and self.joint_info[name][2] != p.JOINT_FIXED)
        self._fingers = [self.joint_index[name] for name in self.finger_names]
        # default velocity motors brake every joint: off (torque control from now on)
        movable = self._act + self._fingers
        p.setJointMotorControlArray(body, movable, p.VELOCITY_CONTROL, forces=[0.0] * len(movable),
                                    physicsClientId=cid)
        # inertial frames (PyBullet reports the base and the sensors in them)
        self.T_link_inertial: dict[int, np.ndarray] = {}
        for link in [-1] + list(range(n)):
            info = p.getDynamicsInfo(body, link, physicsClientId=cid)
            self.T_link_inertial[link] = frames.pose_matrix(info[3], info[4])
        # friction: PyBullet multiplies both bodies' coefficients (world_bodies' module docstring)
        mu_robot = world_bodies.robot_lateral_friction(self.env)
        for link in [-1] + list(range(n)):
            p.changeDynamics(body, link, lateralFriction=mu_robot, restitution=0.0, rollingFriction=0.0,
                             spinningFriction=0.0, physicsClientId=cid)
        # F/T sensors on the configured joints: wrench reported in the child link frame
        self.ft_joints: dict[str, int] = {}
        for sensor, joint in cfg.ft_sensors.items():
            if joint not in self.joint_index:
                raise SpecError(f"ft_sensors.{sensor}", f"joint {joint!r} not in the simulation URDF")
            j = self.joint_index[joint]
            p.enableJointForceTorqueSensor(body, j, True, physicsClientId=cid)
            self.ft_joints[sensor] = j
        self._ft_order = list(self.ft_joints)
        # limbs: the link of each contact surface and every link below the limb's last joint
        self.limb_link: dict[str, int] = {}
        self.limb_links: dict[str, set[int]] = {}
        self.T_link_surface: dict[str, np.ndarray] = {}
        for name, limb in cfg.limbs.items():
            frame = limb.surface.frame
            if frame not in self.link_index:
                raise SpecError(f"limbs.{name}.frame", f"{frame!r} is not a link of the simulation URDF")
            self.limb_link[name] = self.link_index[frame]
            self.T_link_surface[name] = np.asarray(limb.surface.T_frame_surface, dtype=float)
            end_joint = self.joint_index[limb.joints[-1]]
            self.limb_links[name] = self._subtree(end_joint)
        self.link_limb = {link: limb for limb, links in self.limb_links.items() for link in links}
        # fingers of each hand and their closed positions (the limit farthest from 0)
        self.hand_fingers: dict[str, list[int]] = {}
        self.finger_closed = np.zeros(len(self._fingers))
        lower = np.array([self.joint_info[nm][8] for nm in self.finger_names])
        upper = np.array([self.joint_info[nm][9] for nm in self.finger_names])
        self.finger_effort = np.array([self.joint_info[nm][10] for nm in self.finger_names])
        self.finger_open = np.array([cfg.locked_posture[nm] for nm in self.finger_names])  # within the limits
        for k, (lo, hi) in enumerate(zip(lower, upper)):
            self.finger_closed[k] = hi if abs(hi) > abs(lo) + 1e-9 else lo if abs(lo) > abs(hi) + 1e-9 else 0.0
        for hand in HANDS:
            links = self.limb_links.get(hand, set())
            self.hand_fingers[hand] = [k for k, j in enumerate(self._fingers) if j in links]
        self.finger_target = np.zeros(len(self._fingers))  # [-] 0 open .. 1 closed per finger joint
        # actuators
        motor = cfg.motor
        specs = [motor.for_joint(name) for name in self.joint_names]
        mp = MotorParams(**{f: np.array([getattr(s, f) for s in specs]) for f in
                            ("supply_voltage", "resistance", "torque_constant", "gear_ratio", "current_limit",
                             "trip_hold_off_s")})
        self.actuators = ActuatorBank(self.joint_names, robot.effort_limits(), mp, self.params.actuation,
                                      implicit_position=True)
        self._position_mask = np.zeros(len(self._act), dtype=bool)
        self._any_position = False  # = self._position_mask.any()
        self._torque_sel = np.arange(len(self._act))
        self._torque_idx = list(self._act) + self._fingers
        self._filter_self_collisions(q_ref)
        self._finger_gains()
        self._prepare_sensing()

    def _finger_gains(self) -> None:
        """Finger servo gains from each finger joint's apparent inertia m = 1 / (M^-1)_jj at the
        current (reference) posture: kp = m w^2, kd = 2 zeta m w. An explicit PD sized this way is
        stable at 1 kHz on the light phalanges; PyBullet's implicit position motors would hold the
        fingers stiffer, but their 14 solver rows on links ~1e4 times lighter than the body never
        let the constraint solver converge early (they tripled the cost of a physics step)."""
        n_f = len(self._fingers)
        self.finger_kp = np.zeros(n_f)  # [N m/rad]
        self.finger_kd = np.zeros(n_f)  # [N m s/rad]
        if n_f:
            p, cid, body = self.p, self.client, self.body
            movable = [j for j in range(p.getNumJoints(body, physicsClientId=cid))
                       if p.getJointInfo(body, j, physicsClientId=cid)[2] != p.JOINT_FIXED]
            q = [st[0] for st in p.getJointStates(body, movable, physicsClientId=cid)]
            M = np.asarray(p.calculateMassMatrix(body, q, physicsClientId=cid))
            base_dofs = M.shape[0] - len(movable)  # 6 for a floating base
            m_inv = np.diag(np.linalg.inv(M))
            apparent = np.array([1.0 / m_inv[base_dofs + movable.index(j)] for j in self._fingers])  # [kg m^2]
            a = self.params.actuation
            self.finger_kp = apparent * a.finger_bandwidth ** 2
            self.finger_kd = 2.0 * a.finger_damping_ratio * apparent * a.finger_bandwidth
        self._set_finger_goal()

    def _set_finger_goal(self) -> None:
        """Finger servo goals [rad] from the targets, and the servo's per-finger constants as Python
        floats (goal, kp, kd, -effort, effort): on 14 fingers, float arithmetic beats numpy's
        per-call overhead."""
        self.finger_goal = self.finger_open + self.finger_target * (self.finger_closed - self.finger_open)
        self._finger_servo = list(zip(self.finger_goal.tolist(), self.finger_kp.tolist(), self.finger_kd.tolist(),
                                      (-self.finger_effort).tolist(), self.finger_effort.tolist()))

    def _replace_ground_plane(self) -> None:
        """PyBullet's GEOM_PLANE has an infinite bounding box: every robot link overlaps it in the
        broadphase and runs a narrowphase test against it every physics step. The ground becomes
        the same finite box the planner's coal model uses (``Surface.primitive_half_extents``,
        top face at z = 0), with the same friction; only links near the ground are tested."""
        p, cid = self.p, self.client
        for name, surface in self.env.surfaces.items():
            if surface.shape != "plane" or name not in self.env_bodies:
                continue
            old = self.env_bodies[name]
            dyn = p.getDynamicsInfo(old, -1, physicsClientId=cid)
            p.removeBody(old, physicsClientId=cid)
            half = surface.primitive_half_extents().tolist()
            T = surface.T_world_primitive()
            collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            visual = -1
            if self.params.gui:
                visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.5, 0.5, 0.5, 1.0],
                                             physicsClientId=cid)
            body = p.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
                                     basePosition=T[:3, 3].tolist(),
                                     baseOrientation=frames.matrix_to_quat(T[:3, :3]).tolist(), physicsClientId=cid)
            p.changeDynamics(body, -1, lateralFriction=dyn[1], restitution=0.0, rollingFriction=0.0,
                             spinningFriction=0.0, physicsClientId=cid)
            self.env_bodies[name] = body

    def _subtree(self, joint: int) -> set[int]:
        out = {joint}
        changed = True
        while changed:
            changed = False
            for child, parent in self.parent_of.items():
                if parent in out and child not in out:
                    out.add(child)
                    changed = True
        return out

    def _collision_chains(self) -> dict[int, str]:
        """Link -> the kinematic chain it belongs to: a limb (the subtree of its first joint that no
        other limb shares; G1: a leg from the hip, an arm from the shoulder, hand and fingers
        included) or "trunk" (the rest: pelvis, waist, torso, head)."""
        limbs = self.robot.config.limbs
        chains = {link: "trunk" for link in self.link_index.values()}
        for name, limb in limbs.items():
            shared = {j for other, o in limbs.items() if other != name for j in o.joints}
            own = [j for j in limb.joints if j not in shared]
            if own:
                for link in self._subtree(self.joint_index[own[0]]):
                    chains[link] = name
        return chains

    def _filter_self_collisions(self, q_ref: np.ndarray) -> None:
        """Self-collision is checked only where it can matter (each pair PyBullet tests costs a
        narrowphase test every physics step while their bounding boxes overlap):

        - between links of different chains (legs, arms, trunk: a knee against the torso, a hand
          against a thigh, leg against leg); two links of one chain are kept apart by the joint
          limits (``physics.self_collision_same_chain`` turns them back on);
        - not for the fingers (``physics.self_collision_fingers``): the grasp is a constraint and
          they carry no load; they still collide with the environment; never inside one hand;
        - not between links touching (or closer than the margin) at the reference posture
          (FIELD_NOTES: siblings touching at rest are checked even with EXCLUDE_ALL_PARENTS), nor
          the config's ignore pairs."""
        p, cid, body = self.p, self.client, self.body
        ph = self.params.physics
        self._set_configuration(q_ref)
        n = p.getNumJoints(body, physicsClientId=cid)
        links = [-1] + list(range(n))
        has_shape = {link: bool(p.getCollisionShapeData(body, link, physicsClientId=cid)) for link in links}
        margin = ph.self_collision_margin
        self.filtered_pairs: list[tuple[str, str]] = []
        self.checked_pairs: list[tuple[str, str]] = []
        names = {idx: name for name, idx in self.link_index.items()}
        ignore = {frozenset(pair) for pair in self.robot.config.collision.ignore_pairs}
        chains = self._collision_chains()
        fingers = set().union(*(self._subtree(j) for j in self._fingers)) if self._fingers else set()
        hands = [self.limb_links[h] for h in HANDS if h in self.limb_links]
        for a_i, a in enumerate(links):
            for b in links[a_i + 1:]:
                if not (has_shape[a] and has_shape[b]) or self.parent_of.get(b) == a or self.parent_of.get(a) == b:
                    continue  # nothing to collide, or parent / child (excluded by PyBullet)
                pair = (names[a], names[b])
                skip = frozenset(pair) in ignore or any(a in hand and b in hand for hand in hands)  # a gripper's parts
                skip = skip or (not ph.self_collision_same_chain and chains[a] == chains[b])
                skip = skip or (not ph.self_collision_fingers and (a in fingers or b in fingers))
                skip = skip or bool(p.getClosestPoints(body, body, margin, linkIndexA=a, linkIndexB=b,
                                                       physicsClientId=cid))
                if skip:
                    p.setCollisionFilterPair(body, body, a, b, 0, physicsClientId=cid)
                    self.filtered_pairs.append(pair)
                else:
                    self.checked_pairs.append(pair)

    def _set_configuration(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Teleport the robot to Pinocchio configuration q (and velocity v, default 0)."""
        p, cid, body = self.p, self.client, self.body
        self._invalidate()
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.nq,):
            raise SpecError("q", f"must have nq = {self.robot.nq} entries, got {q.shape}")
        T_world_base = frames.pose_matrix(q[:3], q[3:7])
        T_world_inertial = T_world_base @ self.T_link_inertial[-1]
        p.resetBasePositionAndOrientation(body, T_world_inertial[:3, 3].tolist(),
                                          frames.matrix_to_quat(T_world_inertial[:3, :3]).tolist(),
                                          physicsClientId=cid)
        v = np.zeros(self.robot.nv) if v is None else np.asarray(v, dtype=float)
        lin, ang = frames.world_velocity_from_free_flyer(T_world_base, v[:6], T_world_inertial[:3, 3])
        p.resetBaseVelocity(body, lin.tolist(), ang.tolist(), physicsClientId=cid)
        for k, j in enumerate(self._act):
            p.resetJointState(body, j, float(q[7 + k]), float(v[6 + k]), physicsClientId=cid)
        for k, j in enumerate(self._fingers):
            p.resetJointState(body, j, float(self.finger_open[k]), 0.0, physicsClientId=cid)

    def set_state(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Teleport the robot to Pinocchio (q, v) (tests, tools); fingers open, time unchanged."""
        self._set_configuration(q, v)
        self._imu_velocity_prev = self._base_kinematics()[2]
        self._imu_acc = np.array([0.0, 0.0, -self.params.physics.gravity])

    # ============================================================================ stepping
    def _apply(self, cmd: ActuatorCommand) -> None:
        self.actuators.set_command(cmd)

    def _configure_motors(self) -> None:
        """Once per tick: PyBullet position motors for POSITION joints and the fingers; every other
        joint has its velocity motor off and receives torques each physics step."""
        p, cid, body = self.p, self.client, self.body
        cmd = self.actuators.command
        position = cmd.modes == POSITION
        any_position = bool(position.any())
        if not (any_position or self._any_position):
            return  # torque-driven joints only, as in the last tick: nothing to change
        leaving = self._position_mask & ~position
        if leaving.any():
            idx = [self._act[j] for j in np.flatnonzero(leaving)]
            p.setJointMotorControlArray(body, idx, p.VELOCITY_CONTROL, forces=[0.0] * len(idx), physicsClientId=cid)
        if position.any():
            sel = np.flatnonzero(position)
            a = self.params.actuation
            p.setJointMotorControlArray(
                body, [self._act[j] for j in sel], p.POSITION_CONTROL, targetPositions=cmd.values[sel].tolist(),
                targetVelocities=[0.0] * len(sel), forces=self.actuators.position_force_limits()[sel].tolist(),
                positionGains=[a.position_gain] * len(sel), velocityGains=[a.velocity_gain] * len(sel),
                physicsClientId=cid)
        if not np.array_equal(position, self._position_mask):
            self._torque_sel = np.flatnonzero(~position)
            self._torque_idx = [self._act[j] for j in self._torque_sel] + self._fingers
        self._position_mask = position
        self._any_position = any_position

    def _advance(self) -> None:
        p, cid, body = self.p, self.client, self.body
        ph = self.params.physics
        dt = ph.dt_s
        last = ph.substeps - 1
        n_act, n_f = len(self._act), len(self._fingers)
        self._configure_motors()
        actuators = self.actuators
        torque_sel, torque_idx = self._torque_sel, self._torque_idx
        finger_servo = self._finger_servo
        # TORQUE-only commands on powered drivers: the whole-body torques are the same for every
        # physics step of the tick (computed once, equal to computing them each step); only the
        # finger servo needs the joint state every step
        constant = actuators.torques_constant(self.time)
        read = self._fingers if constant else self._act + self._fingers
        physics = 0.0
        perf_counter = time.perf_counter
        for k in range(ph.substeps):
            # the first step starts from the state observe() read (its rows: actuated joints first,
            # fingers last, as in ``read``)
            states = self._joint_states if k == 0 and self._joint_states is not None else \
                p.getJointStates(body, read, physicsClientId=cid)
            if not constant or k == 0:
                if constant:
                    q = np.zeros(n_act)
                    v = q
                else:
                    positions, velocities, _, _ = zip(*states[:n_act])
                    q, v = np.array(positions), np.array(velocities)
                tau, trips = actuators.torques(q, v, self.time + k * dt, dt)
                forces = tau[torque_sel].tolist()  # [N m] whole-body joints in torque modes
                for trip in trips:
                    name = self.joint_names[trip.joint]
                    self._emit("overcurrent", f"{name}: over-current {trip.current:.1f} A > "
                               f"{actuators.motor_params.current_limit[trip.joint]:.1f} A, power cut until "
                               f"t = {trip.until:.3f} s", 2, joint=name, current_A=f"{trip.current:.2f}",
                               until_s=f"{trip.until:.3f}")
            if n_f:
                # finger servo: kp (goal - q) - kd qdot [N m], clipped to the effort
                finger_forces = []
                for state, (goal, kp, kd, low, high) in zip(states[-n_f:], finger_servo):
                    tau_f = kp * (goal - state[0]) - kd * state[1]
                    finger_forces.append(low if tau_f < low else high if tau_f > high else tau_f)
                step_forces = forces + finger_forces
            else:
                step_forces = forces
            if torque_idx:
                p.setJointMotorControlArray(body, torque_idx, p.TORQUE_CONTROL, forces=step_forces,
                                            physicsClientId=cid)
            if k == last:
                self._imu_velocity_prev = self._base_origin_velocity()
            t0 = perf_counter()
            p.stepSimulation(physicsClientId=cid)
            physics += perf_counter() - t0
            self._invalidate()
            if self.grasps.latched:
                self.grasps.cap_norms()
            if self.balls:
                self._track_balls(dt)
        self.physics_time_s = physics
        self._imu_acc = (self._base_kinematics()[2] - self._imu_velocity_prev) / dt
        self.grasps.update()
        self._check_fall()

    # ============================================================================ sensing
    def _base_kinematics(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T_world_base, position_com_in_world, linear velocity of the base origin in world,
        angular velocity in world), cached until the next physics step or teleport."""
        if self._kinematics is None:
            self._kinematics = self._read_base_kinematics()
        return self._kinematics

    def _read_base_kinematics(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        p, cid, body = self.p, self.client, self.body
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        lin, ang = p.getBaseVelocity(body, physicsClientId=cid)
        R_world_inertial = frames.quat_to_matrix(orn)
        com = np.array(pos)
        origin = com + R_world_inertial @ self._t_inertial_base
        T_world_base = _IDENTITY_4.copy()  # = T_world_inertial @ T_inertial_base
        T_world_base[:3, :3] = R_world_inertial @ self._R_inertial_base
        T_world_base[:3, 3] = origin
        ox, oy, oz = origin.tolist()
        com_to_origin = (ox - pos[0], oy - pos[1], oz - pos[2])  # [m] world frame
        v_origin = frames.point_velocity(lin, ang, com_to_origin)  # the root origin's world velocity
        return T_world_base, com, v_origin, np.array(ang)

    def _base_origin_velocity(self) -> np.ndarray:
        """(3,) [m/s] world velocity of the root frame origin (= _base_kinematics()[2], fewer steps)."""
        p, cid, body = self.p, self.client, self.body
        if self._kinematics is not None:
            return self._kinematics[2]
        _, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        lin, ang = p.getBaseVelocity(body, physicsClientId=cid)
        r = frames.quat_to_matrix(orn) @ self._t_inertial_base  # COM -> root origin, world frame
        return frames.point_velocity(lin, ang, r.tolist())

    def _invalidate(self) -> None:
        """The physics state changed (a step or a teleport): drop the cached readings."""
        self._kinematics = None
        self._contact_scan = None
        self._joint_states = None

    def _scan_contacts(self) -> tuple[list[list[float]], tuple | None]:
        """One pass over the robot's contact points (last physics step), cached: per limb (LIMBS
        order) the total force [N] the environment applies on its links (world frame), and the
        first contact of a link that must not touch the ground pressing it harder than the fall
        limit (a getContactPoints row; None if none)."""
        if self._contact_scan is None:
            total = [[0.0, 0.0, 0.0] for _ in LIMBS]
            env, limb_of = self._env_body_set, self._env_limb_links
            ground, allowed, limit = self.ground_body, self._fall_allowed, self._fall_ground_force
            on_ground = None
            for c in self.p.getContactPoints(bodyA=self.body, physicsClientId=self.client):
                if on_ground is None and c[2] == ground and c[3] not in allowed and c[9] > limit:
                    on_ground = c
                if c[2] not in env:
                    continue
                k = limb_of.get(c[3])
                if k is None:
                    continue
                # force on body A: normal along contactNormalOnB (B -> A) plus the two friction directions
                fn, n, f1, d1, f2, d2 = c[9], c[7], c[10], c[11], c[12], c[13]
                acc = total[k]
                acc[0] += fn * n[0] + f1 * d1[0] + f2 * d2[0]
                acc[1] += fn * n[1] + f1 * d1[1] + f2 * d2[1]
                acc[2] += fn * n[2] + f1 * d1[2] + f2 * d2[2]
            self._contact_scan = (total, on_ground)
        return self._contact_scan

    def link_pose(self, link: int) -> np.ndarray:
        """T_world_link (URDF link frame) of a PyBullet link index (-1 = root)."""
        if link == -1:
            return self._base_kinematics()[0]
        state = self.p.getLinkState(self.body, link, computeForwardKinematics=1, physicsClientId=self.client)
        return frames.pose_matrix(state[4], state[5])

    def link_name(self, link: int) -> str:
        """URDF link name of a PyBullet link index (-1 = root)."""
        names = getattr(self, "_link_names", None)
        if names is not None and link in names:
            return names[link]
        return next(name for name, idx in self.link_index.items() if idx == link)

    def surface_pose(self, limb: str) -> np.ndarray:
        """T_world_surface of a limb's contact surface (sole centre / grasp centre)."""
        return self.link_pose(self.limb_link[limb]) @ self.T_link_surface[limb]

    def surface_poses(self, limbs: list[str]) -> list[np.ndarray]:
        """surface_pose() of several limbs, their links read in one PyBullet call."""
        links = [self.limb_link[limb] for limb in limbs]
        if len(links) < 2 or -1 in links:
            return [self.surface_pose(limb) for limb in limbs]
        states = self.p.getLinkStates(self.body, links, computeForwardKinematics=1, physicsClientId=self.client)
        return [frames.pose_matrix(state[4], state[5]) @ self.T_link_surface[limb]
                for state, limb in zip(states, limbs)]

    def _prepare_sensing(self) -> None:
        """Constant data of observe(), computed once per robot load."""
        T_inertial_base = frames.inverse(self.T_link_inertial[-1])
        self._R_inertial_base = T_inertial_base[:3, :3].copy()
        self._t_inertial_base = T_inertial_base[:3, 3].copy()
        # what observe() reads: the fingers too, the next tick's first physics step needs them
        self._read = self._act + [self.ft_joints[s] for s in self._ft_order] + self._fingers
        self._ft_rows = slice(len(self._act), len(self._act) + len(self._ft_order))  # the F/T joints in it
        T_ft = [self.T_link_inertial[self.ft_joints[s]] for s in self._ft_order]
        self._ft_R = np.array([T[:3, :3] for T in T_ft]).reshape(-1, 3, 3)  # child inertial -> link frame
        com_in_link = np.array([T[:3, 3] for T in T_ft]).reshape(-1, 3)  # [m] child COM in the link frame
        # its components cyclically shifted, for r x f = r_yzx f_zxy - r_zxy f_yzx on every sensor at once
        self._ft_t_yzx = com_in_link.take(_YZX, axis=1)
        self._ft_t_zxy = com_in_link.take(_ZXY, axis=1)
        self._env_limb_links = {link: LIMBS.index(limb) for link, limb in self.link_limb.items() if limb in LIMBS}
        self._fall_allowed = set().union(*(self.limb_links[limb] for limb in LIMBS if limb in self.limb_links))
        self._fall_height = self.params.falls.base_height_fraction * self.robot.config.base_height  # [m]
        self._fall_ground_force = self.params.falls.ground_contact_force  # [N]
        self._link_names = {idx: name for name, idx in self.link_index.items()}
        self._gravity_in_world = np.array([0.0, 0.0, -self.params.physics.gravity])
        self._finger_positions = {hand: 0.0 for hand in self.hand_fingers}
        self._ft_bias, self._ft_sigma = self._ft_errors()
        self._invalidate()

    def _ft_errors(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(bias, noise sigma), each (k, 6) [N, N m] per sensor of _ft_order (None when zero): the
        absolute sigmas plus the percentages of each sensor's range (robot config ft_ranges); the
        bias is drawn once per reset."""
        s = self.params.sensors
        ranges = self.robot.config.ft_ranges
        scale = np.array([[ranges[n][0]] * 3 + [ranges[n][1]] * 3 for n in self._ft_order]).reshape(-1, 6)
        absolute = np.array([s.ft_force_noise_std] * 3 + [s.ft_torque_noise_std] * 3)
        sigma = np.sqrt(absolute ** 2 + (0.01 * s.ft_noise_percent * scale) ** 2)
        bias = self.rng.normal(0.0, 1.0, scale.shape) * (0.01 * s.ft_bias_percent * scale) \
            if s.ft_bias_percent else None  # no draw without a bias: the noise streams stay as they were
        return bias, (sigma if sigma.any() else None)

    def observe(self) -> SimState:
        p, cid, body = self.p, self.client, self.body
        s = self.params.sensors
        n_act = len(self._act)
        states = self._joint_states = p.getJointStates(body, self._read, physicsClientId=cid)
        positions, velocities, reactions, applied = zip(*states)
        q = np.array(positions[:n_act])
        v = np.array(velocities[:n_act])
        T_world_base, com, v_origin, omega = self._base_kinematics()
        R = T_world_base[:3, :3]
        quaternion = frames.matrix_to_quat(R)
        gyro = R.T @ omega
        q_pin = np.concatenate([T_world_base[:3, 3], quaternion, q])
        v_pin = np.concatenate([R.T @ v_origin, gyro, v])
        ft = {}
        if self._ft_order:
            # parent-on-child wrench in the child's inertial frame (torque about its COM) -> child
            # link frame, torque about its origin; negated: the distal side on the proximal side
            reaction = np.array(reactions[self._ft_rows])  # (k, 6)
            force = np.einsum("kij,kj->ki", self._ft_R, reaction[:, :3])
            torque = np.einsum("kij,kj->ki", self._ft_R, reaction[:, 3:])
            # torque about the link origin += r x force, r the COM in the link frame
            torque += self._ft_t_yzx * force.take(_ZXY, axis=1) - self._ft_t_zxy * force.take(_YZX, axis=1)
            force, torque = -force, -torque
            if self._ft_bias is not None:
                force += self._ft_bias[:, :3]
                torque += self._ft_bias[:, 3:]
            if self._ft_sigma is not None:  # (k, 6) [N], [N m]
                noise = self.rng.normal(0.0, 1.0, self._ft_sigma.shape) * self._ft_sigma
                force += noise[:, :3]
                torque += noise[:, 3:]
            for k, sensor in enumerate(self._ft_order):
                ft[sensor] = Wrench(force[k], torque[k])
        accel = R.T @ (self._imu_acc - self._gravity_in_world)
        if s.imu_gyro_noise_std:
            gyro = gyro + self.rng.normal(0.0, s.imu_gyro_noise_std, 3)
        if s.imu_accel_noise_std:
            accel = accel + self.rng.normal(0.0, s.imu_accel_noise_std, 3)
        q_meas, v_meas = q, v
        if s.joint_position_noise_std:
            q_meas = q + self.rng.normal(0.0, s.joint_position_noise_std, n_act)
        if s.joint_velocity_noise_std:
            v_meas = v + self.rng.normal(0.0, s.joint_velocity_noise_std, n_act)
        actuators = self.actuators
        tau = actuators.tau.copy()
        if self._any_position:
            sel = np.flatnonzero(self._position_mask)
            tau[sel] = [applied[j] for j in sel]
        tripped = () if actuators.all_powered(self.time) else \
            tuple(nm for nm, t in zip(self.joint_names, actuators.tripped(self.time)) if t)
        return SimState(
            stamp_ns=self.stamp_ns, joint_names=self.joint_names, q=q_meas, v=v_meas,
            tau=tau, motor_current=actuators.motors.current.copy(), tripped=tripped, ft=ft,
            imu=ImuReading(self.root_link, quaternion, gyro, accel),
            base=BaseTruth(self.root_link, T_world_base, v_origin, omega, q_pin, v_pin),
            contact_forces=self.contact_forces(), grasps=self.grasps.latched_surfaces(),
            finger_positions=dict(self._finger_positions), fell=self.fell, fall_reason=self.fall_reason,
            balls=[self._ball_state(b) for b in self.balls])

    def contact_forces(self) -> dict[str, np.ndarray]:
        """limb -> (3,) [N] total force the environment (ground, ladder) applies on the limb's links,
        world frame (grasp constraint forces excluded: see GraspManager.constraint_force())."""
        total = self._scan_contacts()[0]
        return {limb: np.array(total[k]) for k, limb in enumerate(LIMBS)}

    @staticmethod
    def _contact_force_on_a(c: tuple) -> np.ndarray:
        """Force on body A of a getContactPoints row (normal along contactNormalOnB, B -> A)."""
        return (c[9] * np.asarray(c[7]) + c[10] * np.asarray(c[11]) + c[12] * np.asarray(c[13]))

    def ground_reaction(self) -> np.ndarray:
        """(3,) [N] total force of the ground on the robot, world frame."""
        total = np.zeros(3)
        for c in self.p.getContactPoints(bodyA=self.body, bodyB=self.ground_body, physicsClientId=self.client):
            total += self._contact_force_on_a(c)
        return total

    # ============================================================================ falls
    def _check_fall(self) -> None:
        if self.fell:
            return
        T_world_base = self._base_kinematics()[0]
        threshold = self._fall_height
        reason = ""
        if T_world_base[2, 3] < threshold:
            reason = f"base height {T_world_base[2, 3]:.3f} m < {threshold:.3f} m"
        else:
            c = self._scan_contacts()[1]
            if c is not None:
                reason = f"{self._link_names[c[3]]} touches the ground ({c[9]:.0f} N)"
        if reason:
            self.fell, self.fall_reason = True, reason
            self._emit("fall", f"fall at t = {self.time:.3f} s: {reason}", 2, reason=reason)

    # ============================================================================ requests
    def _gripper(self, request: GripperRequest) -> None:
        if request.command == GRIPPER_CLOSE:
            self.grasps.close(request.hand, 1.0)
        elif request.command == GRIPPER_OPEN:
            self.grasps.open(request.hand)
        else:
            self.grasps.position(request.hand, request.position)

    def set_finger_target(self, hand: str, closed_fraction: float) -> None:
        idx = self.hand_fingers.get(hand, [])
        for k in idx:
            self.finger_target[k] = closed_fraction
        self._set_finger_goal()
        if hand in self._finger_positions:
            self._finger_positions[hand] = float(np.mean(self.finger_target[idx])) if idx else 0.0

    def set_grip_strength(self, newtons: float) -> None:
        """Change the grip strength of both hands [N] (applies to latched grasps at once)."""
        if not newtons > 0 or not math.isfinite(newtons):
            raise SpecError("grip_strength", f"must be > 0 [N], got {newtons}")
        self.grip_strength = float(newtons)
        self.grasps.set_max_force(self.grip_strength)

    def _perturb(self, request: PerturbRequest) -> None:
        if request.kind == "drop":
            self._drop(request)
        elif request.kind == "rung_offset":
            name = f"rung_{int(request.rung)}"
            if name not in self.env_bodies:
                self._emit("perturbation", f"rung_offset ignored: no rung {request.rung} "
                           f"(the ladder has {self.env.n_rungs})", 2, rung=request.rung)
                return
            offset = self.env.T_world_ladder[:3, :3] @ np.array([request.dx, 0.0, request.dz])
            self._move_surface(name, offset)
            self._emit("perturbation", f"rung {request.rung} moved by dx = {request.dx:.3f} m, "
                       f"dz = {request.dz:.3f} m", 1, rung=request.rung, dx=request.dx, dz=request.dz)
        else:
            rails = [nm for nm in self.env_bodies if nm.startswith("rail_")]
            if not rails:
                self._emit("perturbation", "rails_shift ignored: the ladder has no rails", 2)
                return
            offset = self.env.T_world_ladder[:3, :3] @ np.array([0.0, request.dy, 0.0])
            for name in rails:
                self._move_surface(name, offset)
            self._emit("perturbation", f"rails shifted by dy = {request.dy:.3f} m", 1, dy=request.dy)

    def check_perturbation(self, request: PerturbRequest) -> None:
        """Refuse (SpecError naming the field, with the limit) what this world cannot carry out."""
        lim = self.params.perturbation
        f = "perturbation"
        if request.kind == "drop":
            self.resolve_link(request.target_link)
            for name, limit, unit in (("mass", lim.max_mass_kg, "kg"), ("radius", lim.max_radius_m, "m"),
                                      ("speed", lim.max_speed_mps, "m/s")):
                if getattr(request, name) > limit:
                    raise SpecError(f"{f}.{name}", f"must be <= {limit} [{unit}] "
                                    f"(perturbation.max_*), got {getattr(request, name)}")
        elif request.kind == "rung_offset":
            n = self.env.n_rungs if self.env is not None else 0
            if not 1 <= int(request.rung) <= n or f"rung_{int(request.rung)}" not in self.env_bodies:
                raise SpecError(f"{f}.rung", f"no rung {request.rung}: the ladder has rungs 1..{n}")
            offsets = (("dx", request.dx), ("dz", request.dz))
        else:
            if not any(name.startswith("rail_") for name in self.env_bodies):
                raise SpecError(f"{f}.kind", "rails_shift: the ladder has no rails")
            offsets = (("dy", request.dy),)
        if request.kind != "drop":
            for name, value in offsets:
                if abs(value) > lim.max_offset_m:
                    raise SpecError(f"{f}.{name}", f"|{name}| must be <= {lim.max_offset_m} [m] "
                                    f"(perturbation.max_offset_m), got {value}")

    def contacts(self):
        """The sim-only judge's view of the contacts now (sim_bridge.contacts.ContactsSnapshot)."""
        from .contacts import contacts_snapshot

        return contacts_snapshot(self)

    def _move_surface(self, name: str, offset_in_world: np.ndarray) -> None:
        p, cid = self.p, self.client
        body = self.env_bodies[name]
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        p.resetBasePositionAndOrientation(body, (np.asarray(pos) + offset_in_world).tolist(), orn,
                                          physicsClientId=cid)
        self.grasps.surface_moved(name, offset_in_world)

    def surface_frame(self, name: str) -> np.ndarray:
        """Current T_world_surface of an environment surface (after run-time perturbations)."""
        from climb_core.environment import R_SURFACE_CYLINDER

        surface = self.env.surfaces[name]
        pos, orn = self.p.getBasePositionAndOrientation(self.env_bodies[name], physicsClientId=self.client)
        T = frames.pose_matrix(pos, orn)
        if surface.shape == "cylinder":
            T[:3, :3] = T[:3, :3] @ R_SURFACE_CYLINDER.T
        return T

    def resolve_link(self, name: str) -> int:
        """A link index from a URDF link name, ``<name>_link``, or a limb name."""
        for candidate in (name, f"{name}_link"):
            if candidate in self.link_index:
                return self.link_index[candidate]
        if name in self.limb_link:
            return self.limb_link[name]
        raise SpecError("perturbation.target_link", f"unknown link {name!r} of {self.robot.config.name}")

    def _drop(self, request: PerturbRequest) -> None:
        p, cid = self.p, self.client
        try:
            link = self.resolve_link(request.target_link)
        except SpecError as err:
            self._emit("perturbation", f"drop ignored: {err}", 2)
            return
        d = self.params.drops
        direction = np.asarray(request.direction or d.direction, dtype=float)
        direction /= np.linalg.norm(direction)
        if link == -1:
            target = self._base_kinematics()[1]
        else:
            target = np.asarray(p.getLinkState(self.body, link, physicsClientId=cid)[0])
        # spawn just clear of the first body on the ray toward the target, at the requested speed
        ray_from = target - direction * d.start_distance_m
        hit = p.rayTest(ray_from.tolist(), target.tolist(), physicsClientId=cid)[0]
        surface = np.asarray(hit[3]) if hit[0] >= 0 else target
        start = surface - direction * (request.radius + d.clearance_m)
        g_along = float(np.dot([0.0, 0.0, -self.params.physics.gravity], direction))
        gap = float(np.linalg.norm(surface - start)) - request.radius
        v0 = math.sqrt(max(request.speed ** 2 - 2.0 * g_along * gap, 0.0))
        shape = p.createCollisionShape(p.GEOM_SPHERE, radius=request.radius, physicsClientId=cid)
        visual = -1
        if self.params.gui:
            visual = p.createVisualShape(p.GEOM_SPHERE, radius=request.radius, rgbaColor=[0.8, 0.1, 0.1, 1.0],
                                         physicsClientId=cid)
        ball = p.createMultiBody(baseMass=request.mass, baseCollisionShapeIndex=shape, baseVisualShapeIndex=visual,
                                 basePosition=start.tolist(), physicsClientId=cid)
        p.changeDynamics(ball, -1, restitution=d.restitution, lateralFriction=world_bodies.robot_lateral_friction(self.env),
                         physicsClientId=cid)
        p.resetBaseVelocity(ball, (v0 * direction).tolist(), [0.0, 0.0, 0.0], physicsClientId=cid)
        self.balls.append(_Ball(ball, request.mass, self.time, v0 * direction))
        self._emit("drop", f"ball of {request.mass:.1f} kg, r = {request.radius:.2f} m thrown at "
                   f"{request.target_link} at {request.speed:.1f} m/s", 1, mass_kg=request.mass,
                   speed_mps=request.speed, target=request.target_link, body=ball)

    def _track_balls(self, dt: float) -> None:
        for ball in self.balls:
            contacts = self.p.getContactPoints(bodyA=ball.body, bodyB=self.body, physicsClientId=self.client)
            ball.touching = bool(contacts)
            for c in contacts:
                ball.impulse_on_robot -= self._contact_force_on_a(c) * dt  # reaction on the robot

    def _ball_state(self, ball: _Ball) -> BallState:
        pos, _ = self.p.getBasePositionAndOrientation(ball.body, physicsClientId=self.client)
        lin, _ = self.p.getBaseVelocity(ball.body, physicsClientId=self.client)
        return BallState(ball.body, ball.mass, np.asarray(pos), np.asarray(lin), ball.impulse_on_robot.copy(),
                         ball.touching, ball.launch_time, ball.launch_velocity.copy())

    # ============================================================================ misc
    def close(self) -> None:
        if self.client is not None:
            try:
                self.p.disconnect(physicsClientId=self.client)
            except self.p.error:  # pragma: no cover - already gone
                pass
            self.client = None

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
