"""The sim_bridge node: a thin rclpy node around sim_bridge.bridge.SimBridge (the executable's
entry point is sim_bridge.node.main, light, which installs the signal handlers before importing
this module).

Messages in -> SimBridge (validation, lock-step, watchdog) -> PyBullet backend -> messages out.
Parameters: config/nodes/sim_bridge.yaml (``--ros-args --params-file ...`` overrides it), declared
from the schema with descriptors (msgs_py.node_kit.declare_from_schema); read-only except
:data:`LIVE_PARAMS`. Topics and their QoS: msgs_py.topics / docs/sim_bridge.md. Bad input never
kills the node: undecodable messages, refused commands, refused service requests are answered or
reported on ``diagnostics`` (docs/interfaces.md).

Hot path: the state messages (joint_states, ft/*, imu, sim/base_truth, /clock) are serialized once
per robot and published as CDR bytes with only the stamp and the numbers rewritten each tick
(msgs_py.cdr.Template: the same bytes as rclpy's, ~4x cheaper per publish than rclpy's field-by-field
conversion), and joint_command is taken raw (``raw=True``) and decoded by msgs_py.cdr. The node-level
parameter ``cpu_affinity`` pins the process (all threads) to the given CPUs (see controller_node.node).
"""
from __future__ import annotations

import array
import time

import numpy as np
from builtin_interfaces.msg import Time
from climb_msgs.msg import GripperCommand, JointCommand, SimContacts
from climb_msgs.srv import SimPerturb, SimReset
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from climb_core.errors import ClimbError, SpecError
from climb_core.params import describe
from msgs_py import cdr, node_kit
from msgs_py.topics import qos_for

from .backend import ResetRequest, SimState
from .bridge import Diagnostic, SimBridge
from .commands import GripperRequest, PerturbRequest
from .contacts import ContactsSnapshot
from .params import NODE_NAME, BridgeParams, load_bridge_params
from .pybullet_backend import PyBulletBackend

_NS = 1_000_000_000

#: parameters a set_parameters call may change while running (read each tick); every other one is
#: read-only (the world is built from it: use sim/reset, or restart the node)
LIVE_PARAMS = ("max_ticks", "lockstep.command_timeout_s", "lockstep.lost_retry_s", "lockstep.startup_wait_s",
               "lockstep.resend_s", "realtime.watchdog_s", "diagnostics.period_s", "contacts.rate_hz")
#: errors a raw message's decoding may raise (ours, then rclpy's / Fast CDR's)
_DECODE_ERRORS = (cdr.CdrError, IndexError, OverflowError, UnicodeDecodeError) + node_kit.DESERIALIZE_ERRORS


def qos(topic: str):
    """The topic's QoSProfile (msgs_py.topics, the graph's one table)."""
    return qos_for(topic)


def to_time(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // _NS), nanosec=int(stamp_ns % _NS))


def to_ns(stamp: Time) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)



def check_service_sources(robot: str, ladder: str) -> None:
    """A service request names a shipped robot and a shipped ladder or gives the spec's YAML text;
    a file path is refused (a request over ROS must not make the node read files; the start-up
    parameters may name paths). Empty = keep the current one."""
    from climb_core.ladder import available_ladders
    from climb_core.robot import available_robots

    if robot and robot not in available_robots():
        raise SpecError("robot", f"unknown robot {robot[:80]!r} (available: {', '.join(available_robots())}; "
                                 "a file path is refused over the service)")
    text = ladder.strip()
    if text and "\n" not in ladder and not any(c in text for c in ":{[") and text not in available_ladders():
        raise SpecError("ladder", f"no ladder named {text[:80]!r} (known: {', '.join(available_ladders())}); or give "
                                  "the spec's YAML text (a file path is refused over the service)")


class SimBridgeNode(Node):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.params = self._declare_params()
        self.backend = PyBulletBackend(self.params)
        self.bridge = SimBridge(self.backend, self.params)
        p = self.params
        self.bridge.reset(ResetRequest(robot=p.robot, ladder=p.ladder, initial_posture=p.initial_posture,
                                       seed=p.seed))
        self._restart = False
        self.callbacks = 0  # callbacks run so far (to drain the executor without blocking)
        self.pub_joints = self.create_publisher(JointState, "joint_states", qos("joint_states"))
        self.pub_ft = {}
        self._make_ft_publishers()
        self.pub_imu = self.create_publisher(Imu, "imu", qos("imu"))
        self.pub_truth = self.create_publisher(Odometry, "sim/base_truth", qos("sim/base_truth"))
        self.pub_clock = self.create_publisher(Clock, "/clock", qos("/clock")) if p.execution == "lockstep" else None
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", qos("diagnostics"))
        node_kit.set_diagnostics_publisher(self, self.pub_diag)
        self.pub_contacts = self.create_publisher(SimContacts, "sim/contacts", qos("sim/contacts"))
        self._next_contacts_ns = 0  # [ns] sim time of the next sim/contacts
        self._msgs_robot = None  # the robot the preallocated state messages were built for
        # (not self._clock: that is rclpy's Node._clock, used by set_parameters; issue 20 row 3)
        self._clock_msg = cdr.Template(serialize_message(Clock()), cdr.locate_clock)
        self._clock_stamp_ns = -1  # [ns] last /clock published
        self._command_reader = cdr.JointCommandReader()
        if self.pub_clock is not None:
            # /clock = t goes out as soon as the physics reaches t, before the sensors are read and
            # the state is published: DDS does not order topics, this lead keeps /clock first
            self.bridge.after_advance = self._publish_clock
        # both subscriptions raw: an undecodable message is reported here instead of failing
        # inside the executor (issue 20 row 5)
        self.create_subscription(JointCommand, "joint_command", node_kit.guarded(self, self._on_command, "joint_command"),
                                 qos("joint_command"), raw=True)
        self.create_subscription(GripperCommand, "gripper_command",
                                 node_kit.guarded(self, self._on_gripper, "gripper_command"),
                                 qos("gripper_command"), raw=True)
        self.create_service(SimReset, "sim/reset", node_kit.guarded(self, self._on_reset, "sim/reset"))
        self.create_service(SimPerturb, "sim/perturb", node_kit.guarded(self, self._on_perturb, "sim/perturb"))
        self.get_logger().info(f"{p.execution} bridge: {self.backend.robot.config.name} on "
                               f"{self.backend.scenario.name or 'ladder'}, control period {p.physics.control_period_s} s"
                               + (f", commands act {p.lockstep.command_delay_ticks} tick late"
                                  if p.execution == "lockstep" and p.lockstep.command_delay_ticks else ""))

    def destroy_node(self) -> None:
        """Disconnects the simulator too (every owner of the node: the executable, sim_graph)."""
        self.backend.close()
        super().destroy_node()

    # -- parameters -----------------------------------------------------------------------------
    def _declare_params(self) -> BridgeParams:
        live = set(LIVE_PARAMS)
        params = node_kit.declare_from_schema(self, BridgeParams, load_bridge_params(),
                                              read_only=[n for n in describe(BridgeParams) if n not in live],
                                              on_change=self._on_params)
        # a node-level setting: empty = the inherited CPU set (an empty list cannot be typed in YAML)
        node_kit.declare_array(self, "cpu_affinity", Parameter.Type.INTEGER_ARRAY, ParameterDescriptor(
            description="CPUs every thread of this process runs on, set at start-up (empty: the inherited "
                        "set) [-]", read_only=True))
        return params

    def _on_params(self, params: BridgeParams) -> None:
        """A validated change of the live parameters: the bridge and the backend read them each tick."""
        self.params = params
        self.bridge.params = params
        self.backend.params = params

    def _make_ft_publishers(self) -> None:
        for sensor in self.backend.ft_joints:
            if sensor not in self.pub_ft:
                self.pub_ft[sensor] = self.create_publisher(WrenchStamped, f"ft/{sensor}", qos("ft/<sensor>"))

    # -- inputs ---------------------------------------------------------------------------------
    def _reject_bytes(self, topic: str, data: bytes, err: Exception) -> None:
        self._publish_diagnostics([Diagnostic(2, f"sim_bridge/{topic}", f"rejected {topic}: undecodable message "
                                              f"({len(data)} bytes): {type(err).__name__}: {err}",
                                              {"bytes": str(len(data))})])

    def _on_command(self, data: bytes) -> None:
        self.callbacks += 1
        try:
            try:
                c = self._command_reader.read(data)
                names, modes, values, stamp = c.names, c.modes, c.values, c.stamp_ns
            except cdr.CdrError:  # another encapsulation: rclpy's deserialization
                msg = deserialize_message(data, JointCommand)
                names, modes, values, stamp = msg.names, msg.modes, msg.values, to_ns(msg.header.stamp)
        except _DECODE_ERRORS as err:
            self._reject_bytes("joint_command", data, err)
            return
        self.bridge.offer_command(names, modes, values, stamp, time.monotonic())

    def _on_gripper(self, data: bytes) -> None:
        self.callbacks += 1
        try:
            msg = deserialize_message(data, GripperCommand)
        except _DECODE_ERRORS as err:
            self._reject_bytes("gripper_command", data, err)
            return
        try:
            request = GripperRequest(msg.hand, int(msg.command), float(msg.position), to_ns(msg.header.stamp))
        except SpecError as err:
            self._publish_diagnostics([Diagnostic(2, "sim_bridge/gripper", f"rejected gripper_command: {err}",
                                                  {"field": err.field, "rule": err.rule})])
            return
        self.bridge.offer_gripper(request)

    def _on_reset(self, request: SimReset.Request, response: SimReset.Response) -> SimReset.Response:
        """Everything is loaded and checked before the world changes: a refused reset keeps the
        world, the sim time and the last good robot / ladder (issue 20 row 7)."""
        self.callbacks += 1
        try:
            check_service_sources(request.robot, request.ladder)
            self.bridge.reset(ResetRequest(
                robot=request.robot, ladder=request.ladder or None, initial_posture=request.initial_posture,
                q=np.asarray(request.q, dtype=float) if len(request.q) else None, seed=int(request.seed)))
        except (ClimbError, ValueError, OSError) as err:
            response.success = False
            response.error = str(err)
            self.get_logger().error(f"sim/reset refused: {err}")
            return response
        self._make_ft_publishers()
        self.bridge.await_first_command()
        self._restart = True
        self._clock_stamp_ns = -1  # time restarts: publish /clock = 0 again with the new state
        self._next_contacts_ns = 0
        response.success = True
        return response

    def _on_perturb(self, request: SimPerturb.Request, response: SimPerturb.Response) -> SimPerturb.Response:
        """Refused with the reason, before anything is queued, when the request is malformed or
        this world cannot carry it out (issue 20 row 8)."""
        self.callbacks += 1
        try:
            self.bridge.offer_perturbation(PerturbRequest(
                int(request.kind), mass=request.mass, radius=request.radius, speed=request.speed,
                target_link=request.target_link, rung=int(request.rung), dx=request.dx, dy=request.dy,
                dz=request.dz, at_time=request.at_time))
            response.success = True
        except SpecError as err:
            response.success = False
            response.error = str(err)
        return response

    # -- outputs --------------------------------------------------------------------------------
    def _build_messages(self) -> None:
        """State messages are serialized once per robot (names, frames and covariances do not
        change); every tick rewrites the stamp and the numbers of these templates."""
        b = self.backend
        self._msgs_robot = b.robot
        n = len(b.joint_names)
        zeros = array.array("d", bytes(8 * n))
        self._js = cdr.Template(serialize_message(JointState(name=list(b.joint_names), position=zeros,
                                                             velocity=zeros, effort=zeros)),
                                cdr.locate_joint_state)
        self._ft_msgs = {}
        for sensor, joint in b.ft_joints.items():
            msg = WrenchStamped()
            msg.header.frame_id = b.link_name(joint)
            self._ft_msgs[sensor] = cdr.Template(serialize_message(msg), cdr.locate_wrench_stamped)
        s = self.params.sensors
        imu = Imu()
        imu.header.frame_id = b.root_link
        imu.angular_velocity_covariance[0::4] = [s.imu_gyro_noise_std ** 2] * 3
        imu.linear_acceleration_covariance[0::4] = [s.imu_accel_noise_std ** 2] * 3
        self._imu = cdr.Template(serialize_message(imu), cdr.locate_imu)
        odom = Odometry()
        odom.header.frame_id = "world"
        odom.child_frame_id = b.root_link
        self._odom = cdr.Template(serialize_message(odom), cdr.locate_odometry)

    def _publish_clock(self, stamp_ns: int) -> None:
        self._clock_msg.set_stamp(stamp_ns)
        self.pub_clock.publish(self._clock_msg.payload())
        self._clock_stamp_ns = stamp_ns

    def publish_state(self, state: SimState) -> None:
        if self._msgs_robot is not self.backend.robot:
            self._build_messages()
        stamp = state.stamp_ns
        if self.pub_clock is not None and self._clock_stamp_ns != stamp:
            self._publish_clock(stamp)  # t = 0, after a reset, or a state published again
        js = self._js
        js.set_stamp(stamp)
        js.field("position")[:] = state.q
        js.field("velocity")[:] = state.v
        js.field("effort")[:] = state.tau
        self.pub_joints.publish(js.payload())
        for sensor, wrench in state.ft.items():
            msg = self._ft_msgs[sensor]
            msg.set_stamp(stamp)
            w = msg.field("wrench")
            w[:3] = wrench.force
            w[3:] = wrench.torque
            self.pub_ft[sensor].publish(msg.payload())
        imu = self._imu
        imu.set_stamp(stamp)
        imu.field("orientation")[:] = state.imu.quaternion_xyzw
        imu.field("angular_velocity")[:] = state.imu.angular_velocity
        imu.field("linear_acceleration")[:] = state.imu.linear_acceleration
        self.pub_imu.publish(imu.payload())
        # last: a lock-step controller computes once this one is in (an IMU arriving after it
        # would interrupt the controller's tick on its core)
        odom = self._odom
        odom.set_stamp(stamp)
        odom.field("pose")[:] = state.base.q[:7]
        odom.field("twist")[:] = state.base.v[:6]
        self.pub_truth.publish(odom.payload())
        rate = self.params.contacts.rate_hz
        if rate > 0.0 and stamp >= self._next_contacts_ns:
            self.pub_contacts.publish(self._contacts_msg(self.backend.contacts()))
            self._next_contacts_ns = stamp + max(int(round(1e9 / rate)), 1)

    @staticmethod
    def _contacts_msg(snapshot: ContactsSnapshot) -> SimContacts:
        limbs = snapshot.limbs
        msg = SimContacts(limbs=[c.limb for c in limbs], normal_force=[c.normal_force for c in limbs],
                          tangential_force=[c.tangential_force for c in limbs], surface=[c.surface for c in limbs],
                          rung=[c.rung for c in limbs], grasped=[c.grasped for c in limbs], fell=snapshot.fell,
                          fall_reason=snapshot.fall_reason)
        msg.header.stamp = to_time(snapshot.stamp_ns)
        msg.header.frame_id = "world"
        return msg

    def _publish_diagnostics(self, diagnostics: list[Diagnostic]) -> None:
        if not diagnostics:
            return
        msg = DiagnosticArray()
        msg.header.stamp = to_time(self.bridge.stamp_ns)
        for d in diagnostics:
            msg.status.append(DiagnosticStatus(
                level=bytes([d.level]), name=d.name, message=d.message, hardware_id="sim_bridge",
                values=[KeyValue(key=k, value=v) for k, v in d.values.items()]))
        self.pub_diag.publish(msg)

    def flush_diagnostics(self) -> None:
        self._publish_diagnostics(self.bridge.drain_diagnostics())

    # -- loops ----------------------------------------------------------------------------------
    def _done(self) -> bool:
        return self.params.max_ticks > 0 and self.bridge.ticks >= self.params.max_ticks

    def wait_for_controller(self, executor: Executor) -> bool:
        """Lock-step start: wait until a controller is connected (VOLATILE topics drop what is
        published before the match), at most lockstep.startup_wait_s of wall time. Connected: a
        joint_command publisher, and a subscriber on every state topic the controller ticks on
        (joint_states, base truth, each F/T sensor): each matches on its own, and a state of t
        missing one of them is a tick the controller never answers."""
        deadline = time.monotonic() + self.params.lockstep.startup_wait_s
        state_pubs = [self.pub_joints, self.pub_truth, *self.pub_ft.values()]
        while node_kit.running() and time.monotonic() < deadline:
            if (self.count_publishers("joint_command") > 0
                    and all(pub.get_subscription_count() > 0 for pub in state_pubs)):
                executor.spin_once(timeout_sec=0.2)  # let the matching settle on both sides
                return True
            executor.spin_once(timeout_sec=0.05)
        self.get_logger().warning("no controller connected yet: starting the lock-step anyway")
        return False

    def run_lockstep(self, executor: Executor) -> None:
        self.wait_for_controller(executor)
        while node_kit.running() and not self._done():
            self._restart = False
            start = time.monotonic()
            self.publish_state(self.bridge.state)
            self.flush_diagnostics()
            published = time.monotonic()
            deadline = published + self.bridge.wait_budget()
            resend = self.params.lockstep.resend_s
            resend_at = published + resend
            while not self.bridge.command_ready() and not self._restart:
                now = time.monotonic()
                remaining = deadline - now
                if remaining <= 0.0 or not node_kit.running():
                    break
                if resend > 0.0 and now >= resend_at and self.bridge.awaiting_first_command:
                    # a reader that matched after the first send never gets it (VOLATILE); the
                    # interval doubles: a world waiting minutes for its plan sends a few copies
                    self.publish_state(self.bridge.state)
                    resend *= 2.0
                    resend_at = now + resend
                executor.spin_once(timeout_sec=min(remaining, 0.1))
            if self._restart:
                continue  # reset while waiting: publish the new t = 0 state
            if not node_kit.running():
                return  # a signal mid-tick: stop here, nothing half done
            self.bridge.note_lockstep_times(published - start, time.monotonic() - published)
            self.bridge.step_lockstep()
        if node_kit.running():  # max_ticks reached: the last state too
            self.publish_state(self.bridge.state)
            self.flush_diagnostics()

    def drain(self, executor: Executor, limit: int = 100) -> None:
        """Run every callback that is ready now, without waiting."""
        for _ in range(limit):
            before = self.callbacks
            executor.spin_once(timeout_sec=0.0)
            if self.callbacks == before:
                return

    def run_realtime(self, executor: Executor) -> None:
        period = self.params.physics.control_period_s
        next_tick = time.monotonic()
        while node_kit.running() and not self._done():
            now = time.monotonic()
            if now < next_tick:
                executor.spin_once(timeout_sec=next_tick - now)
                continue
            self.drain(executor)  # even when running late, read what arrived
            if self._restart:
                self._restart = False
                next_tick = time.monotonic()
                self.publish_state(self.bridge.state)
                continue
            self.bridge.step_realtime(time.monotonic())
            self.publish_state(self.bridge.state)
            self.flush_diagnostics()
            next_tick += period
            if time.monotonic() - next_tick > 10 * period:  # fell far behind: do not try to catch up
                next_tick = time.monotonic()


    def run(self, executor: Executor) -> None:
        """Spin in the configured execution mode until a signal, shutdown or max_ticks."""
        if self.params.execution == "lockstep":
            self.run_lockstep(executor)
        else:
            self.run_realtime(executor)


def run(args: list[str] | None = None) -> int:
    """The executable's body (sim_bridge.node.main installs the signal handlers first)."""
    return node_kit.run_node(SimBridgeNode, args, name=NODE_NAME,
                             after_add=lambda nodes, executor: node_kit.apply_cpu_affinity(nodes[0]),
                             loop=lambda nodes, executor, running: nodes[0].run(executor))
