"""Generic contact-body paths (planner_node.contact_path): a contact plan made whole-body without
any motion primitive, checked for the physical facts the controller relies on."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from climb_core import collision, feasibility
from climb_core.contact import FEET, HANDS, ContactPlan
from controller_node.plan_check import check_plan
from planner_node import contact_path
from planner_node.adapt import AdaptContext, ContactProjector, zone_exclusions
from planner_node.climb_planner import contact_plan_steps, plan_from_contact_plan
from planner_node.pcik import check_with_exclusions
from planner_node.pipeline import PlanRequest, contact_search, guide_path, load_problem
from planner_node import settings as settings_mod
from planner_node.settings import load_settings


@pytest.fixture(scope="module")
def problem():
    pb = load_problem(PlanRequest(id="generic", robot="g1", scenario="default", rungs=1), load_settings())
    cp = contact_search(pb, guide_path(pb).product).product
    return pb, cp


@pytest.fixture(scope="module")
def generic_plan(problem):
    pb, cp = problem
    library = contact_path.empty_library(pb.robot)
    t0 = time.perf_counter()
    res = plan_from_contact_plan(pb.robot, pb.env, cp, library=library, settings=pb.settings, seed=0)
    elapsed = time.perf_counter() - t0
    print(f"\ngeneric paths, 1 rung of the default ladder: {len(cp.stances) - 1} steps planned in {elapsed:.1f} s "
          f"(cpu {res.plan_cpu_s:.1f} s), {res.report.n_attempts} attempts, {res.report.n_backtracks} backtracks")
    return res, library


def _previous_stances(plan):
    return [plan.initial_stance] + [t.target_stance for t in plan.transitions[:-1]]


def test_every_step_of_the_contact_plan_is_generic_without_a_library(problem, generic_plan):
    pb, cp = problem
    res, library = generic_plan
    steps = contact_plan_steps(library, cp)
    assert steps and all(s.primitive is None for s in steps)
    assert res.success, f"{res.failure_constraint}: {res.failure_detail}"
    assert len(res.plan.transitions) == len(cp.stances) - 1
    # the stances the contact search chose are the ones reached (no release in this plan)
    for t, stance in zip(res.plan.transitions, cp.stances[1:]):
        assert sorted(t.target_stance.limbs) == sorted(stance.limbs)
        for h in stance.holds:
            got = t.target_stance.hold(h.limb)
            assert got.env_surface == h.env_surface and np.allclose(got.centre, h.centre, atol=1e-6)
    feet = [res.plan.transitions[-1].target_stance.hold(f).env_surface for f in FEET]
    assert feet == ["rung_1", "rung_1"]


def test_the_controller_accepts_the_plan_and_its_fsm_names(problem, generic_plan):
    pb, _ = problem
    res, _ = generic_plan
    check_plan(res.plan, pb.robot, pb.env)
    for t in res.plan.transitions:
        if t.moving_limb:
            assert t.primitive == ("place_hand" if t.moving_limb in HANDS else "place_foot")
            assert t.stance.hold(t.moving_limb) is None and t.target_stance.hold(t.moving_limb) is not None
        else:
            assert t.primitive in ("com_to_foot", "com_to_centre")
        assert np.all(np.diff(t.times) > 0.0)


def test_paths_keep_their_holds_and_stay_collision_free(problem, generic_plan):
    pb, _ = problem
    res, library = generic_plan
    frozen = feasibility.load_config()
    tol_p = frozen.check.contact_position_tolerance
    tol_a = math.radians(frozen.check.contact_angle_tolerance_deg)
    ctx = AdaptContext(pb.robot, pb.env, library, pb.settings)
    chk = collision.checker(pb.robot, pb.env, frozen.collision)
    worst = np.inf
    for k, (t, before) in enumerate(zip(res.plan.transitions, _previous_stances(res.plan))):
        projector = ContactProjector(ctx, t.stance, t.path[0])
        zone = [before.hold(t.moving_limb), t.target_stance.hold(t.moving_limb)] if t.moving_limb else []
        for i, q in enumerate(t.path):
            pos, ang = projector.errors(q)
            assert pos <= tol_p and ang <= tol_a, (
                f"transition {k} ({t.primitive}) q[{i}]: holds off by {pos} m, {ang} rad")
            excluded = [(h.limb, h.env_surface) for h in t.stance.holds] + zone_exclusions(ctx, q, t.moving_limb, zone)
            d = chk.distances(q, excluded)
            assert d.min_distance >= 0.0, f"transition {k} q[{i}]: {d.pair} at {d.min_distance} m"
            worst = min(worst, d.min_distance)
    print(f"least clearance along the paths: {worst * 1e3:.1f} mm")


def test_each_transition_ends_feasible_and_a_moving_limb_is_lifted(problem, generic_plan):
    pb, _ = problem
    res, library = generic_plan
    frozen = feasibility.load_config()
    ctx = AdaptContext(pb.robot, pb.env, library, pb.settings)
    clearance = pb.settings.contact_path.lift_clearance
    transitions = res.plan.transitions
    lifted = 0
    for k, (t, before) in enumerate(zip(transitions, _previous_stances(res.plan))):
        end = t.path[-1]
        r = feasibility.check(pb.robot, pb.env, end, t.target_stance, frozen)
        assert r.feasible, f"transition {k} ({t.primitive}): end not feasible: {r.violated}"
        nxt = transitions[k + 1] if k + 1 < len(transitions) else None
        if nxt is not None and nxt.moving_limb and t.target_stance.hold(nxt.moving_limb) is not None:
            # the next transition releases that limb first: the others carry the robot here
            old = t.target_stance.hold(nxt.moving_limb)
            r = check_with_exclusions(pb.robot, pb.env, end, nxt.stance, frozen, [(old.limb, old.env_surface)])
            assert r.feasible, f"transition {k}: {old.limb} not removable at the end: {r.violated}"
        old = before.hold(t.moving_limb) if t.moving_limb else None
        if old is None:
            continue
        n = contact_path.hold_direction(ctx, old, t.path[0])
        p0 = pb.robot.T_world_surface(t.moving_limb, t.path[0])[:3, 3]
        m = len(t.path)
        middle = t.path[m // 4: m - m // 4]
        lift = max(float((pb.robot.T_world_surface(t.moving_limb, q)[:3, 3] - p0) @ n) for q in middle)
        assert lift >= clearance, f"transition {k}: {t.moving_limb} lifted {lift:.3f} m < {clearance} m"
        lifted += 1
    assert lifted >= 4  # both feet off the ground onto rung 1, both hands from rung to rung


def test_a_released_limb_is_a_com_shift_then_its_placement(problem, tmp_path):
    pb, cp = problem
    library = contact_path.empty_library(pb.robot)
    # the search's form of a step: remove the left foot, then add it on its new hold
    a, b = cp.stances[0], cp.stances[2]
    assert a.hold("left_foot") is not None and b.hold("left_foot").centre[0] > a.hold("left_foot").centre[0] + 0.1
    split = ContactPlan(cp.robot, cp.environment, cp.joint_names, [a, a.without("left_foot"), b],
                        list(cp.transition_configurations[:3]))
    steps = contact_plan_steps(library, split)
    assert [(s.kind, s.limb, s.unload) for s in steps] == [("release", "left_foot", ("left_foot",)),
                                                           ("limb", "left_foot", ())]
    # no library on disk (an empty primitives directory): the planner falls back to generic paths
    no_library = settings_mod.replace(pb.settings, "planning", primitives_dir=str(tmp_path))
    res = plan_from_contact_plan(pb.robot, pb.env, split, settings=no_library, seed=0)
    assert res.success, f"{res.failure_constraint}: {res.failure_detail}"
    assert res.subtasks == ["release_left_foot_0", "generic_left_foot_1"]
    shift, place = res.plan.transitions
    # the CoM shift keeps the foot held (the FSM releases it when the placement starts) ...
    assert shift.moving_limb == "" and shift.primitive == "com_to_foot"
    assert shift.target_stance.hold("left_foot") is not None
    frozen = feasibility.load_config()
    old = a.hold("left_foot")
    r = check_with_exclusions(pb.robot, pb.env, shift.path[-1], a.without("left_foot"), frozen,
                              [("left_foot", old.env_surface)])
    assert r.feasible, r.violated  # ... and ends in equilibrium without it
    assert place.moving_limb == "left_foot" and place.stance.hold("left_foot") is None
    assert feasibility.check(pb.robot, pb.env, place.path[-1], place.target_stance, frozen).feasible
    check_plan(res.plan, pb.robot, pb.env)


def test_a_step_changing_two_holds_is_still_rejected(problem):
    pb, cp = problem
    a, b = cp.stances[0], cp.stances[-1]
    bad = ContactPlan(cp.robot, cp.environment, cp.joint_names, [a, b], cp.transition_configurations[:2])
    from climb_core.errors import SpecError

    with pytest.raises(SpecError) as err:
        contact_plan_steps(contact_path.empty_library(pb.robot), bad)
    assert err.value.field == "contact_plan.stances[1]"


def test_a_cycle_of_the_best_first_search_becomes_a_whole_body_plan(problem):
    """The search's own form (a hold removed, then added: stances differing by one hold) for one
    cycle from feet on rung 1, hands on rung 5: each release a CoM shift, then the placement."""
    from climb_core import fixtures
    from climb_core.contact import GuidePath
    from planner_node import contact_search

    pb, _ = problem
    robot, env = pb.robot, pb.env
    stance0, q0 = fixtures.get("ladder_4_contacts", robot, env)
    q1 = q0.copy()
    q1[:3] += env.rung_centre(2) - env.rung_centre(1)
    found = contact_search.search(robot, env, q0, stance0, GuidePath("g1", env.name, list(robot.joint_names), [q0, q1]))
    cp = found.plan
    assert all(abs(len(a.holds) - len(b.holds)) == 1 for a, b in zip(cp.stances[:-1], cp.stances[1:]))
    t0 = time.perf_counter()
    res = plan_from_contact_plan(robot, env, cp, library=contact_path.empty_library(robot), settings=pb.settings,
                                 seed=0)
    print(f"\nbest-first search cycle: {len(cp.stances) - 1} stance changes made whole-body in "
          f"{time.perf_counter() - t0:.1f} s, {res.report.n_backtracks} backtracks")
    assert res.success, f"{res.failure_constraint}: {res.failure_detail}"
    check_plan(res.plan, robot, env)
    frozen = feasibility.load_config()
    for k, (t, a, b) in enumerate(zip(res.plan.transitions, cp.stances[:-1], cp.stances[1:])):
        released = [h for h in a.holds if b.hold(h.limb) is None]
        if released:  # a CoM shift that keeps the limb held and ends with the other holds carrying the robot
            limb = released[0].limb
            assert t.moving_limb == "" and t.target_stance.hold(limb) is not None
            nxt = res.plan.transitions[k + 1]
            assert nxt.moving_limb == limb and nxt.stance.hold(limb) is None
            r = check_with_exclusions(robot, env, t.path[-1], nxt.stance, frozen, [(limb, released[0].env_surface)])
            assert r.feasible, f"transition {k}: {limb} not removable: {r.violated}"
        else:
            limb = t.moving_limb
            assert limb and t.target_stance.hold(limb).env_surface == b.hold(limb).env_surface
        assert feasibility.check(robot, env, t.path[-1], t.target_stance, frozen).feasible, k
    last = res.plan.transitions[-1].target_stance
    assert [last.hold(f).env_surface for f in FEET] == ["rung_2", "rung_2"]


def test_a_limb_freed_for_good_is_lifted_further_on_each_retry():
    """The first attempt lifts a freed limb like a transfer; a retry (the step below a stuck one,
    backtracked into) draws a higher lift, so its kept posture clears the surface it left."""
    from types import SimpleNamespace

    p = settings_mod.ContactPathParams(lift_clearance=0.05, free_lift_max=0.15)
    ctx = SimpleNamespace(settings=SimpleNamespace(contact_path=p))
    rng = np.random.default_rng(0)
    assert contact_path.free_lift(ctx, 0, rng) == 0.05
    lifts = [contact_path.free_lift(ctx, k, rng) for k in range(1, 40)]
    assert all(0.05 <= h <= 0.15 for h in lifts) and max(lifts) > 0.12 and len(set(lifts)) == len(lifts)
    flat = SimpleNamespace(settings=SimpleNamespace(contact_path=settings_mod.ContactPathParams(
        lift_clearance=0.05, free_lift_max=0.0)))
    assert contact_path.free_lift(flat, 3, rng) == 0.05


def test_a_hand_freed_for_good_folds_to_the_reference_posture_first_then_alternates(g1):
    """With ``free_rest`` the first attempt brings a freed hand's arm to the robot's reference
    (standing) posture, the second keeps the lift-off posture, later ones blend the two; a foot,
    or ``free_rest`` off, keeps the lift-off posture."""
    from types import SimpleNamespace

    ref = g1.q_reference()
    q_lift = ref.copy()
    arm = contact_path.limb_joint_indices(g1, "right_hand")
    q_lift[arm] += 0.8  # an arm raised toward a rail
    ctx = SimpleNamespace(robot=g1, settings=SimpleNamespace(contact_path=settings_mod.ContactPathParams()))
    rng = np.random.default_rng(0)
    first = contact_path.freed_posture(ctx, "right_hand", q_lift, 0, rng)
    assert np.allclose(first[arm], ref[arm]) and np.allclose(np.delete(first, arm), np.delete(q_lift, arm))
    assert np.array_equal(contact_path.freed_posture(ctx, "right_hand", q_lift, 1, rng), q_lift)
    blends = [contact_path.freed_posture(ctx, "right_hand", q_lift, k, rng)[arm] for k in (2, 4, 6)]
    for b in blends:  # between the two, strictly inside for at least the one joint moved
        s = (q_lift[arm][0] - b[0]) / 0.8
        assert 0.3 - 1e-9 <= s <= 1.0 + 1e-9 and np.allclose(b, q_lift[arm] - s * 0.8)
    assert np.array_equal(contact_path.freed_posture(ctx, "right_foot", q_lift, 0, rng), q_lift)
    off = SimpleNamespace(robot=g1, settings=SimpleNamespace(
        contact_path=settings_mod.ContactPathParams(free_rest=False)))
    assert np.array_equal(contact_path.freed_posture(off, "right_hand", q_lift, 0, rng), q_lift)


def test_a_foot_goes_up_a_ship_ladders_overhanging_treads_behind_their_noses(g1):
    """The ship ladder's treads (17 cm deep, 12.5 cm run) overhang the one below by 4.5 cm: a foot
    on tread 1 rising straight up meets tread 2's nose with its toes. The cues lift the released
    foot off tread 1, back it off until the sole's front is ``step_edge_clearance`` behind tread 2's
    near edge, rise straight up and come onto tread 2 from above."""
    from climb_core import fixtures, holds
    from climb_core.environment import build_environment

    ship = build_environment("ship")
    settings = load_settings()
    p = settings.contact_path
    ctx = AdaptContext(g1, ship, contact_path.empty_library(g1), settings)
    _, q = fixtures.get("standing", g1, ship)

    def on(k):  # the standing robot moved so that its right sole is centred on tread k
        out = q.copy()
        sole = np.asarray(g1.T_world_surface("right_foot", q))[:3, 3]
        tread = ship.rung(k)
        out[:3] += np.array([tread.position[0], sole[1], tread.top_z]) - sole
        return out

    q_s, q_e = on(1), on(2)
    old = holds.hold_from_configuration(g1, ship, q_s, "right_foot", "rung_1")
    new = holds.hold_from_configuration(g1, ship, q_e, "right_foot", "rung_2")
    cues, fractions = contact_path.limb_cues(ctx, "right_foot", old, new, q_s, q_e)
    points = np.array([c[:3, 3] for c in cues])
    p_s = np.asarray(g1.T_world_surface("right_foot", q_s))[:3, 3]
    p_e = np.asarray(g1.T_world_surface("right_foot", q_e))[:3, 3]
    assert np.allclose(points[0], p_s + [0.0, 0.0, p.lift_clearance], atol=1e-6)  # lifted first
    assert np.allclose(points[-1], p_e + [0.0, 0.0, p.approach_distance], atol=1e-6)  # onto it from above
    assert np.all(np.diff(fractions) > 0.0)
    # the sole's front (toe, +x) behind tread 2's near edge wherever the sole is at the tread's
    # height (between its bottom and its top), along the polyline of the cues
    toe = float(np.max(holds.sole_vertices_in_surface(holds.limb_surface(g1, "right_foot"))[:, 0]))
    tread2 = ship.rung(2)
    nose = tread2.position[0] - tread2.half_extents[1]
    line = np.concatenate([[p_s], points])
    along = np.array([a + s * (b - a) for a, b in zip(line[:-1], line[1:]) for s in np.linspace(0.0, 1.0, 50)])
    level = along[(along[:, 2] > tread2.top_z - 2.0 * tread2.half_extents[2]) & (along[:, 2] < tread2.top_z)]
    assert len(level) and level[:, 0].max() + toe <= nose - p.step_edge_clearance + 1e-6, (points, nose)
