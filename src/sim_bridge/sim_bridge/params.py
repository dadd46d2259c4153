"""Bridge parameters: config/nodes/sim_bridge.yaml parsed once into frozen dataclasses.

The schema below (climb_core.params: every leaf has a default, unit, description and range) is the
single source of the node's parameters: the node declares them from it, the library and the tests
read the same YAML without ROS through :func:`load_bridge_params`.
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass
from typing import Any, Mapping

from climb_core.errors import SpecError
from climb_core.params import default_params_file, flatten, group, load_params, param, parse_params

NODE_NAME = "sim_bridge"


@dataclass(frozen=True)
class PhysicsParams:
    dt_s: float = param(0.001, unit="s", description="physics step (1 kHz)", min=1e-5, max=0.01)
    control_period_s: float = param(0.005, unit="s", description="one control tick of physics", min=1e-5, max=1.0)
    gravity: float = param(9.81, unit="m/s^2", description="gravity magnitude along -z", min=0.0)
    solver_iterations: int = param(50, unit="-", description="PyBullet numSolverIterations", min=1)
    self_collision: bool = param(True, unit="-", description="robot self-collision between chains (touching "
                                 "pairs filtered)")
    self_collision_margin: float = param(0.002, unit="m", min=0.0,
                                         description="pairs closer than this at the reference posture are filtered")
    self_collision_same_chain: bool = param(False, unit="-", description="also check two links of one chain "
                                            "(one leg, one arm with its hand, the trunk) against each other")
    self_collision_fingers: bool = param(False, unit="-", description="also check the finger links against "
                                         "the rest of the robot (they always collide with the environment)")


    @property
    def substeps(self) -> int:
        """Physics steps per control tick."""
        return int(round(self.control_period_s / self.dt_s))

    @property
    def control_period_ns(self) -> int:
        return int(round(self.control_period_s * 1e9))


@dataclass(frozen=True)
class LockstepParams:
    command_timeout_s: float = param(1.0, unit="s", min=1e-3, description="wall time to wait for the command "
                                     "stamped t before the controller is declared lost")
    lost_retry_s: float = param(0.005, unit="s", min=0.0,
                                description="wall time waited per tick once the controller is lost")
    startup_wait_s: float = param(10.0, unit="s", min=0.0, description="wall time to wait at start-up for a "
                                  "controller (a joint_command publisher and a joint_states subscriber)")
    reset_wait_s: float = param(0.0, unit="s", min=0.0, description="wall time a world just reset by "
                                "sim/reset waits for its first command before the controller is declared "
                                "lost, when longer than command_timeout_s (config/graph.yaml: 600 s, the "
                                "climb coordinator activates the controller once the first plan exists and "
                                "the world stays at t = 0 meanwhile; 0: command_timeout_s)")
    resend_s: float = param(0.5, unit="s", min=0.0, description="until the first command of a world arrived, "
                            "the awaited state is published again after resend_s of wall time, then at doubling "
                            "intervals: a controller "
                            "whose subscription matched after the first send (DDS drops what a VOLATILE reader "
                            "missed) still gets it; a controller answers a stamp once and sends the same "
                            "command again for a state it already answered; 0: never")
    command_delay_ticks: int = param(0, unit="-", choices=(0, 1), description="actuation latency in control "
                                     "ticks: 0 applies the command stamped t over [t, t + T) (the bridge waits "
                                     "for it); 1 applies it over [t + T, t + 2T) like a robot whose command "
                                     "lands one period after its sensor read, so the physics of one tick runs "
                                     "while the controller computes the next (the command stamped 0 also covers "
                                     "[0, T))")


@dataclass(frozen=True)
class RealtimeParams:
    watchdog_s: float = param(0.05, unit="s", min=1e-3,
                              description="wall time without a valid command before every joint is damped")


@dataclass(frozen=True)
class ActuationParams:
    damping_gain: float = param(2.0, unit="N m s/rad", min=0.0, description="DAMPING: tau = -gain * qdot")
    position_kp: float = param(3000.0, unit="N m/rad", min=0.0,
                               description="POSITION stiff PD, explicit models (mock backend)")
    position_kd: float = param(10.0, unit="N m s/rad", min=0.0,
                               description="POSITION stiff PD, explicit models (mock backend)")
    position_gain: float = param(0.3, unit="-", min=0.0, max=1.0, description="POSITION in PyBullet: "
                                 "implicit position motor, position error gain (stable at any stiffness)")
    velocity_gain: float = param(1.0, unit="-", min=0.0, max=1.0,
                                 description="POSITION in PyBullet: implicit position motor, velocity gain")
    overcurrent_trip_delay_s: float = param(0.002, unit="s", min=0.0,
                                            description="current above the limit this long trips the driver")
    finger_bandwidth: float = param(150.0, unit="rad/s", min=0.0, max=1000.0, description="finger servo: "
                                    "explicit joint PD, kp = m w^2, kd = 2 zeta m w with m the finger's apparent "
                                    "inertia; torque capped at the finger effort limit")
    finger_damping_ratio: float = param(1.0, unit="-", min=0.0, max=5.0, description="finger servo damping ratio")


@dataclass(frozen=True)
class GraspParams:
    snap_to_axis: bool = param(True, unit="-", description="latch with the grasp centre on the rung/rail axis")
    release_position: float = param(0.5, unit="-", min=0.0, max=1.0,
                                     description="a POSITION gripper request below this opens a latched grasp")
    constraint_erp: float = param(0.2, unit="-", min=0.0, max=1.0, description="grasp constraint error reduction")


@dataclass(frozen=True)
class SensorParams:
    ft_force_noise_std: float = param(0.0, unit="N", min=0.0, description="F/T force white noise")
    ft_torque_noise_std: float = param(0.0, unit="N m", min=0.0, description="F/T torque white noise")
    ft_noise_percent: float = param(0.0, unit="%", min=0.0, max=100.0,
                                    description="F/T white noise: sigma of each force / torque component in % of the "
                                                "sensor's range (robot config ft_ranges), on top of the absolute ones")
    ft_bias_percent: float = param(0.0, unit="%", min=0.0, max=100.0,
                                   description="F/T bias: sigma of a constant offset of each component in % of the "
                                               "sensor's range, drawn at every reset")
    joint_position_noise_std: float = param(0.0, unit="rad", min=0.0, description="joint position noise")
    joint_velocity_noise_std: float = param(0.0, unit="rad/s", min=0.0, description="joint velocity noise")
    imu_gyro_noise_std: float = param(0.0, unit="rad/s", min=0.0, description="gyro noise")
    imu_accel_noise_std: float = param(0.0, unit="m/s^2", min=0.0, description="accelerometer noise")


@dataclass(frozen=True)
class FallParams:
    base_height_fraction: float = param(0.5, unit="-", min=0.0, max=1.0, description="fall when the base is "
                                        "lower than this fraction of the standing base height above the ground")
    ground_contact_force: float = param(1.0, unit="N", min=0.0, description="a non hand/foot link pressing "
                                        "the ground harder than this is a fall")


@dataclass(frozen=True)
class DropParams:
    start_distance_m: float = param(1.5, unit="m", min=0.01, description="a ray this long, ending at the "
                                    "target link's centre of mass, finds the first surface the ball meets")
    clearance_m: float = param(0.02, unit="m", min=0.0, description="the ball spawns this far from that "
                               "surface, with the requested speed (so it hits at that speed)")
    direction: tuple[float, ...] = param((0.0, 0.0, -1.0), unit="-",
                                         description="world direction of flight (dropped from above)")
    restitution: float = param(0.5, unit="-", min=0.0, max=1.0, description="ball restitution")


@dataclass(frozen=True)
class PerturbationLimits:
    max_mass_kg: float = param(50.0, unit="kg", min=0.0, description="sim/perturb refuses a heavier ball")
    max_radius_m: float = param(0.5, unit="m", min=0.0, description="sim/perturb refuses a larger ball")
    max_speed_mps: float = param(30.0, unit="m/s", min=0.0, description="sim/perturb refuses a faster ball")
    max_offset_m: float = param(0.5, unit="m", min=0.0,
                                description="sim/perturb refuses a rung offset or a rail shift larger than this")


@dataclass(frozen=True)
class ContactsParams:
    rate_hz: float = param(20.0, unit="Hz", min=0.0, max=1000.0, description="sim-time rate of the sim-only "
                           "judge topic sim/contacts (0 = not published)")


@dataclass(frozen=True)
class DiagnosticsParams:
    period_s: float = param(0.1, unit="s", min=1e-3, description="sim time between periodic diagnostics")


@dataclass(frozen=True)
class BridgeParams:
    robot: str = param("g1", unit="-", description="robot config name or path")
    ladder: str = param("default", unit="-", description="ladder spec name or path")
    initial_posture: str = param("standing", unit="-", description="named stance fixture at start-up")
    seed: int = param(0, unit="-", min=0, description="RNG seed of the sensor noise")
    execution: str = param("lockstep", unit="-", choices=("lockstep", "realtime"), description="execution mode")
    apply_perturbation: bool = param(True, unit="-", description="build the spec's perturbation block")
    gui: bool = param(False, unit="-", description="PyBullet GUI instead of DIRECT")
    max_ticks: int = param(0, unit="-", min=0, description="stop after this many ticks (0 = never)")
    physics: PhysicsParams = group(PhysicsParams, "physics engine")
    lockstep: LockstepParams = group(LockstepParams, "lock-step protocol")
    realtime: RealtimeParams = group(RealtimeParams, "real-time mode")
    actuation: ActuationParams = group(ActuationParams, "actuator models")
    grasp: GraspParams = group(GraspParams, "grasp constraints")
    sensors: SensorParams = group(SensorParams, "sensor noise")
    falls: FallParams = group(FallParams, "fall detection")
    drops: DropParams = group(DropParams, "dropped objects")
    diagnostics: DiagnosticsParams = group(DiagnosticsParams, "diagnostics publishing")
    perturbation: PerturbationLimits = group(PerturbationLimits, "bounds of the sim/perturb service")
    contacts: ContactsParams = group(ContactsParams, "sim/contacts (ground truth of the contacts for the judge)")

    def __post_init__(self) -> None:
        _check(self)

    def replace(self, **changes: Any) -> "BridgeParams":
        """Copy with dotted fields changed: ``params.replace(**{"physics.dt_s": 0.002})``."""
        flat = flatten(self)
        flat.update(changes)
        return parse_params(flat, BridgeParams, NODE_NAME)


def _check(p: BridgeParams) -> None:
    if not isinstance(p.physics, PhysicsParams):
        return
    ratio = p.physics.control_period_s / p.physics.dt_s
    if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
        raise SpecError(f"{NODE_NAME}.physics.control_period_s",
                        f"must be a whole multiple of physics.dt_s ({p.physics.dt_s} s), got {p.physics.control_period_s} s")
    if len(p.drops.direction) != 3 or sum(v * v for v in p.drops.direction) < 1e-12:
        raise SpecError(f"{NODE_NAME}.drops.direction", "must be a non-zero 3-vector")


def default_params_path() -> pathlib.Path:
    return default_params_file(NODE_NAME)


def load_bridge_params(source: str | pathlib.Path | Mapping[str, Any] | None = None,
                       **overrides: Any) -> BridgeParams:
    """config/nodes/sim_bridge.yaml (or a path / parsed document) -> BridgeParams; ``overrides``
    are dotted names: ``load_bridge_params(**{"physics.dt_s": 0.002})``."""
    params = load_params(default_params_path() if source is None else source, BridgeParams, NODE_NAME)
    return params.replace(**overrides) if overrides else params

