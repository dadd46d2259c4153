"""Primitive adaptation pieces (planner_node.adapt, interpolation, primitives) for G1."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from climb_core import feasibility, fixtures, holds
from climb_core.errors import SpecError
from planner_node import adapt as A
from planner_node import interpolation as interp
from planner_node.primitives import load_library, parse_primitive, to_ladder, to_world
from planner_node.settings import load_settings


@pytest.fixture(scope="module")
def ctx(g1, env):
    return A.AdaptContext(g1, env, load_library("g1", "forward", nq=g1.model.nq), load_settings())


def set_joint(robot, q, name, value):
    q[robot.model.joints[robot.model.getJointId(name)].idx_q] = value


def test_algorithm1_retracts_a_colliding_seed(g1, env, ctx):
    stance, q = fixtures.get("ladder_no_left_foot", g1, env)
    seed = q.copy()
    # the free left leg folded forward: its knee goes 6 cm deep into rung 3
    set_joint(g1, seed, "left_hip_pitch_joint", -0.9)
    set_joint(g1, seed, "left_knee_joint", 1.0)
    before = ctx.check(seed, stance)
    assert "collision" in before.violated and before.min_distance < -0.03
    ctx.stats = A.AdaptStats()
    proj = A.project(ctx, seed, stance, np.random.default_rng(0))
    assert proj.q is not None, proj.failure
    # the contact projection alone left it colliding: the retraction (physics-constrained IK) fixed it
    assert ctx.stats.pcik_successes >= 1
    after = feasibility.check(g1, env, proj.q, stance)
    assert after.feasible and after.min_distance >= 0.0
    # and it stayed close to the seed where nothing collided (the right leg, the arms)
    right_leg = [g1.model.joints[g1.model.getJointId(j)].idx_q for j in g1.config.limbs["right_foot"].joints]
    assert np.abs(proj.q[right_leg] - seed[right_leg]).max() < 0.3


def test_algorithm1_reports_unreachable_holds(g1, env, ctx):
    st, q = fixtures.get("standing", g1, env)
    far = st.with_hold(holds.make_hold(g1, env, "left_hand", "rung_8", 0.15))
    proj = A.project(ctx, q, far, np.random.default_rng(0))
    assert proj.q is None
    assert proj.failure == "reach:left_hand"
    assert proj.failures["reach:left_hand"] == ctx.settings.projection.restarts + 1


def test_seed_hold_rules_follow_the_ladder(g1, env, ctx):
    lib = ctx.library
    st4, q4 = fixtures.get("ladder_4_contacts", g1, env)  # feet on rung 1, hands on rung 5
    state = A.ClimbState(q4, st4)
    place_lf = lib.primitives["place_left_foot"]
    h = A.sample_target_hold(ctx, place_lf, state, 0, np.random.default_rng(0))
    assert h.env_surface == "rung_2" and abs(h.centre[1] - 0.12) < 1e-9  # next rung, seed position
    # later attempts sample around the seed hold, within the configured bound
    ys = [A.sample_target_hold(ctx, place_lf, state, j, np.random.default_rng(j)).centre[1] for j in range(1, 6)]
    assert all(abs(y - 0.12) <= ctx.settings.sampling.lateral_max + 1e-9 for y in ys)
    assert len(set(np.round(ys, 6))) > 1
    # hands go to the rung nearest the designed height above the feet: here already there -> skip
    assert A.sample_target_hold(ctx, lib.primitives["place_left_hand"], state, 0, np.random.default_rng(0)) == A.SKIP
    # attempt 3 tries the rung above
    h3 = A.sample_target_hold(ctx, lib.primitives["place_left_hand"], state, 3, np.random.default_rng(0))
    assert h3.env_surface == "rung_6"
    # mount from the ground: the rung nearest the designed mount height
    st0, q0 = fixtures.get("standing", g1, env)
    hm = A.sample_target_hold(ctx, lib.primitives["mount_left_hand"], A.ClimbState(q0, st0), 0,
                              np.random.default_rng(0))
    assert hm.env_surface == "rung_4" and hm.bilateral


def test_zone_exclusions_only_near_the_holds(g1, env, ctx):
    st4, q4 = fixtures.get("ladder_4_contacts", g1, env)
    lf = st4.hold("left_foot")
    assert A.zone_exclusions(ctx, q4, "left_foot", [lf]) == [("left_foot", "rung_1")]
    st3, q3 = fixtures.get("ladder_no_left_foot", g1, env)  # foot lifted 6 cm and pulled back 8 cm
    assert A.zone_exclusions(ctx, q3, "left_foot", [lf]) == []
    assert A.zone_exclusions(ctx, q4, "", [lf]) == []


def test_linear_transform_maps_the_primitive_onto_new_end_points(g1):
    model = g1.model
    q0 = g1.q_reference()
    rng = np.random.default_rng(1)
    wps = [pin.integrate(model, q0, 0.2 * rng.standard_normal(model.nv)) for _ in range(4)]
    qs = pin.integrate(model, wps[0], 0.1 * rng.standard_normal(model.nv))
    qe = pin.integrate(model, wps[-1], 0.1 * rng.standard_normal(model.nv))
    out = interp.linear_transform(model, wps, qs, qe)
    assert np.allclose(out[0], qs) and np.allclose(out[-1], qe)
    # a pure translation of the end points translates the whole primitive
    d = np.zeros(model.nv)
    d[:3] = [0.05, 0.0, 0.24]
    qs2, qe2 = pin.integrate(model, wps[0], d), pin.integrate(model, wps[-1], d)
    moved = interp.linear_transform(model, wps, qs2, qe2)
    for a, b in zip(wps, moved):
        assert np.allclose(pin.difference(model, a, b), d, atol=1e-9)


def test_projected_interpolation_keeps_the_contacts(g1, env, ctx):
    st, q = fixtures.get("ladder_4_contacts", g1, env)
    q_b = q.copy()
    set_joint(g1, q_b, "waist_yaw_joint", 0.3)
    q_b = A.ContactProjector(ctx, st, q)(q_b)
    assert q_b is not None
    proj = A.ContactProjector(ctx, st, q)
    path = interp.projected_interpolation(g1.model, q, q_b, proj, 0.02)
    assert path is not None and len(path) >= 3
    assert interp.max_joint_jump(g1.model, path) <= 0.02 + 1e-9
    for qi in path:
        pos, ang = proj.errors(qi)
        assert pos < 1e-3 and ang < 1e-2


def test_time_parameterisation_respects_the_speed_limits(g1):
    model = g1.model
    q0 = g1.q_reference()
    path = [pin.integrate(model, q0, np.full(model.nv, 0.01 * k)) for k in range(6)]
    t = interp.time_parameterize(model, path, 0.4, 0.1, 0.3, min_duration=0.0, ramp_fraction=0.2)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    for (qa, qb), dt in zip(zip(path[:-1], path[1:]), np.diff(t)):
        dv = pin.difference(model, qa, qb)
        assert np.abs(dv[6:]).max() / dt <= 0.4 + 1e-9
        assert np.linalg.norm(dv[:3]) / dt <= 0.1 + 1e-9


def test_library_round_trip_and_validation(g1, env):
    lib = load_library("g1", "forward", nq=g1.model.nq)
    assert {"mount", "cycle"} <= set(lib.sequences)
    assert all(len(p.waypoints) >= 2 for p in lib.primitives.values())
    # way-points are stored in the ladder frame
    q = fixtures.get("ladder_4_contacts", g1, env)[1]
    assert np.allclose(to_world(env, to_ladder(env, q)), q)
    with pytest.raises(SpecError) as err:
        parse_primitive("bad", {"kind": "limb", "limb": "left_tail"})
    assert err.value.field == "primitives.bad.limb"
    with pytest.raises(SpecError):
        parse_primitive("bad", {"kind": "limb", "limb": "left_foot", "target": {"surface": "rung", "rule": "up"}})
    with pytest.raises(SpecError):
        load_library("g1", "sideways")
