"""climb_core.collision: signed hull distances robot <-> environment and robot <-> itself."""
from __future__ import annotations

import pathlib
import xml.etree.ElementTree as ET

import coal
import numpy as np
import pinocchio as pin
import pytest

from climb_core import collision, fixtures
from climb_core.contact import FEET
from climb_core.errors import SpecError


@pytest.fixture(scope="module")
def checker(g1, env):
    return collision.checker(g1, env)


def _foot_geometry(g1, limb):
    frame = g1.config.limbs[limb].surface.frame
    return next(go.name for go in g1.collision_model.geometryObjects
                if g1.model.frames[go.parentFrame].name == frame)


def test_checker_is_cached_and_covers_env_and_self_pairs(g1, env, checker):
    assert collision.checker(g1, env) is checker
    kinds = set(checker.pair_kind)
    assert kinds == {"env", "self"}
    assert len(checker.env_names) == len(env.surfaces)
    # config ignore pairs are never checked
    ignored = {frozenset(p) for p in g1.config.collision.ignore_pairs}
    links = dict(zip(checker.robot_geoms, checker.geom_link))
    for a, b in checker.pair_names:
        if not b.startswith(collision.ENV_PREFIX):
            assert frozenset((links[a], links[b])) not in ignored


def test_culled_query_equals_brute_force(g1, checker):
    rng = np.random.default_rng(3)
    q_ref = g1.q_reference()
    lo, hi = g1.model.lowerPositionLimit[7:], g1.model.upperPositionLimit[7:]
    for _ in range(25):
        q = q_ref.copy()
        q[7:] = np.clip(q[7:] + rng.normal(0.0, 0.7, len(q) - 7), lo, hi)
        q[:3] += rng.normal(0.0, [0.3, 0.1, 0.2])
        full = checker.all_distances(q)
        rep = checker.distances(q, threshold=0.02)
        k = int(np.argmin(full))
        assert rep.min_distance == pytest.approx(full[k], abs=1e-6)
        assert sorted((a, b) for a, b, _ in rep.below) == sorted(
            checker.pair_names[i] for i in np.flatnonzero(full < 0.02))


def test_foot_box_to_ground_is_the_height(g1, checker):
    geom = _foot_geometry(g1, "left_foot")
    query = checker.pair_query([(geom, "env:ground")])
    for dz in (0.1, 0.013, 0.0, -0.01):
        q = g1.q_reference()
        q[2] += dz
        assert query.compute(q)[0] == pytest.approx(dz, abs=1e-6)


def test_held_surfaces_are_excluded(g1, checker):
    q = g1.q_reference()
    q[2] -= 0.005  # soles 5 mm into the ground
    rep = checker.distances(q, threshold=0.0)
    assert rep.min_distance == pytest.approx(-0.005, abs=1e-6)
    assert rep.pair[1] == "env:ground"
    held = checker.distances(q, contacts=[(limb, "ground") for limb in FEET])
    assert held.min_distance > 0.0
    assert all(b != "env:ground" for _, b, _ in held.below)
    # one foot held: the other still touches
    one = checker.distances(q, contacts=[("left_foot", "ground")])
    assert one.pair == (_foot_geometry(g1, "right_foot"), "env:ground")


def test_reference_posture_is_collision_free_after_the_filter(g1, checker):
    q = g1.q_reference()
    rep = checker.distances(q, contacts=[(limb, "ground") for limb in FEET])
    assert rep.min_distance >= checker.params.reference_contact_distance
    for a, b, d in checker.filtered_at_reference:
        assert d < checker.params.reference_contact_distance


def test_witness_points_are_the_distance_apart(g1, checker):
    q = g1.q_reference()
    q[2] += 0.05
    rep = checker.distances(q)
    p1, p2 = rep.witness_points
    assert rep.min_distance > 0
    assert np.linalg.norm(p2 - p1) == pytest.approx(rep.min_distance, abs=1e-6)


def test_grasping_hands_only_touch_their_rung(g1, env, checker):
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    contacts = [(h.limb, h.env_surface) for h in stance.holds]
    assert checker.distances(q, contacts=contacts).min_distance > 0.0
    # without the exclusion the closed hands and soles are on / around their rungs
    rep = checker.distances(q, threshold=1e-4)
    touching = {b for _, b, _ in rep.below if b.startswith(collision.ENV_PREFIX)}
    assert {"env:rung_1", "env:rung_5"} <= touching


def _urdf_collision_meshes(g1) -> dict[str, str]:
    """geometry name (<link>_0) -> mesh file of the link's single collision mesh in the URDF."""
    out = {}
    for link in ET.parse(g1.config.urdf_path).getroot().iter("link"):
        meshes = [m.get("filename") for c in link.iter("collision") for m in c.iter("mesh")]
        if len(meshes) == 1 and meshes[0].startswith("package://"):
            rel = meshes[0].removeprefix("package://")
            for base in g1.config.package_dirs:
                path = pathlib.Path(base) / rel
                if path.is_file():
                    out[f"{link.get('name')}_0"] = str(path)
    return out


def test_hulls_are_conservative_against_raw_meshes(g1, env, checker):
    """The hull contains its mesh: hull distance <= mesh distance for 20 link/rung pairs."""
    stance, q = fixtures.get("ladder_4_contacts", g1, env)
    meshes = _urdf_collision_meshes(g1)
    links = [g for g in checker.robot_geoms if g in meshes][:10]
    assert len(links) == 10
    pairs = [(g, f"env:rung_{k}") for g in links for k in (2, 3)]
    hull_d = checker.pair_query(pairs).compute(q)
    loader = coal.MeshLoader()
    gm = pin.GeometryModel()
    for go in g1.collision_model.geometryObjects:
        if go.name in links:
            mesh = loader.load(meshes[go.name], np.ones(3))
            gm.addGeometryObject(pin.GeometryObject(go.name, go.parentJoint, go.parentFrame, go.placement, mesh))
    objects = {name: (geom, tf) for name, geom, tf in env.collision_objects()}
    for k in (2, 3):
        geom, tf = objects[f"rung_{k}"]
        gm.addGeometryObject(pin.GeometryObject(f"rung_{k}", 0, 0, pin.SE3(tf.getRotation(), tf.getTranslation()),
                                                geom))
    index = {go.name: i for i, go in enumerate(gm.geometryObjects)}
    for a, b in pairs:
        gm.addCollisionPair(pin.CollisionPair(index[a], index[b.removeprefix("env:")]))
    gd = pin.GeometryData(gm)
    pin.computeDistances(g1.model, g1.model.createData(), gm, gd, q)
    mesh_d = np.array([r.min_distance for r in gd.distanceResults])
    assert (hull_d <= mesh_d + 1e-6).all()
    assert np.median(mesh_d - hull_d) < 0.005  # hulls of link meshes stay tight [m]


def test_vectorised_bounds_are_bitwise_the_per_pair_bounds_and_below_every_distance(g1, checker):
    """The culling bounds (one gather per pair) equal the per-pair formulation bit for bit, so the
    pairs sent to coal, hence every result, are unchanged; and they never exceed a distance."""
    rng = np.random.default_rng(7)
    q_ref = g1.q_reference()
    lo, hi = g1.model.lowerPositionLimit[7:], g1.model.upperPositionLimit[7:]
    for _ in range(5):
        q = q_ref.copy()
        q[7:] = np.clip(q[7:] + rng.normal(0.0, 0.7, len(q) - 7), lo, hi)
        q[:3] += rng.normal(0.0, [0.3, 0.1, 0.2])
        full = checker.all_distances(q)  # runs the kinematics at q
        fast, ref = checker._lower_bounds(), checker._lower_bounds_reference()
        assert np.array_equal(fast, ref)
        assert (fast <= full + 1e-9).all()


def test_exclusions_are_cached_per_contact_set(g1, checker):
    contacts = [("left_foot", "ground"), ("right_hand", "rung_5")]
    first = checker.excluded_pairs(contacts)
    assert first and checker.excluded_pairs(list(contacts)) == first
    names = {checker.pair_names[k] for k in first}
    assert all(b in ("env:ground", "env:rung_5") for _, b in names)
    with pytest.raises(SpecError, match="collision.limb"):
        checker.excluded_pairs([("tail", "ground")])
