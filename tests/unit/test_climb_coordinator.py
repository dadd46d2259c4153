"""climb_coordinator pieces that need no simulator: settings, judging helpers, plan clipping,
the bad-spec path of scripts/climb.py."""
from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import pytest

from climb_core.errors import SpecError

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_settings_load_and_reject_bad_values(tmp_path):
    from climb_coordinator.settings import load_climb_settings

    s = load_climb_settings()
    assert s.bag_rate_hz > 0 and s.foot_force_min > 0 and s.snapshot_count >= 1
    bad = (ROOT / "config" / "climb.yaml").read_text().replace("bag_rate_hz: 50.0", "bag_rate_hz: -1.0")
    path = tmp_path / "climb.yaml"
    path.write_text(bad)
    with pytest.raises(SpecError) as err:
        load_climb_settings(path)
    assert err.value.field == "climb.record.bag_rate_hz"


def test_planner_overrides_are_applied_and_unknown_ones_named():
    from climb_coordinator.settings import apply_planner_overrides
    from planner_node.settings import load_settings

    s = apply_planner_overrides(load_settings(), {"pcik.torque_limit_fraction": 0.6})
    assert s.pcik.torque_limit_fraction == 0.6
    with pytest.raises(SpecError) as err:
        apply_planner_overrides(load_settings(), {"pcik.no_such_thing": 1.0})
    assert "no_such_thing" in err.value.field


def test_rungs_reached_needs_both_feet_on_the_same_rung():
    from climb_coordinator.judge import rung_index, rungs_reached

    assert rungs_reached({"left_foot": 2, "right_foot": 2}) == 2
    assert rungs_reached({"left_foot": 2, "right_foot": 1}) == 0
    assert rungs_reached({"left_foot": 2, "right_foot": None}) == 0
    assert rung_index("rung_12") == 12 and rung_index("ground") == 0 and rung_index("stringer_left") is None


def test_plan_clipping_keeps_joints_inside_the_limits_and_leaves_the_base():
    from climb_coordinator.climb import clip_plan_to_limits
    from climb_core.contact import Stance, Transition, WholeBodyPlan
    from climb_core.robot import load_robot

    robot = load_robot("g1")
    m = robot.model
    q = np.array(m.upperPositionLimit, float)
    q[:7] = [0.1, 0.2, 0.7, 0.0, 0.0, 0.0, 1.0]
    q[7:] = np.where(np.isfinite(q[7:]), q[7:] + 0.1, 0.0)  # every joint 0.1 rad beyond its upper limit
    t = Transition("test", "", Stance(()), Stance(()), np.array([0.0, 1.0]), np.stack([q, q]))
    plan = WholeBodyPlan("g1", "default", list(robot.joint_names), Stance(()), [t])
    out = clip_plan_to_limits(plan, robot, 0.01)
    path = out.transitions[0].path
    assert np.all(path[:, 7:] <= m.upperPositionLimit[7:] - 0.01 + 1e-12)
    assert np.array_equal(path[:, :7], np.stack([q, q])[:, :7])
    assert np.array_equal(plan.transitions[0].path, np.stack([q, q]))  # input untouched


@pytest.mark.parametrize("changes, field", [({"mode": "fast"}, "mode"), ({"rungs": 0}, "rungs"),
                                            ({"snapshots": -1}, "snapshots"), ({"max_transitions": 0}, "max_transitions"),
                                            ({"command_delay_ticks": 2}, "command_delay_ticks"),
                                            ({"command_delay_ticks": True}, "command_delay_ticks"),
                                            ({"bridge_overrides": {"sensors.ft_noise_percent": -1.0}},
                                             "sim_bridge.sensors.ft_noise_percent")])
def test_bad_requests_name_their_field(changes, field):
    from climb_coordinator.climb import ClimbRequest, validate

    with pytest.raises(SpecError) as err:
        validate(ClimbRequest(**changes))
    assert err.value.field == field


def test_climb_script_bad_spec_exits_2_without_traceback(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "climb.py"), "--out", str(tmp_path),
                           "--ladder", "no_such_ladder"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: source:") and "Traceback" not in proc.stderr
    assert proc.stdout.strip().splitlines()[-1].startswith("{")


STORED_VERTICAL = ROOT / "tests" / "data" / "vertical_plan.json"


@pytest.mark.parametrize("args, field", [
    (["--plan", "{missing}"], "plan: file"),
    (["--plan", "{garbage}"], "plan: "),
    (["--plan", "{no_joints}"], "plan.joint_names: required"),
    (["--plan", str(STORED_VERTICAL), "--graph", "composed"], "--plan: a stored plan is executed in process"),
    (["--plan", str(STORED_VERTICAL), "--scenario", "default"], "plan.environment: "),
    (["--plan", str(STORED_VERTICAL), "--robot", "talos"], "plan.robot: "),
])
def test_climb_script_refuses_a_stored_plan_it_cannot_execute_with_exit_2(tmp_path, args, field):
    import json

    files = {"missing": tmp_path / "none.json", "garbage": tmp_path / "garbage.json",
             "no_joints": tmp_path / "no_joints.json"}
    files["garbage"].write_text("{not json")
    doc = json.loads(STORED_VERTICAL.read_text())
    del doc["joint_names"]
    files["no_joints"].write_text(json.dumps(doc))
    args = [a.format(**{k: str(v) for k, v in files.items()}) for a in args]
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "climb.py"), "--out", str(tmp_path / "out"),
                           "--no-bag", "--no-plots", *args], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(f"error: {field}") and "Traceback" not in proc.stderr, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["success"] is False and field in summary["failure_reason"]


def test_a_stored_plan_starts_in_the_fixture_that_holds_its_first_stance():
    from climb_core import fixtures
    from climb_core.contact import Stance
    from climb_core.ladder import load_scenario
    from climb_core.robot import load_robot
    from climb_coordinator.climb import stored_plan_fixture
    from planner_node.plan_io import load_plan

    robot, scenario = load_robot("g1"), load_scenario("vertical")
    plan, _ = load_plan(STORED_VERTICAL)
    assert stored_plan_fixture(plan, robot, scenario) == "standing"
    stance, _ = fixtures.get("ladder_4_contacts", robot, "default")
    from dataclasses import replace

    on_ladder = replace(plan, environment="default", initial_stance=stance)
    assert stored_plan_fixture(on_ladder, robot, load_scenario("default")) == "ladder_4_contacts"
    three = Stance(holds=tuple(h for h in stance.holds if h.limb != "left_foot"))
    assert stored_plan_fixture(replace(on_ladder, initial_stance=three), robot,
                               load_scenario("default")) == "ladder_no_left_foot"
    one_hand = Stance(holds=tuple(h for h in stance.holds if h.limb == "right_hand"))
    with pytest.raises(SpecError) as err:  # no fixture hangs from one hand
        stored_plan_fixture(replace(on_ladder, initial_stance=one_hand), robot, load_scenario("default"))
    assert err.value.field == "plan.initial_stance"


def test_a_stored_plan_gives_the_climb_its_scenario_robot_and_rungs_unless_given(tmp_path):
    """scripts/climb.py --plan: --scenario, --robot and --rungs default to the plan's."""
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("climb_script", ROOT / "scripts" / "climb.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    doc = json.loads(STORED_VERTICAL.read_text())
    doc["robot"] = "talos"  # (only read here, never executed)
    path = tmp_path / "talos_plan.json"
    path.write_text(json.dumps(doc))
    args = script.build_parser().parse_args(["--plan", str(path)])
    script.stored_plan_defaults(args)
    assert (args.scenario, args.robot, args.graph) == ("vertical", "talos", "inprocess")
    args = script.build_parser().parse_args(["--plan", str(path), "--robot", "g1", "--rungs", "1"])
    script.stored_plan_defaults(args)
    assert (args.robot, args.rungs) == ("g1", 1)
