"""climb_core.params: ROS-params YAML <-> frozen dataclasses, strictly typed, without ROS."""
from __future__ import annotations

import dataclasses
import pathlib
from dataclasses import dataclass

import pytest
import yaml

from climb_core.errors import SpecError
from climb_core.params import (describe, flatten, group, load_params, param, parse_params,
                               read_params_document, to_yaml)

ROOT = pathlib.Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Watchdog:
    timeout_s: float = param(0.1, unit="s", min=0.0, description="longest time without a command")
    action: str = param("damp", unit="-", choices=("damp", "hold", "zero_torque"),
                        description="what the bridge does on a timeout")


@dataclass(frozen=True)
class BridgeParams:
    rate_hz: float = param(200.0, unit="Hz", min=1.0, max=1000.0, description="control rate")
    substeps: int = param(5, unit="-", min=1, description="physics steps per control period")
    lock_step: bool = param(True, unit="-", description="step only when the command arrives")
    robot: str = param("g1", unit="-", description="robot config name")
    kp: tuple[float, ...] = param((100.0, 50.0), unit="N m/rad", min=0.0, description="joint gains")
    sensors: tuple[str, ...] = param(("left_wrist",), unit="-", description="F/T sensors published")
    watchdog: Watchdog = group(Watchdog, "command watchdog")


def write(tmp_path, text):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def spec_error(fn, *args):
    with pytest.raises(SpecError) as err:
        fn(*args)
    return err.value


def test_load_nested_file_fills_defaults_and_freezes(tmp_path):
    path = write(tmp_path, """
bridge:
  ros__parameters:
    rate_hz: 500.0
    kp: [10.0, 20.0, 30.0]
    watchdog:
      timeout_s: 0.25
other_node:
  ros__parameters:
    anything: 1
""")
    p = load_params(path, BridgeParams, "bridge")
    assert p.rate_hz == 500.0 and p.kp == (10.0, 20.0, 30.0) and p.watchdog.timeout_s == 0.25
    assert p.substeps == 5 and p.watchdog.action == "damp" and p.sensors == ("left_wrist",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.rate_hz = 1.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.watchdog.timeout_s = 1.0  # type: ignore[misc]


def test_dotted_keys_wildcard_and_slash_sections(tmp_path):
    path = write(tmp_path, """
/**:
  ros__parameters:
    use_sim_time: true
    robot: "talos"
    substeps: 2
/bridge:
  ros__parameters:
    watchdog.action: "hold"
    substeps: 10
""")
    p = load_params(path, BridgeParams, "bridge")
    assert (p.robot, p.substeps, p.watchdog.action) == ("talos", 10, "hold")  # node section wins over /**


def test_unknown_and_misplaced_keys_are_refused(tmp_path):
    doc = {"bridge": {"ros__parameters": {"watchdog": {"timeout": 0.2}}}}
    err = spec_error(load_params, doc, BridgeParams, "bridge")
    assert err.field == "bridge.watchdog.timeout" and "unknown" in err.rule
    err = spec_error(parse_params, {"rate": 1.0}, BridgeParams, "bridge")
    assert err.field == "bridge.rate"
    err = spec_error(parse_params, {"watchdog": 0.3}, BridgeParams, "bridge")
    assert err.field == "bridge.watchdog" and "watchdog.timeout_s" in err.rule
    err = spec_error(parse_params, {"watchdog": {"timeout_s": 0.3}, "watchdog.timeout_s": 0.4}, BridgeParams, "b")
    assert err.field == "b.watchdog.timeout_s" and "twice" in err.rule
    err = spec_error(load_params, {"controller": {"ros__parameters": {}}}, BridgeParams, "bridge")
    assert err.field == "bridge"
    err = spec_error(load_params, {"bridge": {"rate_hz": 1.0}}, BridgeParams, "bridge")
    assert err.field == "bridge" and "ros__parameters" in err.rule
    err = spec_error(load_params, tmp_path / "missing.yaml", BridgeParams, "bridge")
    assert "not found" in err.rule


@pytest.mark.parametrize("values, field, words", [
    ({"rate_hz": 200}, "bridge.rate_hz", "decimal point"),       # ROS would type 200 as an integer
    ({"substeps": 2.0}, "bridge.substeps", "expected int"),
    ({"substeps": True}, "bridge.substeps", "expected int"),
    ({"lock_step": 1}, "bridge.lock_step", "expected bool"),
    ({"robot": 3}, "bridge.robot", "expected str"),
    ({"rate_hz": float("nan")}, "bridge.rate_hz", "finite"),
    ({"rate_hz": 0.5}, "bridge.rate_hz", ">= 1.0"),
    ({"rate_hz": 2000.0}, "bridge.rate_hz", "<= 1000.0"),
    ({"substeps": 0}, "bridge.substeps", ">= 1"),
    ({"kp": [1.0, -2.0]}, "bridge.kp[1]", ">= 0.0"),
    ({"kp": [1.0, 2]}, "bridge.kp[1]", "expected float"),
    ({"kp": 1.0}, "bridge.kp", "list of float"),
    ({"sensors": "left_wrist"}, "bridge.sensors", "list of str"),
    ({"watchdog": {"action": "panic"}}, "bridge.watchdog.action", "one of damp, hold, zero_torque"),
    ({"watchdog.timeout_s": -0.1}, "bridge.watchdog.timeout_s", ">= 0.0"),
])
def test_type_range_and_choice_errors_name_the_parameter(values, field, words):
    err = spec_error(parse_params, values, BridgeParams, "bridge")
    assert err.field == field and words in err.rule, err


def test_flatten_parse_and_yaml_roundtrip(tmp_path):
    p = BridgeParams(rate_hz=1e-05 + 1.0, substeps=3, lock_step=False, robot="yes: no",
                     kp=(1e-05, 2.5e20), sensors=(), watchdog=Watchdog(timeout_s=1e-05, action="zero_torque"))
    flat = flatten(p)
    assert list(flat) == ["rate_hz", "substeps", "lock_step", "robot", "kp", "sensors", "watchdog.timeout_s",
                          "watchdog.action"]
    assert flat["kp"] == [1e-05, 2.5e20] and isinstance(flat["kp"], list)
    assert parse_params(flat, BridgeParams, "bridge") == p
    text = to_yaml(p, "bridge")
    assert "# [Hz] control rate" in text and "# [s] longest time without a command" in text
    assert load_params(write(tmp_path, text), BridgeParams, "bridge") == p
    assert load_params(write(tmp_path, to_yaml(BridgeParams(), "bridge")), BridgeParams, "bridge") == BridgeParams()


def test_describe_gives_what_a_node_declares():
    info = describe(BridgeParams)
    assert list(info) == list(flatten(BridgeParams()))
    assert info["kp"].type == "float_array" and info["kp"].unit == "N m/rad" and info["kp"].min == 0.0
    assert info["sensors"].type == "str_array" and info["lock_step"].type == "bool"
    assert info["watchdog.action"].choices == ("damp", "hold", "zero_torque")
    assert info["watchdog.timeout_s"].description == "longest time without a command"


@dataclass(frozen=True)
class NoUnit:
    x: float = dataclasses.field(default=1.0, metadata={"description": "x"})


@dataclass(frozen=True)
class NoDescription:
    x: float = param(1.0, unit="m", description=" ")


@dataclass(frozen=True)
class BadDefault:
    x: float = param(-1.0, unit="m", min=0.0, description="x")


@dataclass(frozen=True)
class ListType:
    x: list[float] = dataclasses.field(default_factory=list, metadata={"unit": "m", "description": "x"})


@dataclass
class NotFrozen:
    x: float = param(1.0, unit="m", description="x")


@pytest.mark.parametrize("schema, words", [
    (NoUnit, "unit"), (NoDescription, "description"), (BadDefault, ">= 0.0"), (ListType, "unsupported"),
    (NotFrozen, "frozen"),
])
def test_schema_mistakes_are_reported(schema, words):
    err = spec_error(describe, schema)
    assert words in err.rule, err


def test_project_node_files_have_the_ros_layout():
    files = sorted((ROOT / "config" / "nodes").glob("*.yaml"))
    assert files, "config/nodes/ holds the node parameter files"
    for path in files:
        sections = read_params_document(yaml.safe_load(path.read_text()), str(path))
        assert sections, path
    from msgs_py.env_probe import EnvProbeParams

    probe = load_params(ROOT / "config" / "nodes" / "env_probe.yaml", EnvProbeParams, "env_probe")
    assert probe.topic == "env_probe" and probe.wait_for_subscribers_s >= 0.0
