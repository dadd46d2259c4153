"""climb/markers (climb_coordinator.markers): the scene, the stances, contact forces with their
friction cones and the CoM as a visualization_msgs/MarkerArray."""
from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def stance_q(g1, env):
    from climb_core import fixtures

    return fixtures.get("ladder_4_contacts", g1, env)


def _by_ns(array, ns):
    return [m for m in array.markers if m.ns == ns]


def test_scene_stances_forces_and_com(env, stance_q):
    from visualization_msgs.msg import Marker, MarkerArray

    from climb_coordinator.markers import ContactForce, marker_array
    from rclpy.serialization import serialize_message

    stance, _ = stance_q
    foot = stance.hold("left_foot")
    p = foot.points[0]
    forces = [ContactForce("left_foot", p.position, 150.0 * p.normal + np.array([10.0, 0, 0]), p.normal, foot.friction),
              ContactForce("right_hand", np.zeros(3), np.array([0.0, 0.0, 50.0]), np.array([0.0, 0.0, 1.0]), 0.6,
                           bilateral=True)]
    arr = marker_array(env, current=stance, next_stance=stance, forces=forces, com=[0.1, 0.0, 0.9])
    assert isinstance(arr, MarkerArray) and arr.markers[0].action == Marker.DELETEALL
    scene = _by_ns(arr, "scene")
    assert len(scene) == len(env.surfaces)
    rungs = [m for m in scene if m.text.startswith("rung_")]
    assert len(rungs) == env.n_rungs and all(m.type == Marker.CYLINDER for m in rungs)
    r1 = env.rung(1)
    m1 = next(m for m in rungs if m.text == "rung_1")
    assert m1.scale.x == pytest.approx(2 * r1.radius) and m1.scale.z == pytest.approx(r1.length)
    assert [m1.pose.position.x, m1.pose.position.y, m1.pose.position.z] == pytest.approx(list(r1.position))
    # RViz draws a cylinder along its local z: the marker's z axis is the rung's axis
    from scipy.spatial.transform import Rotation

    o = m1.pose.orientation
    z = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()[:, 2]
    assert abs(abs(float(np.dot(z, r1.axis))) - 1.0) < 1e-9
    ground = next(m for m in scene if m.text == "ground")
    assert ground.type == Marker.CUBE and ground.scale.z < 0.1
    # every hold of both stances: its points and a label
    for ns in ("stance_current", "stance_next"):
        spheres = [m for m in _by_ns(arr, ns) if m.type == Marker.SPHERE_LIST]
        assert len(spheres) == len(stance.holds)
        assert sum(len(m.points) for m in spheres) == sum(len(h.points) for h in stance.holds)
    assert _by_ns(arr, "stance_next")[0].color.a < 1.0
    # forces: two arrows, one cone (the grasp has none), the cone's half-angle is atan(mu)
    f = _by_ns(arr, "forces")
    arrows = [m for m in f if m.type == Marker.ARROW]
    cones = [m for m in f if m.type == Marker.TRIANGLE_LIST]
    assert len(arrows) == 2 and len(cones) == 1
    a0 = arrows[0].points
    tip = np.array([a0[1].x, a0[1].y, a0[1].z]) - np.array([a0[0].x, a0[0].y, a0[0].z])
    assert tip == pytest.approx(0.002 * forces[0].force)
    pts = np.array([[q.x, q.y, q.z] for q in cones[0].points])
    assert len(pts) % 3 == 0
    apex = pts[0]
    rim = pts[1::3] - apex
    n = p.normal / np.linalg.norm(p.normal)
    along = rim @ n
    across = np.linalg.norm(rim - np.outer(along, n), axis=1)
    assert np.allclose(across / along, foot.friction)
    # CoM: a sphere and its line to the ground
    com = _by_ns(arr, "com")
    assert com[0].type == Marker.SPHERE and com[0].pose.position.z == pytest.approx(0.9)
    assert com[1].points[1].z == pytest.approx(float(env.surfaces["ground"].position[2]))
    # unique (ns, id) and the array serializes (a publishable message)
    keys = [(m.ns, m.id) for m in arr.markers[1:]]
    assert len(keys) == len(set(keys))
    assert len(serialize_message(arr)) > 1000


def test_forces_from_sim_contacts_and_the_coordinator_entry_point(env, stance_q):
    from climb_coordinator.markers import build_markers, forces_from_contacts

    stance, _ = stance_q
    limbs = ["left_foot", "right_foot", "left_hand", "right_hand"]
    forces = forces_from_contacts(limbs, [150.0, 140.0, 30.0, 0.0], [10.0, 0.0, 5.0, 0.0], stance, env,
                                  grasped=[False, False, True, False])
    assert [c.limb for c in forces] == ["left_foot", "right_foot", "left_hand"]  # no force: no arrow
    lf = forces[0]
    assert float(np.dot(lf.force, lf.normal)) == pytest.approx(150.0)
    assert np.linalg.norm(lf.force - 150.0 * lf.normal) == pytest.approx(10.0)
    assert forces[2].bilateral and not forces[0].bilateral
    arr = build_markers(None, ("g1", "default"), current=stance, forces=forces)
    assert {m.ns for m in arr.markers[1:]} == {"scene", "stance_current", "forces"}
