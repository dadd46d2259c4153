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


def rel(T_a, T_b):
    """T_a^-1 T_b (4x4)."""
    return np.linalg.inv(T_a) @ T_b


def test_limb_cues_anchor_the_back_off_to_the_start_hold_and_the_approach_to_the_target(g1, env, ctx):
    prim = ctx.library.primitives["place_right_hand"]
    cues = A.limb_cues(ctx, prim)
    w = cues.weights
    assert len(w) == len(prim.waypoints) and w[0] == 0.0 and w[-1] == 1.0 and np.all(np.diff(w) >= 0.0)
    P_s, P_e = cues.poses[0], cues.poses[-1]
    # the back-off (design: 4 then 10 cm along the palm normal, from the start grasp) is start-anchored ...
    back = [i for i, P in enumerate(cues.poses) if np.linalg.norm(rel(P_s, P)[:3, 3] - [0, 0, -0.1]) < 0.015]
    assert back and all(w[i] == 0.0 for i in range(max(back) + 1))
    # ... the approach (10 then 3 cm off the target rung along its palm normal) target-anchored
    near = [i for i, P in enumerate(cues.poses) if np.linalg.norm(rel(P_e, P)[:3, 3] - [0, 0, -0.03]) < 0.015]
    assert near and all(w[i] == 1.0 for i in range(min(near), len(w)))
    # on its own reference ladder, from its own end points, a primitive is re-targeted onto itself
    q_s, q_e = to_world(env, prim.waypoints[0]), to_world(env, prim.waypoints[-1])
    T_ladder = np.asarray(env.T_world_ladder)
    for T, P in zip(A.retarget_poses(ctx, prim, q_s, q_e), cues.poses):
        assert np.allclose(T, T_ladder @ P, atol=1e-6)


def test_retargeted_way_points_keep_their_pose_relative_to_the_actual_holds(g1, env, ctx):
    prim = ctx.library.primitives["place_right_hand"]
    cues = A.limb_cues(ctx, prim)
    q_s, q_e = to_world(env, prim.waypoints[0]), to_world(env, prim.waypoints[-1])
    assert g1.T_world_surface("right_hand", q_s)[2, 3] == pytest.approx(env.surfaces["rung_4"].top_z - 0.02, abs=0.01)
    # the hand rolled about its start rung (as the IK may leave a grasp) and the target 5 cm higher
    i_roll = g1.model.joints[g1.model.getJointId("right_wrist_roll_joint")].idx_q
    q_s[i_roll] += 0.3
    q_e = q_e.copy()
    q_e[2] += 0.05
    T_s, T_e = g1.T_world_surface("right_hand", q_s), g1.T_world_surface("right_hand", q_e)
    # without the start hold: the back-off goes along the actual (rolled) palm normal
    T_new = A.retarget_poses(ctx, prim, q_s, q_e)
    for T, P, w in zip(T_new, cues.poses, cues.weights):
        if w == 0.0:
            assert np.allclose(rel(T_s, T), rel(cues.poses[0], P), atol=1e-6)
        if w == 1.0:  # the approach: relative to where the hand actually lands
            assert np.allclose(rel(T_e, T), rel(cues.poses[-1], P), atol=1e-6)
    assert A.pose_deviation(T_new[0], T_s) == pytest.approx((0.0, 0.0), abs=1e-6)
    # from the grasp it leaves: the back-off counts from that grasp's nominal pose, as designed
    hold = holds.make_hold(g1, env, "right_hand", "rung_4", -prim.seed_s)
    N_s = A.nominal_grasp_pose(ctx, hold, q_s)
    assert A.pose_deviation(N_s, T_s)[1] > 0.2  # the roll the hand has to undo
    T_new = A.retarget_poses(ctx, prim, q_s, q_e, hold)
    back = [i for i, w in enumerate(cues.weights) if w == 0.0 and i > 0]
    assert back
    for i in back:
        assert np.allclose(rel(N_s, T_new[i]), rel(cues.poses[0], cues.poses[i]), atol=2e-3)


def test_the_hand_backoff_scale_lengthens_the_back_off_and_keeps_the_release_and_the_approach(g1, env, ctx):
    from planner_node.settings import apply_overrides

    prim = ctx.library.primitives["place_left_hand"]
    cues = A.limb_cues(ctx, prim)
    q_s, q_e = to_world(env, prim.waypoints[0]), to_world(env, prim.waypoints[-1])
    T_s, T_e = g1.T_world_surface("left_hand", q_s), g1.T_world_surface("left_hand", q_e)

    def backs(poses):  # distance behind the grasps along their normals (z into the rung), blended
        return np.array([(1 - w) * (T_s[:3, 3] - P[:3, 3]) @ T_s[:3, 2] + w * (T_e[:3, 3] - P[:3, 3]) @ T_e[:3, 2]
                         for w, P in zip(cues.weights, poses)])

    plain = A.retarget_poses(ctx, prim, q_s, q_e)
    scaled = apply_overrides(ctx.settings, {"interpolation.hand_backoff_scale": 1.3})
    # the default ladder (75 deg) is below hand_backoff_min_incline_deg (82): unchanged
    assert np.allclose(A.retarget_poses(A.AdaptContext(g1, env, ctx.library, scaled), prim, q_s, q_e, attempt=1), plain)
    wide_ctx = A.AdaptContext(g1, env, ctx.library, apply_overrides(scaled, {"interpolation.hand_backoff_min_incline_deg": 75.0}))
    # a library's seed attempt keeps the design's back-off, the next one takes the longer one
    assert [A.hand_backoff_scale(wide_ctx, k) for k in range(4)] == [1.0, 1.3, 1.0, 1.3]
    assert np.allclose(A.retarget_poses(wide_ctx, prim, q_s, q_e, attempt=0), plain)
    wide = A.retarget_poses(wide_ctx, prim, q_s, q_e, attempt=1)
    b0, b1 = backs(plain), backs(wide)
    assert b0.max() > 0.09  # the design backs the hand off ~10 cm before it travels
    assert b1 == pytest.approx(np.where(b0 > 0, 1.3 * b0, b0), abs=2e-3)
    # the ends are the grasps themselves; the orientation of every way-point is unchanged
    assert np.allclose(wide[0], plain[0]) and np.allclose(wide[-1], plain[-1])
    for P0, P1 in zip(plain, wide):
        assert np.allclose(P0[:3, :3], P1[:3, :3])
    # feet are not hands: unchanged
    foot = ctx.library.primitives["place_left_foot"]
    fq_s, fq_e = to_world(env, foot.waypoints[0]), to_world(env, foot.waypoints[-1])
    assert np.allclose(A.retarget_poses(wide_ctx, foot, fq_s, fq_e, attempt=1), A.retarget_poses(ctx, foot, fq_s, fq_e))


def test_a_library_is_parsed_once_per_version_of_its_file(tmp_path):
    import shutil

    from planner_node import primitives as P

    lib = load_library("g1", "forward")
    assert load_library("g1", "forward") is lib  # cached
    assert not lib.primitives["place_left_hand"].waypoints.flags.writeable  # shared: read-only
    folder = tmp_path / "g1" / "forward"
    folder.mkdir(parents=True)
    shutil.copy(lib.path, folder / P.LIBRARY_FILE)
    a = load_library("g1", "forward", root=tmp_path)
    assert a is not lib and a.primitives.keys() == lib.primitives.keys()
    text = (folder / P.LIBRARY_FILE).read_text()
    (folder / P.LIBRARY_FILE).write_text(text.replace("initial_fixture: standing", "initial_fixture: ladder_4_contacts"))
    b = load_library("g1", "forward", root=tmp_path)  # the file changed: parsed again
    assert b is not a and b.initial_fixture == "ladder_4_contacts"
    with pytest.raises(SpecError) as err:  # the robot check runs on a cached library too
        load_library("g1", "forward", root=tmp_path, nq=a and 10)
    assert err.value.field == "primitives.joint_names"


def test_projection_with_a_limb_cue_places_the_free_limb_and_keeps_the_contacts(g1, env, ctx):
    st4, q4 = fixtures.get("ladder_4_contacts", g1, env)
    kept = st4.without("right_hand")
    T = g1.T_world_surface("right_hand", q4)
    cue = T.copy()
    cue[:3, 3] -= 0.06 * T[:3, 2]  # 6 cm back along the palm normal, off the rung
    proj = A.ContactProjector(ctx, kept, q4)
    q = proj(q4, cue=("right_hand", cue))
    assert q is not None
    dp, da = A.pose_deviation(g1.T_world_surface("right_hand", q), cue)
    assert dp < 1e-3 and da < 1e-2
    pos, ang = proj.errors(q)
    assert pos < 1e-3 and ang < 1e-2
    # an unreachable cue (2 m away) is refused, not half-done
    far = cue.copy()
    far[:3, 3] += [0.0, 0.0, 2.0]
    assert proj(q4, cue=("right_hand", far)) is None


def test_a_landing_grasp_rolled_about_its_rung_is_projected_again_with_its_nominal_roll(g1, env, ctx):
    st4, q4 = fixtures.get("ladder_4_contacts", g1, env)
    hold = st4.hold("right_hand")
    nominal = A.nominal_grasp_pose(ctx, hold, q4)
    assert A.grasp_pins(ctx, q4, st4, "right_foot") == {} and A.grasp_pins(ctx, q4, st4, "") == {}
    assert np.allclose(A.grasp_pins(ctx, q4, st4, "right_hand")["right_hand"], nominal)
    # this fixture holds the rung with the right palm rolled ~1 rad from the nominal grasp (the IK leaves
    # the roll free): as the end of a right-hand placement it is projected again, the roll pinned
    q_bar = q4.copy()
    free = A.project(ctx, q_bar, st4, np.random.default_rng(0))
    assert free.q is not None
    assert A.pose_deviation(g1.T_world_surface("right_hand", free.q), nominal)[1] > ctx.settings.projection.grasp_roll_tolerance
    out = A.end_configuration(ctx, q_bar, q4, st4, "right_hand", (), np.random.default_rng(0))
    assert out.q is not None
    assert A.pose_deviation(g1.T_world_surface("right_hand", out.q), nominal)[1] < 0.02
    assert ctx.check(out.q, st4).feasible
    # a contact plan's own end configuration is taken as projected
    kept = A.end_configuration(ctx, q_bar, q4, st4, "right_hand", (), np.random.default_rng(0), fallbacks=False)
    assert np.allclose(kept.q, free.q)


def test_foot_cues_in_the_ladder_frame_are_anchored_to_the_rung_left_then_the_rung_reached(g1, env, ctx):
    prim = ctx.library.primitives["place_left_foot"]
    cues = A.limb_cues(ctx, prim)
    P_s, P_e = cues.poses[0], cues.poses[-1]
    w = cues.weights
    # design: 15 cm back and 10 cm up from the start hold (ladder frame), then 14 cm back / 6 cm up from the target
    i_back = int(np.argmin([np.linalg.norm(P[:3, 3] - P_s[:3, 3] - [-0.15, 0.0, 0.10]) for P in cues.poses]))
    i_over = int(np.argmin([np.linalg.norm(P[:3, 3] - P_e[:3, 3] - [-0.14, 0.0, 0.06]) for P in cues.poses]))
    assert np.linalg.norm(cues.poses[i_back][:3, 3] - P_s[:3, 3] - [-0.15, 0.0, 0.10]) < 0.03
    assert 0 < i_back < i_over < len(w) - 1
    assert np.all(w[:i_back + 1] == 0.0) and np.all(w[i_over:] > 0.99) and 0.0 < w[(i_back + i_over) // 2] < 1.0
    # the next rung, one rung spacing further along the ladder: the approach moves with the target rung,
    # the back-off stays with the rung the foot leaves
    q_s, q_e = to_world(env, prim.waypoints[0]), to_world(env, prim.waypoints[-1])
    step = env.surfaces["rung_2"].position - env.surfaces["rung_1"].position
    q_e2 = q_e.copy()
    q_e2[:3] += step
    T_new = A.retarget_poses(ctx, prim, q_s, q_e2)
    T_ladder = np.asarray(env.T_world_ladder)
    assert np.allclose(T_new[i_back], T_ladder @ cues.poses[i_back], atol=1e-6)
    assert np.allclose(T_new[i_over][:3, 3], (T_ladder @ cues.poses[i_over])[:3, 3] + step, atol=1e-3)
