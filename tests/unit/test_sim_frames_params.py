"""Frame conversions, parameters and interface tables of the sim bridge (no physics engine)."""
from __future__ import annotations

import ast
import pathlib

import numpy as np
import pytest

from climb_core.errors import SpecError
from sim_bridge import frames
from sim_bridge.params import BridgeParams, load_bridge_params
from sim_bridge.topics import TOPICS

ROOT = pathlib.Path(__file__).resolve().parents[2]


def random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return frames.quat_to_matrix(q / np.linalg.norm(q))


def test_quaternion_round_trip_and_inverse():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = random_rotation(rng)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(frames.quat_to_matrix(frames.matrix_to_quat(R)), R)
        T = frames.pose_matrix(rng.normal(size=3), frames.matrix_to_quat(R))
        assert np.allclose(frames.inverse(T) @ T, np.eye(4))
    assert np.allclose(frames.cross(np.array([1.0, 2, 3]), np.array([-4.0, 5, 0.5])),
                       np.cross([1.0, 2, 3], [-4.0, 5, 0.5]))


def test_wrench_moves_from_the_inertial_frame_to_the_link_origin():
    """A pure force through the COM has no torque about the COM, and r x F about the link origin."""
    rng = np.random.default_rng(1)
    R_li = random_rotation(rng)
    p_com = np.array([0.2, 0.1, -0.3])  # [m] COM in the link frame
    T_link_inertial = frames.pose_matrix(p_com, frames.matrix_to_quat(R_li))
    force_link = np.array([0.0, 5.8, 18.7])  # [N]
    force, torque = frames.wrench_child_inertial_to_link(R_li.T @ force_link, np.zeros(3), T_link_inertial)
    assert np.allclose(force, force_link)
    assert np.allclose(torque, np.cross(p_com, force_link))


def test_base_frame_and_free_flyer_velocity_conversions_invert_each_other():
    rng = np.random.default_rng(2)
    R = random_rotation(rng)
    T_world_base = frames.pose_matrix([0.3, -0.2, 0.8], frames.matrix_to_quat(R))
    T_base_inertial = frames.pose_matrix([0.0, 0.0, -0.076], frames.matrix_to_quat(random_rotation(rng)))
    T_world_inertial = T_world_base @ T_base_inertial
    assert np.allclose(frames.base_pose_from_inertial(T_world_inertial, T_base_inertial), T_world_base)
    v_local = rng.normal(size=6)
    com = T_world_inertial[:3, 3]
    lin_com, ang = frames.world_velocity_from_free_flyer(T_world_base, v_local, com)
    v_origin = frames.point_velocity(lin_com, ang, T_world_base[:3, 3] - com)  # the root origin's velocity
    assert np.allclose(frames.free_flyer_velocity(T_world_base, v_origin, ang), v_local)
    assert not np.allclose(lin_com, v_origin)  # the COM is not the origin: the conversion matters


def test_the_yaml_holds_the_schema_defaults():
    """config/nodes/sim_bridge.yaml is the deployed parameter set; it must mirror the schema."""
    assert load_bridge_params() == BridgeParams()


def test_every_yaml_number_has_a_unit_comment():
    for line in (ROOT / "config" / "nodes" / "sim_bridge.yaml").read_text().splitlines():
        code = line.split("#")[0]
        if ":" in code:
            value = code.split(":", 1)[1].strip()
            try:
                ast.literal_eval(value)
                numeric = value not in ("true", "false") and any(c.isdigit() for c in value)
            except (ValueError, SyntaxError):
                numeric = False
            if numeric:
                assert "# [" in line, f"no unit on: {line}"


def test_bad_parameters_name_the_field():
    with pytest.raises(SpecError, match="physics.control_period_s"):
        load_bridge_params(**{"physics.control_period_s": 0.0045})
    with pytest.raises(SpecError, match="execution"):
        load_bridge_params(execution="sometimes")
    with pytest.raises(SpecError, match="unknown parameter"):
        load_bridge_params(**{"physics.dtt_s": 0.001})
    assert load_bridge_params(**{"physics.control_period_s": 0.002}).physics.substeps == 2


def test_one_reliable_qos_per_topic():
    assert {spec.reliability for spec in TOPICS.values()} == {"reliable"}
    assert {"joint_states", "imu", "sim/base_truth", "/clock", "diagnostics", "joint_command",
            "gripper_command", "ft/<sensor>", "sim/contacts"} == set(TOPICS)
    from msgs_py.topics import lookup  # the graph's one QoS table agrees

    for name, spec in TOPICS.items():
        assert (lookup(name).depth, lookup(name).reliability) == (spec.depth, spec.reliability), name
    doc = (ROOT / "docs" / "sim_bridge.md").read_text()
    for name in TOPICS:
        assert f"`{name}`" in doc, f"{name} missing from the QoS table of docs/sim_bridge.md"


def test_library_modules_do_not_import_rclpy():
    package = ROOT / "src" / "sim_bridge" / "sim_bridge"
    for path in package.glob("*.py"):
        if path.name in ("node.py", "ros_node.py"):  # the executable and its node
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n.split(".")[0] in ("rclpy", "climb_msgs") for n in names), path.name
