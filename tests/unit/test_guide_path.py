"""The free-flyer guide path (planner_node.guide_path): RRT-Connect with the rough equilibrium
criterion, on the default ladder and on scenes built from Surface objects.

Every path is checked independently of the planner's own culled queries: each milestone's body
clearance with the collision checker's exact pair query, the criterion recomputed, the spacing of
consecutive milestones, determinism for a seed and the wall-time limit."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from climb_core import fixtures
from climb_core.collision import checker
from climb_core.environment import Environment, Surface, build_environment, rpy_deg_to_matrix
from climb_core.errors import InfeasibleError, SpecError
from climb_core.robot import load_robot
from planner_node import guide_path as gp
from planner_node.settings import load_settings

TIME_LIMIT_S = 5.0


@pytest.fixture(scope="module")
def robot():
    return load_robot("g1")


@pytest.fixture(scope="module")
def ladder(robot):
    return build_environment("default")


@pytest.fixture(scope="module")
def params():
    return load_settings().guide_path


@pytest.fixture(scope="module")
def q_standing(robot, ladder):
    return fixtures.get("standing", robot, ladder)[1]


def _box(name: str, size, position, rpy_deg=(0.0, 0.0, 0.0), role: str = "obstacle") -> Surface:
    T = np.eye(4)
    T[:3, :3] = rpy_deg_to_matrix(rpy_deg)
    T[:3, 3] = position
    return Surface(name, role, "box", T, half_extents=0.5 * np.asarray(size, dtype=float), friction=0.6)


def _bar(name: str, radius: float, length: float, position, yaw_deg: float = 0.0) -> Surface:
    T = np.eye(4)
    T[:3, :3] = rpy_deg_to_matrix((0.0, 0.0, yaw_deg))
    T[:3, 3] = position
    return Surface(name, "rail", "cylinder", T, radius=radius, length=length,
                   half_extents=np.array([0.5 * length, radius, radius]), friction=0.6)


class SurfaceEnvironment(Environment):
    """An Environment from Surface objects with each surface's limb types given explicitly (the
    scene spec's ``contact`` field)."""

    def __init__(self, name: str, base: Environment, surfaces: list[Surface], use: dict[str, tuple[str, ...]],
                 keep_base: bool = False):
        kept = list(base.surfaces.values()) if keep_base else [base.surfaces["ground"]]
        super().__init__(base.scenario, {s.name: s for s in [*kept, *surfaces]}, False, base.T_world_ladder)
        self._name = name
        self._use = {s.name: tuple(k for k in ("foot", "hand") if s in gp.contact_surfaces(base, k)) for s in kept}
        self._use.update(use)

    @property
    def name(self) -> str:
        return self._name

    def contact_surfaces(self, limb_type: str) -> list[Surface]:
        return [s for s in self.surfaces.values() if limb_type in self._use.get(s.name, ())]


def assert_valid_path(result: gp.GuideResult, robot, env, q_start, goal, tolerance, params) -> None:
    path = result.path
    assert path.robot == robot.config.name and path.joint_names == list(robot.joint_names)
    assert len(path.milestones) >= 2 and np.array_equal(path.milestones[0], q_start)
    assert all(q.shape == (robot.nq,) and np.isfinite(q).all() for q in path.milestones)
    # the last milestone's base within the goal tolerance
    assert np.linalg.norm(path.milestones[-1][:3] - goal) <= tolerance + 1e-9
    pl = gp._planner(robot, env, params)
    exact = checker(robot, env).pair_query(pl.body_pairs)
    for i, (q, x) in enumerate(zip(path.milestones, result.states)):
        d = exact.compute(q)
        assert d.min() >= params.body_clearance - 1e-9, (i, d.min())
        assert pl.support(x, q).ok, i
        if i:
            assert np.allclose(q, pl.configuration(x))
            np.testing.assert_allclose(np.linalg.norm(q[3:7]), 1.0, atol=1e-9)
    steps = [float(pl.metric(a, b)[0]) for a, b in zip(result.states[:-1], result.states[1:])]
    assert max(steps) <= params.milestone_spacing + 1e-9, steps


def _plan(robot, env, q0, goals, params, seed=0, limit=TIME_LIMIT_S):
    t = time.perf_counter()
    result = gp.plan_guide_path_through(robot, env, q0, goals, params, seed=seed, time_limit_s=limit)
    return result, time.perf_counter() - t


# --------------------------------------------------------------------------------------------


def test_reference_postures_file_matches_the_project_configurations(robot, ladder, params):
    """config/guide_postures/g1.yaml is what derive_reference_postures gives (no drift)."""
    post = gp.load_reference_postures(robot, params)
    derived = gp.derive_reference_postures(robot, ladder)
    assert set(post.names) == set(gp.REQUIRED_POSTURES)
    for name, (joints, pitch, _) in derived.items():
        i = post.index(name)
        np.testing.assert_allclose(post.joints[i], [joints[j] for j in robot.joint_names], atol=1e-4)
        assert post.root_pitch[i] == pytest.approx(pitch, abs=1e-4)
    assert post.root_pitch[post.index("climbing")] < -0.1  # the ladder fixture leans its pelvis back


def test_limb_lengths_and_criterion_at_the_fixtures(robot, ladder, params, q_standing):
    pl = gp._planner(robot, ladder, params)
    lengths = pl.limb_lengths
    assert 0.7 < lengths["left_foot"] < 0.8 and lengths["left_foot"] == pytest.approx(lengths["right_foot"])
    assert 0.45 < lengths["left_hand"] < 0.6 and lengths["left_hand"] == pytest.approx(lengths["right_hand"])
    x = gp.state_of(pl, q_standing)
    report = pl.support(x, q_standing)
    assert report.ok and set(report.limbs) == {"left_foot", "right_foot"}
    _, q_ladder = fixtures.get("ladder_4_contacts", robot, ladder)
    report = pl.support(gp.state_of(pl, q_ladder), q_ladder)
    assert report.ok and set(report.limbs) == {"left_foot", "right_foot", "left_hand", "right_hand"}
    assert report.limbs["left_hand"].startswith("rung_")
    # floating 1 m above the standing pose: nothing within reach
    up = x.copy()
    up[2] += 1.0
    assert not pl.support(up).ok


def test_culled_clearance_agrees_with_the_exact_query(robot, ladder, params):
    pl = gp._planner(robot, ladder, params)
    exact = checker(robot, ladder).pair_query(pl.body_pairs)
    rng = np.random.default_rng(3)
    for _ in range(40):
        x = np.array([rng.uniform(-0.2, 0.8), rng.uniform(-0.3, 0.3), rng.uniform(0.6, 1.8),
                      rng.uniform(-0.5, 0.5), rng.uniform(0.0, 2.0)])
        q = pl.configuration(x)
        d, _ = pl.clearance(q)
        true = exact.compute(q).min()
        below = true < params.body_clearance
        assert (d < params.body_clearance) == below
        assert d >= true - 1e-6 if below else d <= true + 1e-6  # a pair's distance / a lower bound


def test_default_ladder_three_rungs(robot, ladder, params, q_standing):
    goals = gp.ladder_goals(robot, ladder, 3, 0.1)
    result, elapsed = _plan(robot, ladder, q_standing, goals, params)
    print(f"\nguide path default ladder 3 rungs: {elapsed:.3f} s, {len(result.path.milestones)} milestones, "
          f"{result.stats.as_dict()}")
    assert elapsed < TIME_LIMIT_S
    assert_valid_path(result, robot, ladder, q_standing, goals[-1].position, 0.1, params)
    # one rung apart: each rung's goal is passed within tolerance, in order, by some milestone
    bases = np.array([q[:3] for q in result.path.milestones])
    hits = [int(np.argmin(np.linalg.norm(bases - g.position, axis=1))) for g in goals]
    assert hits == sorted(hits)
    assert all(np.linalg.norm(bases[h] - g.position) <= 0.1 for h, g in zip(hits, goals))
    # the standing-on-rung goal: feet-rung offset of the fixture, one rung spacing apart
    step = goals[1].position - goals[0].position
    assert np.linalg.norm(step) == pytest.approx(ladder.ladder.rung_spacing, abs=1e-9)
    # deterministic for a seed
    again, _ = _plan(robot, ladder, q_standing, goals, params)
    assert len(again.path.milestones) == len(result.path.milestones)
    assert all(np.array_equal(a, b) for a, b in zip(again.path.milestones, result.path.milestones))


def test_default_ladder_around_a_wall(robot, ladder, params, q_standing):
    """Start 1.5 m back and 0.8 m to the left with a wall across the straight line to the ladder:
    the trees grow from biased, projected samples around the wall's end; the path is as valid."""
    env = SurfaceEnvironment("test_ladder_wall", ladder, [_box("wall", (0.2, 1.4, 1.0), (-0.7, 0.95, 0.5))], {},
                             keep_base=True)
    q0 = q_standing.copy()
    q0[:2] = (-1.5, 0.8)
    goals = gp.ladder_goals(robot, env, 2, 0.1)
    result, elapsed = _plan(robot, env, q0, goals, params, seed=2)
    print(f"\nguide path ladder behind a wall, 2 rungs: {elapsed:.3f} s, {result.stats.as_dict()}")
    assert elapsed < TIME_LIMIT_S and result.stats.samples > 0
    assert_valid_path(result, robot, env, q0, goals[-1].position, 0.1, params)
    # it passes the wall's plane (x = -0.7) beyond the wall's end (y < 0.25) minus the body's half width
    crossing = [q[1] for a, q in zip(result.path.milestones[:-1], result.path.milestones[1:]) if a[0] < -0.7 <= q[0]]
    assert crossing and crossing[0] < 0.25


def test_ladder_from_the_four_contact_stance(robot, ladder, params):
    """From the ladder_4_contacts fixture (feet on rung 1: the first rung goal is the start), the
    milestones are the start and one per further rung, one rung spacing apart."""
    _, q = fixtures.get("ladder_4_contacts", robot, ladder)
    result = gp.plan_for_environment(robot, ladder, q, rungs=3, params=params, seed=0, time_limit_s=TIME_LIMIT_S)
    bases = np.array([m[:3] for m in result.path.milestones])
    assert len(bases) == 3
    np.testing.assert_allclose(np.diff(bases, axis=0), [ladder.rung_centre(2) - ladder.rung_centre(1)] * 2, atol=1e-9)
    assert_valid_path(result, robot, ladder, q, gp.ladder_goal_position(robot, ladder, 3), 0.1, params)


def test_goal_in_collision(robot, ladder, params, q_standing):
    goal = ladder.rung(4).position  # the pelvis inside rung 4
    t = time.perf_counter()
    with pytest.raises(InfeasibleError) as err:
        gp.plan_guide_path(robot, ladder, q_standing, goal, 0.03, params, seed=0, time_limit_s=2.0)
    assert err.value.constraint == "guide_path:goal_in_collision"
    assert time.perf_counter() - t < 2.0 + 0.5


def test_goal_out_of_reach(robot, ladder, params, q_standing):
    """The top of a 2 m block standing alone: supported and collision-free, but no supported path
    climbs it (no hand surface, walls out of reach)."""
    block = _box("far_block", (1.0, 1.0, 2.0), (-3.0, 0.0, 1.0))
    env = SurfaceEnvironment("test_far_block", ladder, [block], {"far_block": ("foot",)}, keep_base=True)
    goal = np.array([-3.0, 0.0, 2.0 + 0.78])
    pl = gp._planner(robot, env, params)
    x = np.array([*goal, math.pi, float(pl.postures.index("standing"))])
    assert pl.valid(x) == ""  # the goal itself is fine
    limit = 1.5
    t = time.perf_counter()
    with pytest.raises(InfeasibleError) as err:
        gp.plan_guide_path(robot, env, q_standing, goal, 0.1, params, seed=0, time_limit_s=limit)
    elapsed = time.perf_counter() - t
    assert err.value.constraint == "guide_path:goal_unreachable", str(err.value)
    assert limit <= elapsed < limit + 0.5


def test_start_in_collision_and_bad_input(robot, ladder, params, q_standing):
    q = q_standing.copy()
    q[:3] = ladder.rung(2).position + [0.0, 0.0, 0.1]
    with pytest.raises(InfeasibleError) as err:
        gp.plan_guide_path(robot, ladder, q, [0.3, 0.0, 1.0], 0.1, params, time_limit_s=1.0)
    assert err.value.constraint in ("guide_path:start_in_collision", "guide_path:start_unsupported")
    with pytest.raises(SpecError) as spec:
        gp.plan_guide_path(robot, ladder, q_standing, [0.3, 0.0], 0.1, params)
    assert spec.value.field == "guide_path.goal_position"
    with pytest.raises(SpecError) as spec:
        gp.plan_guide_path(robot, ladder, q_standing, [0.3, 0.0, 1.0], 0.0, params)
    assert spec.value.field == "guide_path.goals[0].tolerance"


@pytest.mark.parametrize("scene", ["narrow_passage", "stairs_handrail", "car_ingress"])
def test_scenes(robot, params, scene):
    """The shipped scenes (config/scenes/): from the start pose to the scene's goal."""
    env = build_environment(scene)
    q0 = gp.start_configuration(robot, env)
    gp._planner(robot, env, params)  # built once (collision model, limb lengths): not timed
    t = time.perf_counter()
    result = gp.plan_for_environment(robot, env, q0, params=params, seed=0, time_limit_s=TIME_LIMIT_S)
    elapsed = time.perf_counter() - t
    print(f"\nguide path {scene}: {elapsed:.3f} s, {len(result.path.milestones)} milestones, {result.stats.as_dict()}")
    assert elapsed < TIME_LIMIT_S
    goal = np.asarray(env.goal.base_position)
    assert_valid_path(result, robot, env, q0, goal, env.goal.tolerance, params)
    # the goal is reached standing on a foot surface of the scene, feet supported
    last = gp._planner(robot, env, params).support(result.states[-1])
    foot_surfaces = {x.name for x in gp.contact_surfaces(env, "foot")}
    assert {"left_foot", "right_foot"} <= set(last.limbs)
    assert last.limbs["left_foot"] in foot_surfaces and last.limbs["left_foot"] != "ground"
    again = gp.plan_for_environment(robot, env, q0, params=params, seed=0, time_limit_s=TIME_LIMIT_S)
    assert len(again.path.milestones) == len(result.path.milestones)
    assert all(np.array_equal(a, b) for a, b in zip(again.path.milestones, result.path.milestones))


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["postures"]["standing"]["joints"].update(not_a_joint=0.1), "postures.standing.joints.not_a_joint"),
    (lambda d: d["postures"]["climbing"].update(root_pitch="x"), "postures.climbing.root_pitch"),
    (lambda d: d.pop("body_links"), "body_links"),
    (lambda d: d.update(order=["standing", "climbing"]), "order"),
])
def test_postures_file_rules(robot, params, tmp_path, edit, field):
    import dataclasses

    import yaml

    doc = yaml.safe_load(gp.postures_path("g1", params).read_text())
    edit(doc)
    (tmp_path / "g1.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(SpecError) as err:
        gp.load_reference_postures(robot, dataclasses.replace(params, postures_dir=str(tmp_path)))
    assert err.value.field == f"guide_postures/g1.yaml.{field}"
