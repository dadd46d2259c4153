"""The `sim_bridge` executable: a thin rclpy node around sim_bridge.bridge.SimBridge.

Messages in -> SimBridge (validation, lock-step, watchdog) -> PyBullet backend -> messages out.
Parameters: config/nodes/sim_bridge.yaml (``--ros-args --params-file ...`` overrides it); topics and
their QoS: sim_bridge.topics / docs/sim_bridge.md.
"""
from __future__ import annotations

import array
import sys
import time
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from climb_msgs.msg import GripperCommand, JointCommand
from climb_msgs.srv import SimPerturb, SimReset
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState

from climb_core.errors import ClimbError, SpecError
from climb_core.params import describe, flatten, parse_params
from climb_core.ros_env import apply_local_dds_env

from .backend import ResetRequest, SimState
from .bridge import Diagnostic, SimBridge
from .commands import GripperRequest, PerturbRequest
from .params import NODE_NAME, BridgeParams, load_bridge_params
from .pybullet_backend import PyBulletBackend
from .topics import TOPICS

_NS = 1_000_000_000


def qos(topic: str) -> QoSProfile:
    spec = TOPICS[topic]
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth,
                      reliability=ReliabilityPolicy.RELIABLE if spec.reliability == "reliable"
                      else ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)


def to_time(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // _NS), nanosec=int(stamp_ns % _NS))


def to_ns(stamp: Time) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)


_PARAM_TYPES = {"bool": Parameter.Type.BOOL, "int": Parameter.Type.INTEGER, "float": Parameter.Type.DOUBLE,
                "str": Parameter.Type.STRING, "float_array": Parameter.Type.DOUBLE_ARRAY}


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
        self._msgs_robot = None  # the robot the preallocated state messages were built for
        self._clock_msg = Clock()
        self._clock_stamp_ns = -1  # [ns] last /clock published
        if self.pub_clock is not None:
            # /clock = t goes out as soon as the physics reaches t, before the sensors are read and
            # the state is published: DDS does not order topics, this lead keeps /clock first
            self.bridge.after_advance = self._publish_clock
        self.create_subscription(JointCommand, "joint_command", self._on_command, qos("joint_command"))
        self.create_subscription(GripperCommand, "gripper_command", self._on_gripper, qos("gripper_command"))
        self.create_service(SimReset, "sim/reset", self._on_reset)
        self.create_service(SimPerturb, "sim/perturb", self._on_perturb)
        self.get_logger().info(f"{p.execution} bridge: {self.backend.robot.config.name} on "
                               f"{self.backend.scenario.name or 'ladder'}, control period {p.physics.control_period_s} s")

    # -- parameters -----------------------------------------------------------------------------
    def _declare_params(self) -> BridgeParams:
        defaults = flatten(load_bridge_params())
        infos = describe(BridgeParams)
        for name, value in defaults.items():
            info = infos[name]
            if info.is_array and not value:
                self.declare_parameter(name, Parameter.Type.DOUBLE_ARRAY)
            else:
                self.declare_parameter(name, value)
        values: dict[str, Any] = {}
        for name in defaults:
            value = self.get_parameter(name).value
            values[name] = list(value) if isinstance(value, (list, tuple, array.array)) else value
        return parse_params(values, BridgeParams, NODE_NAME)

    def _make_ft_publishers(self) -> None:
        for sensor in self.backend.ft_joints:
            if sensor not in self.pub_ft:
                self.pub_ft[sensor] = self.create_publisher(WrenchStamped, f"ft/{sensor}", qos("ft/<sensor>"))

    # -- inputs ---------------------------------------------------------------------------------
    def _on_command(self, msg: JointCommand) -> None:
        self.callbacks += 1
        self.bridge.offer_command(msg.names, msg.modes, msg.values, to_ns(msg.header.stamp), time.monotonic())

    def _on_gripper(self, msg: GripperCommand) -> None:
        self.callbacks += 1
        try:
            request = GripperRequest(msg.hand, int(msg.command), float(msg.position), to_ns(msg.header.stamp))
        except SpecError as err:
            self._publish_diagnostics([Diagnostic(2, "sim_bridge/gripper", f"rejected gripper_command: {err}",
                                                  {"field": err.field, "rule": err.rule})])
            return
        self.bridge.offer_gripper(request)

    def _on_reset(self, request: SimReset.Request, response: SimReset.Response) -> SimReset.Response:
        self.callbacks += 1
        try:
            self.bridge.reset(ResetRequest(
                robot=request.robot, ladder=request.ladder or None, initial_posture=request.initial_posture,
                q=np.asarray(request.q, dtype=float) if len(request.q) else None, seed=int(request.seed)))
            self._make_ft_publishers()
            self._restart = True
            self._clock_stamp_ns = -1  # time restarts: publish /clock = 0 again with the new state
            response.success = True
        except (ClimbError, ValueError, OSError) as err:
            response.success = False
            response.error = str(err)
            self.get_logger().error(f"sim/reset failed: {err}")
        return response

    def _on_perturb(self, request: SimPerturb.Request, response: SimPerturb.Response) -> SimPerturb.Response:
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
        """State messages are built once per robot and updated in place every tick (names, frames
        and covariances do not change; a publish serializes the message at once)."""
        b = self.backend
        self._msgs_robot = b.robot
        self._js = JointState()
        self._js.name = list(b.joint_names)
        self._ft_msgs = {}
        for sensor, joint in b.ft_joints.items():
            msg = WrenchStamped()
            msg.header.frame_id = b.link_name(joint)
            self._ft_msgs[sensor] = msg
        s = self.params.sensors
        self._imu = Imu()
        self._imu.header.frame_id = b.root_link
        self._imu.angular_velocity_covariance[0::4] = [s.imu_gyro_noise_std ** 2] * 3
        self._imu.linear_acceleration_covariance[0::4] = [s.imu_accel_noise_std ** 2] * 3
        self._odom = Odometry()
        self._odom.header.frame_id = "world"
        self._odom.child_frame_id = b.root_link

    def _publish_clock(self, stamp_ns: int) -> None:
        self._clock_msg.clock = to_time(stamp_ns)
        self.pub_clock.publish(self._clock_msg)
        self._clock_stamp_ns = stamp_ns

    def publish_state(self, state: SimState) -> None:
        if self._msgs_robot is not self.backend.robot:
            self._build_messages()
        stamp = to_time(state.stamp_ns)
        if self.pub_clock is not None and self._clock_stamp_ns != state.stamp_ns:
            self._publish_clock(state.stamp_ns)  # t = 0, after a reset, or a state published again
        js = self._js
        js.header.stamp = stamp
        js.position = array.array("d", state.q.tobytes())
        js.velocity = array.array("d", state.v.tobytes())
        js.effort = array.array("d", state.tau.tobytes())
        self.pub_joints.publish(js)
        for sensor, wrench in state.ft.items():
            msg = self._ft_msgs[sensor]
            msg.header.stamp = stamp
            f, t = wrench.force.tolist(), wrench.torque.tolist()
            force, torque = msg.wrench.force, msg.wrench.torque
            force.x, force.y, force.z = f
            torque.x, torque.y, torque.z = t
            self.pub_ft[sensor].publish(msg)
        imu = self._imu
        imu.header.stamp = stamp
        o = imu.orientation
        o.x, o.y, o.z, o.w = state.imu.quaternion_xyzw.tolist()
        w, a = imu.angular_velocity, imu.linear_acceleration
        w.x, w.y, w.z = state.imu.angular_velocity.tolist()
        a.x, a.y, a.z = state.imu.linear_acceleration.tolist()
        self.pub_imu.publish(imu)
        odom = self._odom
        odom.header.stamp = stamp
        pos = state.base.q[:7].tolist()
        position, o = odom.pose.pose.position, odom.pose.pose.orientation
        position.x, position.y, position.z = pos[:3]
        o.x, o.y, o.z, o.w = pos[3:7]
        v = state.base.v[:6].tolist()
        tw = odom.twist.twist
        tw.linear.x, tw.linear.y, tw.linear.z = v[:3]
        tw.angular.x, tw.angular.y, tw.angular.z = v[3:]
        self.pub_truth.publish(odom)

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
        published before the match), at most lockstep.startup_wait_s of wall time."""
        deadline = time.monotonic() + self.params.lockstep.startup_wait_s
        while rclpy.ok() and time.monotonic() < deadline:
            if self.count_publishers("joint_command") > 0 and self.pub_joints.get_subscription_count() > 0:
                executor.spin_once(timeout_sec=0.2)  # let the matching settle on both sides
                return True
            executor.spin_once(timeout_sec=0.05)
        self.get_logger().warning("no controller connected yet: starting the lock-step anyway")
        return False

    def run_lockstep(self, executor: Executor) -> None:
        self.wait_for_controller(executor)
        while rclpy.ok() and not self._done():
            self._restart = False
            self.publish_state(self.bridge.state)
            self.flush_diagnostics()
            deadline = time.monotonic() + self.bridge.wait_budget()
            while not self.bridge.command_ready() and not self._restart:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    break
                executor.spin_once(timeout_sec=min(remaining, 0.1))
            if self._restart:
                continue  # reset while waiting: publish the new t = 0 state
            self.bridge.step_lockstep()
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
        while rclpy.ok() and not self._done():
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


def make_executor() -> Executor:
    """rclpy's EventsExecutor (C++ event queue: about half the CPU of SingleThreadedExecutor per
    message, FIELD_NOTES; it doubled the lock-step rate over ROS), else SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - rclpy before Jazzy
        return SingleThreadedExecutor()
    return EventsExecutor()


def main(args: list[str] | None = None) -> int:
    apply_local_dds_env()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = SimBridgeNode()
        executor = make_executor()
        executor.add_node(node)
        if node.params.execution == "lockstep":
            node.run_lockstep(executor)
        else:
            node.run_realtime(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ClimbError, ValueError) as err:
        print(f"sim_bridge: {err}", file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.backend.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
