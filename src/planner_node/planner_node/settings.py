"""Planner parameters: config/planner.yaml (ROS 2 params layout, node ``primitive_adaptation``).

One frozen dataclass per concern, parsed once with :mod:`climb_core.params` (units, ranges,
unknown keys refused) and handed to the library; the node declares the same parameters. The
feasibility check's own settings stay in config/feasibility.yaml (frozen for benchmarks); the
planner only adds *planning margins* on top of them (``planning``), so that what it plans passes
the frozen check with room to spare.
"""
from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from climb_core.params import group, load_params, param

NODE_NAME = "primitive_adaptation"


@dataclass(frozen=True)
class PCIKParams:
    max_iterations: int = param(40, unit="-", min=1, description="SQP iterations of one physics-constrained IK solve")
    step_limit: float = param(0.15, unit="rad", min=1.0e-3, description=(
        "trust region: bound on each joint's change per iteration (base: same number in m and rad)"))
    position_tolerance: float = param(2.0e-4, unit="m", min=0.0, description="contact position error at convergence")
    angle_tolerance: float = param(2.0e-3, unit="rad", min=0.0, description="contact orientation error at convergence")
    step_tolerance: float = param(1.0e-4, unit="rad", min=0.0, description="converged when no joint moves more than this")
    orientation_weight: float = param(0.3, unit="m/rad", min=0.0, description="angular rows vs position rows")
    posture_weight: float = param(1.0, unit="1/rad^2", min=0.0, description="cost of joint distance to the target configuration")
    base_position_weight: float = param(10.0, unit="1/m^2", min=0.0, description="cost of base distance to the target configuration")
    base_orientation_weight: float = param(10.0, unit="1/rad^2", min=0.0, description="cost of base rotation away from the target")
    damping: float = param(1.0e-3, unit="-", min=1.0e-9, description="Levenberg damping of |dq|^2")
    floating_weight: float = param(10.0, unit="1/m^2", min=0.0, description=(
        "cost of a floating contact's distance to its preferred position"))
    com_weight: float = param(100.0, unit="1/m^2", min=0.0, description="cost of the CoM's distance to a CoM target (x, y)")
    cue_weight: float = param(1.0e5, unit="-", min=0.0, description=(
        "penalty on the slack of a soft (design cue) contact: the way-point poses of make_primitives"))
    contact_slack_weight: float = param(1.0e6, unit="-", min=1.0, description="penalty on contact constraint slack")
    equilibrium_slack_weight: float = param(10.0, unit="1/N^2", min=1.0e-9, description=(
        "penalty on the base wrench imbalance slack (static equilibrium)"))
    equilibrium_tolerance: float = param(0.5, unit="N", min=0.0, description=(
        "base wrench imbalance left in the linearised problem below which the core check is tried"))
    torque_slack_weight: float = param(1.0e1, unit="1/(N m)^2", min=1.0e-9, description="penalty on torque-limit excess")
    collision_slack_weight: float = param(1.0e6, unit="1/m^2", min=1.0, description="penalty on collision-margin violation")
    force_regularization: float = param(1.0e-5, unit="1/N^2", min=1.0e-12, description=(
        "cost of 0.5 |f|^2 (spreads the forces: far fewer active constraints in the QP)"))
    collision_activation: float = param(0.03, unit="m", min=0.0, description=(
        "pairs closer than this enter the QP as linearised distance constraints"))
    collision_margin: float = param(0.008, unit="m", min=0.0, description="signed distance the IK keeps from obstacles")
    self_collision_margin: float = param(0.003, unit="m", min=0.0, description=(
        "signed distance the IK keeps between the robot's own links"))
    torque_limit_fraction: float = param(0.9, unit="-", min=0.1, max=1.0, description=(
        "share of the effort limits the IK may use (room for the interpolation between solutions)"))
    grip_limit_fraction: float = param(0.9, unit="-", min=0.1, max=1.0, description="share of the grip strength the IK may use")
    friction_margin: float = param(0.9, unit="-", min=0.1, max=1.0, description="the IK's friction cones use margin * mu")
    grasp_moment_limit: float = param(0.0, unit="N m", min=0.0, description=(
        "per-axis cap on a grasp's moment in the IK's statics, scaled by grip_limit_fraction (the controller's "
        "contacts.grasp_torque_limit is 6; 0 = the frozen check's, none: docs/planner.md)"))
    min_normal_force: float = param(2.0, unit="N", min=0.0, description="least normal force per regular unilateral contact point")
    sole_cop_margin: float = param(0.0, unit="m", min=0.0, max=0.05, description=(
        "the IK's statics count a flat sole's corners this far inside its edges (the CoP kept off them)"))
    joint_limit_margin: float = param(0.01, unit="rad", min=0.0, description="kept away from the position limits")


@dataclass(frozen=True)
class ProjectionParams:
    restarts: int = param(10, unit="-", min=0, description="Algorithm 1: perturbed restarts n")
    perturbation_joint: float = param(0.05, unit="rad", min=0.0, description=(
        "std dev of the joint perturbation, multiplied by the restart index"))
    perturbation_base: float = param(0.01, unit="m", min=0.0, description=(
        "std dev of the base position perturbation, multiplied by the restart index"))
    retract: bool = param(True, unit="-", description="retract colliding projections with the physics-constrained IK")
    repair_equilibrium: bool = param(True, unit="-", description=(
        "when a projection is collision-free but not in equilibrium, try the physics-constrained IK"))
    repair_attempts: int = param(3, unit="-", min=0, description=(
        "physics-constrained IK repairs (retraction / equilibrium) per projection, at most"))
    retract_tries: int = param(2, unit="-", min=1, description=(
        "retraction of a path configuration: from it, then from perturbed copies (this many tries in all)"))
    grasp_roll_tolerance: float = param(0.15, unit="rad", min=-1.0, description=(
        "a moving hand's new grasp rolled more than this about its rung (vs the hold's nominal pose) is "
        "projected again with the roll pinned (-1: never)"))
    latch_grasps: bool = param(True, unit="-", description=(
        "a grasp held from one primitive to the next keeps the roll about its rung it latched with (the "
        "simulator's and the controller's closed hand cannot roll around the rung); false: free in every "
        "configuration (before 2026-11-30: the arms swung the hands 40-55 deg around the rung within a CoM shift)"))
    start_seed_restarts: int = param(3, unit="-", min=-1, description=(
        "limb / CoM primitives: when the primitive's end configuration cannot be projected, project the start "
        "configuration (limb on its new hold) with this many restarts (-1: never)"))


@dataclass(frozen=True)
class SamplingParams:
    lateral_sigma: float = param(0.02, unit="m", min=0.0, description=(
        "std dev of a sampled hold's position along the rung around the seed hold (attempt > 0)"))
    lateral_max: float = param(0.05, unit="m", min=0.0, description="bound on that offset")
    ground_sigma: float = param(0.02, unit="m", min=0.0, description="std dev of a sampled ground foot position (x, y)")
    alternative_rungs: bool = param(True, unit="-", description=(
        "attempts 3 and 4 of a hand primitive try the rung above / below the seed rung"))


@dataclass(frozen=True)
class InterpolationParams:
    max_step: float = param(0.04, unit="rad", min=1.0e-4, description=(
        "planner discretisation: largest joint change between checked configurations"))
    base_scale: float = param(0.5, unit="m/rad", min=1.0e-3, description="base metres counted as radians / base_scale")
    max_depth: int = param(10, unit="-", min=1, description="recursion depth of the projected bisection")
    exclusion_distance_hand: float = param(0.06, unit="m", min=0.0, description=(
        "a moving hand closer than this to the hold it leaves / reaches may touch that surface (release, approach)"))
    exclusion_distance_foot: float = param(0.03, unit="m", min=0.0, description=(
        "a moving foot closer than this to the hold it leaves / reaches may touch that surface"))
    max_repairs: int = param(4, unit="-", min=0, description=(
        "colliding path sections retracted (a new milestone each) before an adaptation attempt fails"))
    retarget_hands: bool = param(True, unit="-", description=(
        "hand primitives: a transformed way-point whose moving hand strays from the design cue's pose "
        "(relative to the actual start / target hold) is projected onto that pose as well"))
    retarget_feet: bool = param(True, unit="-", description="the same for foot primitives")
    retarget_mount: bool = param(False, unit="-", description="the same for the mount (hands from the ground)")
    retarget_position_tolerance: float = param(0.02, unit="m", min=0.0, description=(
        "a way-point's moving limb this far from its re-targeted pose is re-targeted"))
    retarget_angle_tolerance: float = param(0.1, unit="rad", min=0.0, description=(
        "... or rotated this much from it"))
    hand_backoff_scale: float = param(1.0, unit="-", min=1.0, max=2.0, description=(
        "hand transfers (re-targeted) on ladders at least hand_backoff_min_incline_deg steep: each "
        "way-point's distance from the rungs along the palm normals of the grasps left and reached "
        "(blended by its cue weight) is multiplied by this; the release and the approach stay on their "
        "straight lines. Room for the open Dex3 thumb, which stands 9.7 cm proud of the palm face"))
    hand_backoff_min_incline_deg: float = param(82.0, unit="deg", min=0.0, max=90.0, description=(
        "ladders from this inclination up get hand_backoff_scale (a scene without a ladder: never)"))


@dataclass(frozen=True)
class TimingParams:
    max_joint_speed: float = param(0.4, unit="rad/s", min=1.0e-3, description="fastest joint motion in the plan")
    max_base_speed: float = param(0.08, unit="m/s", min=1.0e-3, description="fastest base translation")
    max_base_angular_speed: float = param(0.3, unit="rad/s", min=1.0e-3, description="fastest base rotation")
    ramp_fraction: float = param(0.15, unit="-", min=0.0, max=0.5, description=(
        "share of a transition slowed down at its start and end (up to 2x slower)"))
    min_transition_duration: float = param(1.0, unit="s", min=0.0, description="least duration of one transition")
    max_com_acceleration: float = param(0.0, unit="m/s^2", min=0.0, description=(
        "largest horizontal acceleration of the centre of mass at a way-point, each transition from rest to rest "
        "(the ZMP within z_com / g times it of the CoM; 0: no bound)"))
    soles_max_com_acceleration: float = param(0.1, unit="m/s^2", min=0.0, description=(
        "the same bound on the transitions the flat soles carry alone (no grasp; the smaller of the two applies; "
        "0: off; G1 tipped over its heels in the first hand's mount of 80-90 deg ladders at the planner's speeds)"))
    edge_slowdown_margin: float = param(0.0, unit="m", min=0.0, max=0.1, description=(
        "a transition the flat soles carry alone (no grasp) slows down by margin / distance where its CoM comes "
        "closer than this to the heel or toe edge of the soles' hull (0: off; the vertical and caged ladders set "
        "0.045 in their files: G1 fell backwards over its heels mounting the vertical ladder at full speed, the "
        "CoM planned 2.6 cm from them, and mounted slowed there)"))
    edge_slowdown_max: float = param(2.0, unit="-", min=1.0, max=5.0, description=(
        "largest slow-down factor of edge_slowdown_margin"))


@dataclass(frozen=True)
class PlanningParams:
    robot: str = param("g1", unit="-", description="robot config name (config/robots/<name>.yaml)")
    strategy: str = param("forward", unit="-", description="primitive library: config/primitives/<robot>/<strategy>/")
    primitives_dir: str = param("config/primitives", unit="-", description="primitive libraries (relative to the project root)")
    attempts_per_subtask: int = param(5, unit="-", min=1, description="MSP-Recurse: adaptation attempts m per sub-task")
    attempts_per_variant: int = param(2, unit="-", min=1, description=(
        "attempts of a sub-task with one library variant before the next nearest reference ladder's"))
    timeout_s: float = param(120.0, unit="s", min=0.1, description="wall-time limit of one multi-step search")
    seed: int = param(0, unit="-", min=0, description="random seed of the hold sampling and IK perturbations")
    collision_margin: float = param(0.005, unit="m", min=0.0, max=0.1, description=(
        "collision margin of the planner's own checks (the frozen check uses config/feasibility.yaml)"))
    self_collision_margin: float = param(0.001, unit="m", min=-0.01, max=0.1, description=(
        "self-collision margin of the planner's own checks (links of one robot, e.g. pelvis vs hip at deep flexion)"))
    torque_limit_fraction: float = param(0.95, unit="-", min=0.1, max=1.0, description=(
        "share of the effort limits the planner's own checks allow"))
    grip_limit_fraction: float = param(0.95, unit="-", min=0.1, max=1.0, description=(
        "share of the grip strength the planner's own checks allow"))
    friction_margin: float = param(0.95, unit="-", min=0.1, max=1.0, description="planner's own checks use margin * mu")
    grasp_moment_limit: float = param(0.0, unit="N m", min=0.0, description=(
        "planner's own checks: per-axis cap on a grasp's moment, scaled by grip_limit_fraction (the controller's "
        "contacts.grasp_torque_limit is 6: a stance whose grasps need more cannot be held by the QP; 0 = the frozen "
        "check's, none: 6 cost 6 of 12 plans at 78-80 deg and no executed climb, docs/planner.md)"))
    min_normal_force: float = param(3.0, unit="N", min=0.0, description=(
        "planner's own checks: least normal force per unilateral contact point (keeps the CoP off the sole edges)"))
    sole_cop_margin: float = param(0.02, unit="m", min=0.0, max=0.05, description=(
        "planner's own checks: a flat sole's corners count this far inside its edges (the CoP kept off them)"))
    approach_tolerance: float = param(0.03, unit="m", min=0.0, description=(
        "a foot already this close to its approach position on the ground does not step"))
    foot_on_rung_pitch_deg: float = param(10.0, unit="deg", min=-30.0, max=30.0, description=(
        "a foot on a round rung stands pitched this far toes up (climb_core.holds foot_on_rung_pitch_deg): the "
        "rung pushes it back toward the robot as well as up, which a robot standing on one foot with its CoM "
        "behind the rung needs (level, G1's one-foot stances on the vertical ladder needed 1.1-1.8 of the torque "
        "limits in the QP's contact model and fell; the 336-ladder grid planned 84 % level, 97 % at 10 deg; "
        "docs/planner.md); 0 = level on the rung's top line"))


@dataclass(frozen=True)
class ContactSearchParams:
    """Best-first multi-contact search (planner_node.contact_search)."""

    time_limit_s: float = param(180.0, unit="s", min=0.1, description=(
        "wall-time limit of one search (all milestones; narrow_passage takes 85 s on this machine)"))
    max_nodes: int = param(800, unit="-", min=1, description="node budget: contact sets expanded in one search (car_ingress: 292)")
    milestone_max_nodes: int = param(150, unit="-", min=0, description=(
        "an intermediate milestone not reached after this many expansions is given up and the next one targeted from "
        "the same node (0: never; a guide path's free-flyer may hover where no stance holds it)"))
    milestone_tolerance: float = param(0.1, unit="m", min=0.0, description=(
        "a node whose base (position + weighted rotation) is this close to an intermediate milestone's reaches it"))
    lookahead: bool = param(True, unit="-", description=(
        "a node's cost is the smaller of its costs to the targeted milestone and to the next one"))
    goal_tolerance: float = param(0.1, unit="m", min=0.0, description=(
        "the last milestone is reached by a node whose base and limbs on surfaces are this close to its"))
    base_rotation_weight: float = param(0.3, unit="m/rad", min=0.0, description=(
        "configuration distance: base rotation angle counted in metres"))
    limb_weight: float = param(1.0, unit="-", min=0.0, description=(
        "configuration distance: weight of the summed contact-surface position distances of the limbs"))
    joint_weight: float = param(0.05, unit="m/rad", min=0.0, description=(
        "configuration distance: RMS joint angle difference counted in metres"))
    floating_cost_weight: float = param(1.0, unit="-", min=0.0, description=(
        "node cost: weight of an added contact's distance to its position at the milestone"))
    free_limb_cost: float = param(0.05, unit="m", min=0.0, description=(
        "node cost: a limb without a contact counts this instead of its distance to its milestone place"))
    min_contacts: int = param(3, unit="-", min=1, description=(
        "on a ladder, contacts are removed only from sets with more than this (3: the quasi-static climbing gait)"))
    min_contacts_scene: int = param(1, unit="-", min=1, description=(
        "in a scene without a ladder, the same bound (1: single support, the robot walks)"))
    single_support_cop_margin: float = param(0.0, unit="m", min=0.0, max=0.05, description=(
        "the search's IK on a set left on one contact (single support): a flat sole's corners count this far "
        "inside its edges, as the adaptation's check counts them (planning.sole_cop_margin; 0: the whole sole)"))
    hand_release_min_contacts: int = param(1, unit="-", min=1, description=(
        "a hand's contact is removed only from a set that keeps at least this many (2: a hand's support is "
        "released or moved on two other supports, never onto one foot alone)"))
    step_up_hand_support: float = param(0.0, unit="m", min=0.0, description=(
        "a free foot is offered a surface whose top is more than this above its sole only while a hand holds "
        "a surface (a high step is taken with a hand's support: car_ingress's 0.45 m sill; 0: off)"))
    com_over_feet_weight: float = param(3000.0, unit="1/m^2", min=0.0, description=(
        "on a walked ladder (stairs, ship ladders: guide_path.walk_max_incline_deg), the search's IK's cost of the "
        "CoM's horizontal distance to the held feet's centroid: a hand may let go of a rail without the robot "
        "hanging back on the other (steeper ladders are climbed with the CoM behind the rungs; 0: off)"))
    foot_max_treads_up: int = param(1, unit="-", min=0, description=(
        "on a walked ladder, a foot's new hold is at most this many treads above the other foot's (the ground is "
        "tread 0, the platform n + 1): the robot steps one tread at a time (0: no bound)"))
    repair_rounds: int = param(4, unit="-", min=0, description=(
        "in process: a searched plan whose adaptation is stuck at a transition is searched again without "
        "that transition, up to this many times"))
    ik_floating_weight: float = param(100.0, unit="1/m^2", min=0.0, description=(
        "the search's IK: cost of the added contact's distance to its milestone place (0: pcik.floating_weight)"))
    ik_max_iterations: int = param(20, unit="-", min=0, description=(
        "the search's IK: SQP iterations of one call (0: pcik.max_iterations); the final check decides success"))
    reach_margin: float = param(0.02, unit="m", min=0.0, description=(
        "reach pruning: a surface farther than the limb's length plus this from its root is not tried"))
    max_surfaces_per_limb: int = param(2, unit="-", min=0, description=(
        "a free limb tries the surfaces within reach closest to its milestone place, at most this many (0: all)"))
    key_resolution: float = param(0.05, unit="m", min=1.0e-4, description=(
        "visited sets: hold centres rounded to this grid (limb -> surface + position)"))


@dataclass(frozen=True)
class GuidePathParams:
    """Free-flyer guide path (planner_node.guide_path): RRT-Connect, sampler bias, projection."""

    postures_dir: str = param("config/guide_postures", unit="-", description=(
        "reference postures and free-flyer body links, <dir>/<robot>.yaml (relative to the project root)"))
    body_clearance: float = param(0.02, unit="m", min=0.0, description="least signed distance body - environment")
    reach_fraction: float = param(0.92, unit="-", min=0.1, max=1.0, description=(
        "a limb reaches a surface closer than this share of its length (G1 standing: hip - ground 0.68 m of 0.748 m)"))
    min_supporting_limbs: int = param(2, unit="-", min=1, max=4, description=(
        "equilibrium criterion: limbs that must reach a surface accepting them"))
    min_supporting_feet: int = param(1, unit="-", min=0, max=2, description="... of which feet (on a surface below the CoM)")
    foot_below_com: float = param(0.3, unit="m", min=0.0, description=(
        "a supporting foot's surface point lies at least this far below the CoM"))
    step_size: float = param(0.3, unit="m", min=0.01, description="RRT-Connect extension step (state metric)")
    edge_resolution: float = param(0.05, unit="m", min=0.005, description=(
        "linear-interpolation steering: states checked at most this far apart (state metric)"))
    milestone_spacing: float = param(0.3, unit="m", min=0.01, description=(
        "milestones at most this far apart along the path (state metric); about one rung"))
    yaw_weight: float = param(0.3, unit="m/rad", min=0.0, description="state metric: root yaw counted in metres")
    posture_weight: float = param(0.3, unit="m", min=0.0, description=(
        "state metric: one unit of posture blend (between neighbouring reference postures) in metres"))
    projection_step: float = param(0.02, unit="m", min=0.001, description="projection: the root moves down by this step")
    max_drop: float = param(1.5, unit="m", min=0.0, description="projection: the root moves down at most this far")
    projection_collision_tries: int = param(3, unit="-", min=1, description=(
        "projection: collision checks below the first supported height before the sample is rejected"))
    workspace_margin_xy: float = param(0.6, unit="m", min=0.0, description=(
        "sampling box: start and goal roots' bounding box grown by this horizontally"))
    workspace_margin_z: float = param(0.4, unit="m", min=0.0, description="... and by this vertically")
    posture_bias: float = param(0.8, unit="-", min=0.0, max=1.0, description=(
        "probability that a sample takes a reference posture exactly (else a random blend)"))
    yaw_bias: float = param(0.8, unit="-", min=0.0, max=1.0, description=(
        "probability that a sample faces the goal direction (else a uniform yaw)"))
    yaw_sigma: float = param(0.2, unit="rad", min=0.0, description="std dev of a biased sample's yaw around the goal direction")
    goal_samples: int = param(40, unit="-", min=1, description="goal configurations tried within the tolerance")
    shortcut_iterations: int = param(30, unit="-", min=0, description="random shortcut attempts on the found path")
    walk_max_incline_deg: float = param(60.0, unit="deg", min=0.0, max=90.0, description=(
        "a ladder this steep or less (stairs: 20-50 deg, ship ladders: 50-60 deg) is walked up: its milestones stand on the treads, "
        "the base over the feet in the standing posture, instead of the climbing stance's (the base behind "
        "the rungs)"))
    time_limit_s: float = param(5.0, unit="s", min=0.01, description="wall-time limit of one guide path")
    seed: int = param(0, unit="-", min=0, description="random seed of the sampler")


@dataclass(frozen=True)
class ContactPathParams:
    """Generic contact-body paths (planner_node.contact_path): a stance change no primitive fits."""

    lift_clearance: float = param(0.05, unit="m", min=0.0, description=(
        "the moving limb's surface frame leaves its hold by this along the hold's normal (a grasp: toward the body)"))
    approach_distance: float = param(0.08, unit="m", min=0.0, description=(
        "the moving limb reaches its new hold along the hold's normal from this far"))
    free_lift_max: float = param(0.05, unit="m", min=0.0, description=(
        "a limb freed for good leaves its hold by lift_clearance along the hold's direction, then keeps its "
        "posture; a retry lifts it by a random distance up to this"))
    free_rest: bool = param(True, unit="-", description=(
        "a hand freed for good is brought to the robot's reference (standing) arm posture after its lift-off "
        "(first attempt; the retries alternate with the lift-off posture and blends of the two); false: it "
        "keeps its lift-off posture"))
    carry_backoff: float = param(0.12, unit="m", min=0.0, description=(
        "carry way-points: held this far in front of the target (horizontally toward where the limb comes from)"))
    step_edge_clearance: float = param(0.03, unit="m", min=0.0, description=(
        "a foot going up onto a higher flat surface rises where its sole's front is this far behind that "
        "surface's near edge (a ship ladder's tread overhangs the one below: the foot backs off first)"))
    carry_waypoints: int = param(2, unit="-", min=1, max=8, description=(
        "way-points between the lift-off and the approach point"))
    com_weight: float = param(10000.0, unit="1/m^2", min=0.0, description=(
        "way-point IK: cost of the CoM's horizontal distance to its target (between the end configurations' CoMs)"))
    latch_grasps: bool = param(False, unit="-", description=(
        "each step starts from its state with every closed grasp latched at its roll about the bar "
        "(planner_node.adapt.latch_grasps, as the primitive adaptation does with projection.latch_grasps): the "
        "simulator's grasp is rigid. Off by default: with it the stairs ladder's adaptation ran out of time "
        "(sub-task 11, reach:left_foot); the ship ladder sets it (config/ladders/ship.yaml: unlatched, a CoM "
        "shift rolled its held hands 0.6-0.8 rad and the wrist tracked 1.1 rad off)"))
    backtrack_window: int = param(-1, unit="-", min=-1, description=(
        "the adaptation of a contact plan stops (stuck) when the sub-task this far below the deepest one "
        "reached has exhausted its attempts (-1: backtrack without bound, MSP-Recurse)"))


@dataclass(frozen=True)
class PlannerSettings:
    planning: PlanningParams = group(PlanningParams, "search and planning margins")
    pcik: PCIKParams = group(PCIKParams, "physics-constrained IK")
    projection: ProjectionParams = group(ProjectionParams, "Algorithm 1 (projection onto a stance)")
    sampling: SamplingParams = group(SamplingParams, "ending-stance sampling around the seed hold")
    interpolation: InterpolationParams = group(InterpolationParams, "milestone interpolation and discretisation")
    timing: TimingParams = group(TimingParams, "time parameterisation of the plan")
    guide_path: GuidePathParams = group(GuidePathParams, "free-flyer guide path (RRT-Connect)")
    contact_search: ContactSearchParams = group(ContactSearchParams, "best-first multi-contact search")
    contact_path: ContactPathParams = group(ContactPathParams, "generic contact-body paths (no primitive)")


def default_settings_path() -> pathlib.Path:
    from climb_core.ros_env import project_root

    return project_root() / "config" / "planner.yaml"


_CACHE: dict[str, PlannerSettings] = {}


def load_settings(path: str | pathlib.Path | None = None) -> PlannerSettings:
    """The ``primitive_adaptation`` section of config/planner.yaml (or ``path``), cached."""
    p = str(path or default_settings_path())
    if p not in _CACHE:
        _CACHE[p] = load_params(p, PlannerSettings, NODE_NAME)
    return _CACHE[p]


def replace(settings: PlannerSettings, group_name: str, **changes) -> PlannerSettings:
    """Copy of ``settings`` with fields of one group changed (tests, scripts)."""
    return dataclasses.replace(settings, **{group_name: dataclasses.replace(getattr(settings, group_name), **changes)})


def parse_overrides(items: list[str], where: str = "--set") -> dict:
    """Command-line ``GROUP.FIELD=VALUE`` strings -> {"GROUP.FIELD": value} (values read as YAML
    scalars) for :func:`apply_overrides`; SpecError ``<where>`` for an item of another form."""
    import yaml

    from climb_core.errors import SpecError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise SpecError(where, f"expects GROUP.FIELD=VALUE, got {item!r}")
        out[key.strip()] = yaml.safe_load(value)
    return out


def apply_overrides(settings: PlannerSettings, overrides: dict, where: str = "planner_overrides") -> PlannerSettings:
    """``settings`` with dotted ``group.field`` values replaced, each validated like the YAML
    loader does (SpecError naming ``<where>.<group.field>`` for an unknown field or a bad value)."""
    from climb_core.errors import SpecError
    from climb_core.params import describe, flatten, parse_params

    if not isinstance(overrides, dict):
        raise SpecError(where, "must be a mapping of dotted planner settings (group.field) to values")
    known = describe(PlannerSettings)
    flat = {k: v for k, v in flatten(settings).items() if k in known}
    for key, value in overrides.items():
        if key not in known:
            raise SpecError(f"{where}.{key}", "unknown planner setting")
        flat[key] = value
    base = parse_params(flat, PlannerSettings, where)
    if type(settings) is PlannerSettings:
        return base
    # a subclass (a node's parameters with the planner's groups): keep its own fields
    return dataclasses.replace(settings, **{f.name: getattr(base, f.name) for f in dataclasses.fields(PlannerSettings)})


#: the file whose ``climb.planner_overrides`` the planning nodes apply by default (the in-process
#: climb applies the same ones: the graph and the fast path plan the same climbs)
CLIMB_OVERRIDES_FILE = "config/climb.yaml"


def read_climb_overrides(path: str | pathlib.Path = CLIMB_OVERRIDES_FILE, key: str = "planner_overrides") -> dict:
    """The ``climb.<key>`` mapping of a climb settings file (``planner_overrides`` or
    ``scene_planner_overrides``; {} when the path is "")."""
    import yaml

    from climb_core.errors import SpecError
    from climb_core.ros_env import project_root

    if not str(path):
        return {}
    p = pathlib.Path(path)
    if not p.is_absolute():
        p = project_root() / p
    try:
        doc = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SpecError("planner_overrides_file", f"cannot read {p}: {exc}") from None
    climb = doc.get("climb") if isinstance(doc, dict) else None
    overrides = (climb or {}).get(key) if isinstance(climb, dict) else None
    if overrides is None:
        return {}
    if not isinstance(overrides, dict):
        raise SpecError("planner_overrides_file", f"{p}: climb.{key} must be a mapping")
    return dict(overrides)


def walked(scenario: Any, settings: PlannerSettings) -> bool:
    """Whether the robot walks through ``scenario`` rather than climbs it: a scene without a ladder,
    or a ladder no steeper than ``guide_path.walk_max_incline_deg`` (stairs). A walked scenario plans
    with config/climb.yaml's ``scene_planner_overrides`` on top of its ``planner_overrides``."""
    ladder = getattr(scenario, "ladder", None)
    return ladder is None or float(ladder.inclination_deg) <= settings.guide_path.walk_max_incline_deg


def choose_strategy(scenario: Any, settings: PlannerSettings | None = None) -> tuple[str, str]:
    """(``search`` | ``primitives``, reason) for a climb that names no strategy: a scene is searched
    (the primitive libraries climb ladders); a ladder the robot walks up (:func:`walked`: stairs) is
    searched too, its holds (treads, rails) chosen by the contact search; a steeper ladder is climbed
    with the robot's primitive library (``planning.strategy``)."""
    settings = settings or load_settings()
    ladder = getattr(scenario, "ladder", None)
    if ladder is None:
        return "search", "a scene without a ladder: guide path and best-first contact search"
    what = f"{ladder.type} ladder at {float(ladder.inclination_deg):g} deg"
    limit = f"guide_path.walk_max_incline_deg {settings.guide_path.walk_max_incline_deg:g}"
    if walked(scenario, settings):
        return "search", f"{what} (<= {limit}): walked up, the contact search chooses the treads and rails"
    reason = f"{what} (> {limit}): climbed with the {settings.planning.strategy} primitive library"
    steep = steep_reason(scenario, read_climb_overrides(key="steep_ladder"))
    return "primitives", f"{reason}; {steep}" if steep else reason


def scene_settings(settings: PlannerSettings, overrides_file: str | pathlib.Path = CLIMB_OVERRIDES_FILE
                   ) -> PlannerSettings:
    """``settings`` for a walked scenario (:func:`walked`): the ``climb.scene_planner_overrides`` of
    ``overrides_file`` applied on top (config/climb.yaml: a scene plans with the planner's own
    torque shares, not the ladder's headroom; "" for none)."""
    return apply_overrides(settings, read_climb_overrides(overrides_file, "scene_planner_overrides"),
                           where=f"{overrides_file or 'planner_overrides'}:climb.scene_planner_overrides")


def scenario_settings(settings: PlannerSettings, scenario: Any) -> PlannerSettings:
    """``settings`` with the scenario's own ``planner_overrides`` applied (a scene file's tuning,
    argued in the file: narrow_passage's sole margins and speeds); SpecError
    ``scenario.planner_overrides.<group.field>`` for an unknown setting or a bad value."""
    overrides = dict(getattr(scenario, "planner_overrides", ()) or ())
    return apply_overrides(settings, overrides, where="scenario.planner_overrides") if overrides else settings


def steep_ladder(scenario: Any, steep: Mapping[str, Any]) -> bool:
    """Whether ``scenario`` is a ladder at least ``steep["min_incline_deg"]`` steep (config/climb.yaml's
    ``steep_ladder``; a missing or 0 bound: never)."""
    ladder = getattr(scenario, "ladder", None)
    bound = steep_bound(steep)
    return ladder is not None and bound > 0.0 and float(ladder.inclination_deg) >= bound


def steep_bound(steep: Mapping[str, Any]) -> float:
    """[deg] ``steep["min_incline_deg"]`` (0 when missing or null), checked as it is read: SpecError
    ``climb.steep_ladder.<field>`` for a bound that is not a number in [0, 90] or
    ``planner_overrides`` that are not a mapping (the planning nodes read the block themselves;
    the climb's own loader checks it the same way)."""
    from climb_core.errors import SpecError

    if not isinstance(steep, Mapping):
        raise SpecError("climb.steep_ladder", f"must be a mapping, got {type(steep).__name__}")
    bound = steep.get("min_incline_deg", 0.0)
    bound = 0.0 if bound is None else bound
    if isinstance(bound, bool) or not isinstance(bound, (int, float)) or not 0.0 <= float(bound) <= 90.0:
        raise SpecError("climb.steep_ladder.min_incline_deg", f"must be a number of degrees in [0, 90], got {bound!r}")
    if not isinstance(steep.get("planner_overrides") or {}, Mapping):
        raise SpecError("climb.steep_ladder.planner_overrides", "must be a mapping of dotted planner settings")
    return float(bound)


def steep_reason(scenario: Any, steep: Mapping[str, Any]) -> str:
    """What a steep ladder (:func:`steep_ladder`) plans with, for the strategy's logged reason ("" if
    it is not one)."""
    if not steep_ladder(scenario, steep):
        return ""
    keys = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}"
                     for k, v in (steep.get("planner_overrides") or {}).items())
    return (f"steep (>= {float(steep['min_incline_deg']):g} deg, climb.steep_ladder): its one-foot stances on a "
            f"round rung lean on the grasps, planned within the controller's grasp moments ({keys})")


def settings_for_scenario(settings: PlannerSettings, scenario: Any,
                          scene_overrides: Mapping[str, Any] | None = None,
                          steep: Mapping[str, Any] | None = None) -> PlannerSettings:
    """The settings a scenario is planned with, in the one order every caller uses: ``settings``
    (config/planner.yaml with the climb's planner_overrides), then for a walked scenario
    (:func:`walked`: a scene, stairs) the scene overrides (``scene_overrides``, default
    config/climb.yaml's ``scene_planner_overrides``), for a steep ladder (:func:`steep_ladder`) the
    steep ladder's (``steep``, default config/climb.yaml's ``steep_ladder``: its bound and its
    ``planner_overrides``), then the scenario file's own ``planner_overrides``
    (:func:`scenario_settings`), last."""
    if walked(scenario, settings):
        if scene_overrides is None:
            settings = scene_settings(settings)
        else:
            settings = apply_overrides(settings, dict(scene_overrides), where="climb.scene_planner_overrides")
    else:
        steep = read_climb_overrides(key="steep_ladder") if steep is None else steep
        if steep_ladder(scenario, steep):
            settings = apply_overrides(settings, dict(steep.get("planner_overrides") or {}),
                                       where="climb.steep_ladder.planner_overrides")
    return scenario_settings(settings, scenario)


def climb_settings(overrides_file: str | pathlib.Path = CLIMB_OVERRIDES_FILE,
                   base: PlannerSettings | None = None) -> PlannerSettings:
    """The planner settings the climb plans with: config/planner.yaml (or ``base``) with the
    ``climb.planner_overrides`` of ``overrides_file`` applied ("" for none)."""
    return apply_overrides(base or load_settings(), read_climb_overrides(overrides_file),
                           where=f"{overrides_file or 'planner_overrides'}:climb.planner_overrides")
