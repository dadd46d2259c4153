"""Controller parameters: config/nodes/controller.yaml as a frozen dataclass schema.

Built on :mod:`climb_core.params` (ROS params layout, every leaf with default, unit, description
and range). The node declares them from :func:`climb_core.params.describe`, reads them back and
calls :func:`parse_controller_params`; tests and scripts call :func:`load_controller_params` on
the same file. Libraries receive the dataclass, never raw dicts.
"""
from __future__ import annotations

import dataclasses
import pathlib
from dataclasses import dataclass
from typing import Any, Mapping

from climb_core.errors import SpecError
from climb_core.params import default_params_file, flatten, group, load_params, param, parse_params

NODE_NAME = "controller"


@dataclass(frozen=True)
class QpParams:
    solver: str = param("daqp", unit="-", choices=("daqp", "proxsuite"),
                        description="daqp called directly, or proxsuite dense warm-started")
    time_limit_s: float = param(0.004, unit="s", min=0.0, description="solver wall-time bound (0 = none)")
    iter_limit: int = param(1000, unit="-", min=1, description="solver iteration limit")
    failure_dir: str = param("build/qp_failures", unit="-",
                             description="failing QPs are saved here as .npz (relative to the project root)")
    max_saved_failures: int = param(50, unit="-", min=0, description="stop saving failing QPs after this many")
    failure_grace_s: float = param(0.2, unit="s", min=0.0, description=(
        "consecutive infeasible ticks tolerated before the FSM's qp_failure event (each one counted, saved "
        "and answered with the relaxed solve, saturated, of the current tasks): an impact can make the QP "
        "infeasible for a few ticks. 0 = fail on the first"))
    recover_after_s: float = param(1.0, unit="s", min=0.0, description=(
        "in failure: once the QP has solved this long without a break (the hold tasks on the contacts kept) "
        "and every joint is slower than impact.settle_joint_speed, the FSM leaves failure for replan_needed "
        "(reason qp_failure: the climb session replans from the measured state). 0 = stay in failure"))
    acceleration_regularization: float = param(1e-5, unit="-", min=1e-12, description="weight on |qdd|^2")
    force_regularization: float = param(1e-4, unit="1/N^2", min=1e-12,
                                        description="weight on the squared contact force variables")
    torque_regularization: float = param(1.0, unit="-", min=0.0,
                                         description="weight on sum (tau_i / tau_max_i)^2: keeps joints away from "
                                                     "saturation and makes the contact force split unique")
    contact_velocity_gain: float = param(10.0, unit="1/s", min=0.0,
                                         description="J qdd + Jdot v = -k J v on held contacts (drift damping)")
    torque_limit_fraction: float = param(0.95, unit="-", min=0.0, max=1.0,
                                         description="share of the URDF effort limit the QP may use")
    joint_limit_horizon_s: float = param(0.1, unit="s", min=1e-3,
                                         description="horizon of the joint position-limit acceleration bounds")
    joint_limit_margin: float = param(0.02, unit="rad", min=0.0, description="distance kept from the URDF joint limits")
    joint_acceleration_bound: float = param(400.0, unit="rad/s^2", min=1.0, description="|qdd| bound of every joint")
    base_acceleration_bound: float = param(100.0, unit="m/s^2", min=1.0,
                                           description="|qdd| bound of the free-flyer (linear and angular)")


@dataclass(frozen=True)
class ContactParams:
    friction_margin: float = param(0.8, unit="-", min=0.05, max=1.0,
                                   description="the QP's friction cones use margin * mu")
    generators_per_point: int = param(4, unit="-", min=3, description=(
        "edges of the linearised friction cone (a multiple of 4 contains the planner's pyramid and single-tangent "
        "forces up to mu f_n: constraints.friction_generators)"))
    min_normal_force: float = param(1.0, unit="N", min=0.0,
                                    description="minimum normal force per point of an established unilateral contact")
    unilateral_force_limit_ft_range: float = param(0.8, unit="-", min=0.05, max=1.0, description=(
        "cap on the total normal force of one unilateral contact, as a share of the force range of its limb's "
        "F/T sensor (robot config ft_ranges), which must read it: G1's ankles 1 kN -> 800 N, TALOS's 3 kN -> "
        "2.4 kN. A fixed 800 N left TALOS's 916 N without support on one foot (measured, docs/benchmarks.md)"))
    grip_force_fraction: float = param(0.8, unit="-", min=0.0, max=1.0,
                                       description="share of the robot's grip strength the QP may use")
    grasp_torque_limit: float = param(6.0, unit="N m", min=0.0, description="per-axis moment cap of a closed grasp")
    release_ramp_s: float = param(0.4, unit="s", min=0.01, description="force ramp to zero before a release")
    engage_ramp_s: float = param(0.2, unit="s", min=0.0, description="force ramp up after a contact is made")
    released_force_threshold: float = param(8.0, unit="N", min=0.0,
                                            description="a contact counts as unloaded below this force")


@dataclass(frozen=True)
class LineContactParams:
    enabled: bool = param(True, unit="-", description=(
        "locate a sole's line on a round rung from the ankle F/T from the contact's engage ramp on and move "
        "the contact there (a rung off its planned place along the sole: line_contact.py)"))
    locate_force: float = param(20.0, unit="N", min=1.0,
                                description="readings count once the contact's normal force exceeds this")
    samples: int = param(3, unit="-", min=2, description="readings counted before the first estimate")
    significance: float = param(4.0, unit="-", min=0.0, description=(
        "an estimate moves the line only when it differs from the line in use by this many standard "
        "errors of the fit (and by min_shift)"))
    track_s: float = param(0.0, unit="s", min=0.0, description=(
        "the line is followed this long after the first counted reading; 0 = while the contact lasts (a sole "
        "rolls on the rung as the load moves: measured, tracking for 0.5 s only left the right foot 6 mm off "
        "the line and it rolled off rung 3 at the climb's last transition)"))
    fit_time_constant_s: float = param(0.2, unit="s", min=0.0, description=(
        "readings fade from the fit with this time constant (the foot loads and rolls at first); 0 = all count "
        "alike"))
    max_shift: float = param(0.08, unit="m", min=0.0,
                             description="the located line is clipped to this distance from the planned one")
    min_shift: float = param(0.003, unit="m", min=0.0,
                             description="an estimate closer than this to the line in use leaves the contact as it is")


def _task_gains(name: str, weight: float, stiffness: float, orientation_weight: float = 1.0) -> type:
    """A frozen gains dataclass whose defaults are this task's (the schema builds groups from
    class defaults)."""
    namespace = {
        "__annotations__": {"weight": float, "stiffness": float, "orientation_weight": float},
        "weight": param(weight, unit="-", min=0.0, description="task weight in the QP cost"),
        "stiffness": param(stiffness, unit="1/s^2", min=0.0, description="PD stiffness k; damping is 2 sqrt(k)"),
        "orientation_weight": param(orientation_weight, unit="-", min=0.0,
                                    description="relative weight of the angular rows of a 6D task [m^2/rad^2]"),
        "__module__": __name__,
    }
    return dataclass(frozen=True)(type(name, (), namespace))


ComGains = _task_gains("ComGains", 100.0, 60.0)
PostureGains = _task_gains("PostureGains", 1.0, 40.0)
BaseOrientationGains = _task_gains("BaseOrientationGains", 20.0, 60.0)
ContactBodyGains = _task_gains("ContactBodyGains", 200.0, 150.0, 0.3)
#: any of the gains classes above (weight, stiffness, orientation_weight)
TaskGains = Any


@dataclass(frozen=True)
class TaskParams:
    com: ComGains = group(ComGains, "centre-of-mass position task")
    posture: PostureGains = group(PostureGains, "whole-body joint task")
    base_orientation: BaseOrientationGains = group(BaseOrientationGains, "free-flyer orientation task")
    contact_body: ContactBodyGains = group(ContactBodyGains, "moving limb pose task (way-points)")


@dataclass(frozen=True)
class CollisionParams:
    enabled: bool = param(True, unit="-", description="velocity-damper collision avoidance on")
    influence_distance: float = param(0.06, unit="m", min=1e-3, description="d_i: dampers act below this distance")
    security_distance: float = param(0.01, unit="m", min=0.0, description="d_s: distance treated as a collision")
    damping: float = param(0.4, unit="m/s", min=1e-3, description="xi: approach speed allowed at d_i")
    max_braking: float = param(30.0, unit="m/s^2", min=0.0,
                               description="largest separating acceleration a damper may demand (keeps the QP "
                                           "feasible when a pair enters the zone too fast)")
    broadphase_margin: float = param(0.0, unit="m", min=0.0,
                                     description="bounding-sphere prefilter margin before calling coal")
    broadphase_slack: float = param(0.03, unit="m", min=0.0,
                                    description="the sphere-vs-capsule broadphase re-runs when a bounding-sphere "
                                                "centre moved this far since its last run (pairs within the cutoff "
                                                "plus this are kept meanwhile; conservative)")
    env_links: tuple[str, ...] = param(
        ("left_hand_palm_link", "right_hand_palm_link", "left_wrist_yaw_link", "right_wrist_yaw_link",
         "left_hand_index_1_link", "right_hand_index_1_link", "left_hand_middle_1_link",
         "right_hand_middle_1_link", "left_hand_thumb_2_link", "right_hand_thumb_2_link",
         "left_elbow_link", "right_elbow_link", "left_knee_link", "right_knee_link",
         "left_ankle_roll_link", "right_ankle_roll_link"), unit="-",
        description="robot links checked against the environment")
    env_roles: tuple[str, ...] = param(("rung", "rail", "stringer", "platform", "obstacle"), unit="-",
                                       description="environment surface roles checked")
    self_pairs: tuple[str, ...] = param(
        ("left_hand_palm_link:right_hand_palm_link", "left_knee_link:right_knee_link",
         "left_ankle_roll_link:right_ankle_roll_link"), unit="-",
        description="robot link pairs checked against each other, 'link_a:link_b'")

    @property
    def self_pair_tuples(self) -> tuple[tuple[str, str], ...]:
        return tuple(tuple(p.split(":", 1)) for p in self.self_pairs)  # type: ignore[misc]


@dataclass(frozen=True)
class GuardedParams:
    force_threshold: float = param(6.0, unit="N", min=0.1,
                                   description="F/T force change (tared at motion start) that means contact")
    approach_speed: float = param(0.04, unit="m/s", min=1e-3, description="slow search speed past the planned pose")
    search_stiffness: float = param(400.0, unit="1/s^2", min=0.0,
                                    description="contact-body task stiffness on the approach and while creeping past "
                                                "the planned pose (a blocked limb builds force within a few mm)")
    stiffen_time_s: float = param(0.3, unit="s", min=0.0,
                                  description="the contact-body stiffness ramps to search_stiffness over this time "
                                              "once the approach begins")
    search_distance: float = param(0.05, unit="m", min=0.0,
                                   description="the search past the planned pose ends without contact (replanning "
                                               "is needed) once the limb itself has travelled this far past it")
    search_lead_max: float = param(0.025, unit="m", min=0.0,
                                   description="the search's creeping target may run this far beyond "
                                               "search_distance while the limb lags behind it (then the search "
                                               "ends whatever the limb's travel): a limb that lags its target "
                                               "reaches the surface before the search gives up")
    replan_offset: float = param(0.025, unit="m", min=0.0,
                                 description="a placement that found its surface farther than this from the "
                                             "plan (early or late, along the approach) loads the contact, then "
                                             "holds and asks for a replan in the corrected model "
                                             "(replan_needed, reason contact_offset)")
    filter_time_constant_s: float = param(0.01, unit="s", min=0.0, description="first-order filter on the F/T force")
    noise_sigmas: float = param(5.0, unit="-", min=0.0,
                                description="the contact threshold is at least this many standard deviations of "
                                            "the filtered F/T force noise, estimated online per sensor (0: "
                                            "force_threshold alone)")
    noise_time_constant_s: float = param(1.0, unit="s", min=0.01,
                                         description="time constant of the online F/T noise estimate (from the "
                                                     "raw force's tick-to-tick differences)")
    stall_lag: float = param(0.015, unit="m", min=0.0,
                             description="search: the limb this far behind its creeping target along the "
                                         "approach (blocked) is a contact once the slow-filtered force change "
                                         "confirms it (confirm_sigmas); 0: off. A noisy F/T raises the fast "
                                         "threshold beyond what a creeping limb can push")
    tilt_limit_deg: float = param(5.0, unit="deg", min=0.0, max=90.0,
                                  description="a foot's guarded approach or search: its sole turned this far from "
                                              "its target orientation is a contact (it pivots on what it touches: "
                                              "the leg pushes on while a noisy F/T cannot see the few newtons; "
                                              "measured 10 -> 25 deg toes up in 0.6 s on a round rung under 2 % "
                                              "noise, then a slip); 0: off")
    confirm_time_constant_s: float = param(0.2, unit="s", min=0.0,
                                           description="first-order filter of the F/T force that confirms a stall")
    confirm_sigmas: float = param(4.0, unit="-", min=0.0,
                                  description="a stall is a contact when the slow-filtered force change exceeds "
                                              "this many standard deviations of its noise (and force_threshold)")
    approach_arm_fraction: float = param(0.0, unit="-", min=0.0, max=1.0,
                                         description="contact checks start this far into the last path segment "
                                                     "(the approach; the F/T is tared again there), plus settle_time_s")
    settle_time_s: float = param(0.05, unit="s", min=0.0,
                                 description="the F/T is tared when the approach starts and checked from this "
                                             "time later (transients of the contact-set change settle)")


@dataclass(frozen=True)
class ImpactParams:
    enabled: bool = param(True, unit="-", description="detect impacts (F/T and joint velocities) and brace")
    force_jump: float = param(400.0, unit="N", min=0.0,
                              description="an impact: a limb's F/T force (10 ms filter) departs this far from its "
                                          "200 ms filter within a tick (or noise_sigmas of its noise when larger); "
                                          "contact ramps and guarded placements change it slowly")
    noise_sigmas: float = param(8.0, unit="-", min=0.0,
                                description="the force jump is at least this many standard deviations of the "
                                            "filtered F/T noise (estimated online)")
    joint_velocity_jump: float = param(12.0, unit="rad/s", min=0.0,
                                       description="an impact: a joint's velocity changed this much more in one "
                                                   "control period than the last QP's acceleration explains (0: off)")
    brace_states: tuple[str, ...] = param(
        ("move_com", "idle", "hold", "replan_needed"), unit="-",
        description="FSM states an impact braces from (every limb on its hold); in the others (a limb being "
                    "released, in flight or placed) it is reported and the transition goes on. Measured: a "
                    "5 kg ball on a climb with a hand in flight succeeded unbraced and fell braced (the hand "
                    "held mid-air, the QP infeasible)")
    brace_time_s: float = param(0.5, unit="s", min=0.0, description="least time in the brace state")
    brace_max_s: float = param(2.0, unit="s", min=0.0,
                               description="longest wait in the brace state for the joints to settle")
    settle_joint_speed: float = param(0.3, unit="rad/s", min=0.0,
                                      description="the brace ends once every joint is slower than this")
    posture_stiffness_scale: float = param(1.0, unit="-", min=1.0,
                                           description="the posture task's stiffness toward the configuration at "
                                                       "the impact is multiplied by this while bracing (measured on "
                                                       "a 7 kg ball: 4 drove the QP infeasible for the whole brace "
                                                       "and two contacts were lost; 1 held them)")
    grip_force_fraction: float = param(0.8, unit="-", min=0.0, max=1.0,
                                       description="share of the grip strength a grasp may use while bracing "
                                                   "(measured on a 7 kg ball: 1.0 let the QP lean on the grasps "
                                                   "until they slid and the robot fell; 0.8, the contacts' share, "
                                                   "held)")
    contact_lost_distance: float = param(0.03, unit="m", min=0.0,
                                         description="after a brace, an active contact whose contact surface moved "
                                                     "this far from where it was made is lost (replan)")
    replace_lost: bool = param(True, unit="-", description=(
        "a single contact lost in a brace is put back before anything else: the plan's transition that "
        "last placed that limb on that surface runs again (blended from where the robot is, guarded), "
        "then the interrupted transition; false: replan_needed at once"))
    cooldown_s: float = param(0.5, unit="s", min=0.0,
                              description="no new impact is detected this long after a brace ends")
    startup_s: float = param(0.5, unit="s", min=0.0,
                             description="no impact is detected this long after a reset (the F/T filters start, "
                                         "the feet settle on the ground)")


@dataclass(frozen=True)
class FallbackParams:
    natural_frequency: float = param(15.0, unit="rad/s", min=0.0,
                                     description="joint PD around the configuration at failure, gains scaled by "
                                                 "the joint-space inertia M_ii: kp = M_ii w^2, kd = 2 zeta w M_ii "
                                                 "(stable at the 200 Hz update on light and heavy joints alike)")
    damping_ratio: float = param(1.0, unit="-", min=0.0, description="zeta of the fallback PD")


@dataclass(frozen=True)
class ComplianceParams:
    feedforward: str = param("qp", unit="-", choices=("none", "qp"),
                             description="f of eq. 1: none (paper) or the QP's torques converted to duty")
    current_margin: float = param(0.85, unit="-", min=0.05, max=1.0,
                                  description="duty clamped so the predicted current stays below margin * limit")
    gain_scale: float = param(0.3, unit="-", min=0.0, max=1.0,
                              description="multiplies the robot config's PWM kP / kD: the config's leg gains "
                                          "(10 duty/rad) oscillate with a 200 Hz duty update (measured: stable "
                                          "at 0.3, marginal at 0.5, unstable at 1.0)")


@dataclass(frozen=True)
class GripperParams:
    close_time_s: float = param(0.3, unit="s", min=0.0, description="wait after CLOSE before the grasp is loaded")
    open_time_s: float = param(0.2, unit="s", min=0.0, description="wait after OPEN before the hand moves")
    pregrasp_position: float = param(0.0, unit="-", min=0.0, max=1.0,
                                     description="finger position (0 open .. 1 closed) while the hand travels")


@dataclass(frozen=True)
class ControllerParams:
    robot: str = param("g1", unit="-", description="robot config name (config/robots/<name>.yaml) or path")
    mode: str = param("qp", unit="-", choices=("qp", "compliance"),
                      description="qp: torques from the whole-body QP; compliance: PWM per joint (eq. 1)")
    execution: str = param("lockstep", unit="-", choices=("lockstep", "realtime"),
                           description="lockstep: compute on each joint_states; realtime: wall-clock timer")
    control_period_s: float = param(0.005, unit="s", min=1e-4, description="control period (200 Hz)")
    actuation_latency_s: float = param(0.0, unit="s", min=0.0, max=0.05,
                                       description="time from the state read to the command acting; each tick "
                                                   "computes its command for the state predicted that far ahead "
                                                   "(the last QP's accelerations held); set control_period_s with "
                                                   "the bridge's lockstep.command_delay_ticks 1 (without it a "
                                                   "compliance hand transfer trips 16 drivers and a QP climb "
                                                   "fails at its 11th transition)")
    ladder: str = param("default", unit="-",
                        description="ladder spec (config/ladders/<name>.yaml or a path): the environment of the "
                                    "collision dampers and holds (the planner's nominal one)")
    initial_stance: str = param("standing", unit="-",
                                description="stance fixture (climb_core.fixtures) whose holds are active at "
                                            "activation (the bridge's initial_posture)")
    autostart: bool = param(True, unit="-", description="node: configure and activate on start-up")
    nice: int = param(0, unit="-", min=-20, max=19,
                      description="node: niceness increment applied at start-up (os.nice; negative = higher "
                                  "priority, needs CAP_SYS_NICE / root; 0 = inherit). The controller is on the "
                                  "lock-step critical path: -10 keeps its latency on a busy machine")
    fsm_table: str = param("default", unit="-", description="config/fsm/<name>.yaml or a path")
    state_timeout_s: float = param(0.05, unit="s", min=0.0,
                                   description="realtime: no command from a state older than this")
    estimator: str = param("ground_truth", unit="-", choices=("ground_truth",),
                           description="base state source (sim/base_truth in simulation)")
    qp: QpParams = group(QpParams, "whole-body QP")
    contacts: ContactParams = group(ContactParams, "contact model and force ramps")
    line_contact: LineContactParams = group(LineContactParams, "a sole's line on a round rung located from F/T")
    tasks: TaskParams = group(TaskParams, "task weights and stiffnesses")
    collision: CollisionParams = group(CollisionParams, "velocity-damper collision avoidance (eq. 6-8)")
    guarded: GuardedParams = group(GuardedParams, "guarded motion of the add-contact state")
    impact: ImpactParams = group(ImpactParams, "impact detection and the brace state")
    fallback: FallbackParams = group(FallbackParams, "safe hold after a QP failure")
    compliance: ComplianceParams = group(ComplianceParams, "PWM compliance mode")
    gripper: GripperParams = group(GripperParams, "gripper states")

    def __post_init__(self) -> None:
        _check(self)  # the cross-field rules, whichever parser built it (parse_params, a node's on-set)

    def replace(self, **changes: Any) -> "ControllerParams":
        """Copy with dotted changes: ``params.replace(**{"qp.solver": "proxsuite"})``."""
        flat = flatten(self)
        for key, value in changes.items():
            flat[key] = value
        return parse_controller_params(flat)


def _check(params: ControllerParams) -> ControllerParams:
    c = params.collision
    if c.security_distance >= c.influence_distance:
        raise SpecError(f"{NODE_NAME}.collision.security_distance", "must be smaller than collision.influence_distance")
    for i, pair in enumerate(c.self_pairs):
        parts = pair.split(":")
        if len(parts) != 2 or not all(parts):
            raise SpecError(f"{NODE_NAME}.collision.self_pairs[{i}]", "must be 'link_a:link_b'")
    return params


def parse_controller_params(values: Mapping[str, Any]) -> ControllerParams:
    """Flat (dotted) or nested ``ros__parameters`` mapping -> ControllerParams."""
    return _check(parse_params(values, ControllerParams, NODE_NAME))


def default_params_path() -> pathlib.Path:
    return default_params_file(NODE_NAME)


def load_controller_params(path: str | pathlib.Path | None = None, **overrides: Any) -> ControllerParams:
    """Read config/nodes/controller.yaml (or ``path``) and apply dotted overrides
    (``load_controller_params(**{"qp.solver": "proxsuite"})``)."""
    params = _check(load_params(path if path is not None else default_params_path(), ControllerParams, NODE_NAME))
    return params.replace(**overrides) if overrides else params
