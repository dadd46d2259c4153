"""climb_coordinator's parameters and input checks without ROS processes: one source of truth for
the defaults (the schema = config/nodes/climb_coordinator.yaml = what config/graph.yaml passes),
the rules beyond the schema (known robot, node names), the descriptors the node declares, and the
checks that drop a bad sim/contacts or controller/state."""
from __future__ import annotations

import math
import pathlib
from types import SimpleNamespace

import pytest
import yaml

from climb_core.errors import SpecError
from climb_core.params import describe, load_params, parse_params
from climb_coordinator.coordinator_node import (NODE_NAME, READ_ONLY, CoordinatorParams, check_contacts,
                                                check_controller_state, check_params, request_from_msg)

ROOT = pathlib.Path(__file__).resolve().parents[2]
YAML = ROOT / "config" / "nodes" / "climb_coordinator.yaml"


def test_yaml_equals_the_schema_defaults_and_the_graph_passes_it():
    assert load_params(YAML, CoordinatorParams, NODE_NAME) == CoordinatorParams()
    nodes = {n["name"]: n for n in yaml.safe_load((ROOT / "config" / "graph.yaml").read_text())["graph"]["nodes"]}
    assert nodes[NODE_NAME]["params_files"] == ["config/nodes/climb_coordinator.yaml"]
    assert check_params(CoordinatorParams()) == CoordinatorParams()


def test_every_parameter_has_a_unit_and_every_number_a_range():
    infos = describe(CoordinatorParams)
    assert set(READ_ONLY) <= set(infos)
    for name, info in infos.items():
        assert info.unit and info.description, name
        if info.type in ("int", "float"):
            assert info.min is not None and info.max is not None, name


def test_descriptors_carry_the_unit_and_the_range():
    pytest.importorskip("rclpy")
    from msgs_py.node_kit import descriptor_for

    d = descriptor_for(describe(CoordinatorParams)["heartbeat_timeout_s"])
    assert "[s]" in d.description and d.floating_point_range[0].from_value == 0.05
    d = descriptor_for(describe(CoordinatorParams)["max_forced_replans"])
    assert d.integer_range[0].from_value == 0 and d.integer_range[0].to_value == 100


@pytest.mark.parametrize("values, field, words", [
    ({"heartbeat_timeout_s": -1.0}, "heartbeat_timeout_s", ">= 0.05"),
    ({"service_timeout_s": math.inf}, "service_timeout_s", "finite"),
    ({"max_forced_replans": -1}, "max_forced_replans", ">= 0"),
    ({"reset_sim": 7}, "reset_sim", "expected bool"),
    ({"plan_wait_margin_s": 10}, "plan_wait_margin_s", "decimal point"),
])
def test_schema_refuses_bad_values_naming_the_parameter(values, field, words):
    with pytest.raises(SpecError) as err:
        parse_params(values, CoordinatorParams, NODE_NAME)
    assert err.value.field == f"{NODE_NAME}.{field}" and words in err.value.rule, err.value


@pytest.mark.parametrize("change, field, words", [
    ({"robot": "banana"}, "robot", "unknown robot 'banana'"),
    ({"controller": ""}, "controller", "ROS node name"),
    ({"bridge": "9 lives"}, "bridge", "ROS node name"),
])
def test_rules_beyond_the_schema(change, field, words):
    import dataclasses

    with pytest.raises(SpecError) as err:
        check_params(dataclasses.replace(CoordinatorParams(), **change))
    assert err.value.field == f"{NODE_NAME}.{field}" and words in err.value.rule, err.value
    assert check_params(CoordinatorParams(robot="talos", controller="ns/controller")).robot == "talos"


def _contacts(**over):
    base = dict(limbs=["left_foot", "right_foot"], normal_force=[100.0, 90.0], tangential_force=[1.0, 2.0],
                surface=["rung_1", "rung_1"], rung=[1, 1], grasped=[False, False])
    base.update(over)
    return SimpleNamespace(**base)


def test_contacts_check():
    check_contacts(_contacts())
    with pytest.raises(SpecError, match="sim/contacts.surface: must have one entry per limb"):
        check_contacts(_contacts(surface=["rung_1"]))
    with pytest.raises(SpecError, match="sim/contacts.normal_force: must be finite"):
        check_contacts(_contacts(normal_force=[math.nan, 1.0]))


def test_controller_state_check():
    check_controller_state(SimpleNamespace(tick_time_ms=0.4))
    with pytest.raises(SpecError, match="controller/state.tick_time_ms"):
        check_controller_state(SimpleNamespace(tick_time_ms=math.inf))


def test_request_takes_the_node_defaults():
    msg = SimpleNamespace(scenario="", ladder="", robot="", rungs=1, controller_mode="", seed=0,
                          planning_timeout_s=0.0, descend=False, plan_cycles=0, command_delay_ticks=0)
    req = request_from_msg(msg, "talos", 5)
    assert (req.robot, req.max_forced_replans, req.ladder, req.mode) == ("talos", 5, "default", "qp")
