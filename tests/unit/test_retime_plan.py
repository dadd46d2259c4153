"""scripts/retime_plan.py and planner_node.plan_io.retimed: a stored plan timed again, paths kept."""
from __future__ import annotations

import dataclasses
import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from planner_node import plan_io
from planner_node.interpolation import time_parameterize, time_transition
from planner_node.settings import load_settings

ROOT = pathlib.Path(__file__).resolve().parents[2]
STORED = ROOT / "tests" / "data" / "narrow_passage_step_plan.json"


def test_retimed_keeps_the_paths_and_times_them_under_the_given_limits(g1):
    plan, _ = plan_io.load_plan(STORED)
    # the timing the stored plan was made with (before the soles' CoM acceleration bound)
    timing = dataclasses.replace(load_settings().timing, soles_max_com_acceleration=0.0)
    half = dataclasses.replace(timing, max_joint_speed=timing.max_joint_speed / 2,
                               max_base_speed=timing.max_base_speed / 2,
                               max_base_angular_speed=timing.max_base_angular_speed / 2)
    same = plan_io.retimed(plan, g1.model, timing)
    slow = plan_io.retimed(plan, g1.model, half)
    for t, a, b in zip(plan.transitions, same.transitions, slow.transitions):
        np.testing.assert_array_equal(t.path, b.path)
        assert b.stance == t.stance and b.target_stance == t.target_stance and b.primitive == t.primitive
        np.testing.assert_allclose(a.times, t.times, atol=1e-6)  # the planner's own timing, reproduced
        np.testing.assert_allclose(b.times, time_transition(g1.model, list(t.path), t.stance, half))
        # half the speed: twice the time, unless the least duration of a transition decides
        assert b.times[-1] == pytest.approx(max(2 * t.times[-1], half.min_transition_duration), rel=1e-6) \
            or t.times[-1] <= half.min_transition_duration + 1e-9


def _run(*args):
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "retime_plan.py"), *args],
                          capture_output=True, text=True, timeout=120)


def test_the_script_writes_the_retimed_plan_and_refuses_bad_options(tmp_path):
    out = tmp_path / "slow.json"
    run = _run(str(STORED), str(out), "--speed-scale", "0.5")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["transitions"] == 19 and summary["duration_s"] > 1.8 * summary["duration_before_s"]
    plan, metadata = plan_io.load_plan(out)
    assert metadata["retimed"]["speed_scale"] == 0.5 and len(plan.transitions) == 19
    for args, field in ((["--speed-scale", "0"], "speed-scale"), (["--set", "pcik.max_iterations=3"], "--set"),
                        (["--set", "timing.max_base_speed=-1.0"], "--set")):
        bad = _run(str(STORED), str(tmp_path / "x.json"), *args)
        assert bad.returncode == 2 and bad.stderr.startswith(f"error: {field}"), bad.stderr
        assert "Traceback" not in bad.stderr
    missing = _run(str(tmp_path / "none.json"), str(tmp_path / "x.json"))
    assert missing.returncode == 2 and missing.stderr.startswith("error: plan:"), missing.stderr


def _com_accelerations(model, path, times):
    import pinocchio as pin

    data = model.createData()
    c = np.array([pin.centerOfMass(model, data, q)[:2] for q in path])
    dt = np.diff(times)
    v = np.vstack([np.zeros(2), np.diff(c, axis=0) / dt[:, None], np.zeros(2)])
    half = np.concatenate([[dt[0] / 2], (dt[:-1] + dt[1:]) / 2, [dt[-1] / 2]])
    return np.linalg.norm(np.diff(v, axis=0), axis=1) / half


def test_the_com_acceleration_bound_holds_and_only_lengthens_the_path(g1):
    """narrow_passage's first single-support step: the CoM forward then back at the base speed
    limit changes velocity at 0.78 m/s^2 (a 5.4 cm ZMP shift, G1 tipped over its toe).
    ``max_com_acceleration`` stretches the segments around such way-points until every one is within
    the bound (the path starting and ending at rest); 0 leaves the timing as it was."""
    q0 = g1.q_reference()
    path = []
    for x in (0.0, 0.01, 0.03, 0.05, 0.04, 0.02, 0.0, -0.01, 0.02, 0.04):  # base forward, back, forward
        q = q0.copy()
        q[0] += x
        path.append(q)
    timing = load_settings().timing
    args = (timing.max_joint_speed, timing.max_base_speed, timing.max_base_angular_speed,
            timing.min_transition_duration, timing.ramp_fraction)
    free = time_parameterize(g1.model, path, *args)
    assert _com_accelerations(g1.model, path, free).max() > 0.5  # the planner's speeds: well over
    np.testing.assert_array_equal(time_parameterize(g1.model, path, *args, max_com_acceleration=0.0), free)
    bounded = time_parameterize(g1.model, path, *args, max_com_acceleration=0.2)
    assert _com_accelerations(g1.model, path, bounded).max() <= 0.2 * 1.01 + 1e-9
    assert np.all(np.diff(bounded) >= np.diff(free) - 1e-12)  # segments only lengthened


def _standing_on_soles(g1):
    from climb_core import fixtures
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario

    return fixtures.get("standing", g1, build_environment(load_scenario("default")))


def test_near_the_heels_the_path_slows_down_and_elsewhere_it_does_not(g1):
    """``timing.edge_slowdown_margin`` (off by default, the vertical ladder's file sets it): the base
    moved back toward the heels with the soles alone
    holding the robot: segments whose CoM is within the margin of the heels' edge take margin /
    distance longer (capped), the others keep their time; a sideways move of the same length (the
    sides are 6 cm from the CoM's track at most, and not counted) and a path with a grasp are not
    slowed."""
    from climb_core.contact import Stance
    from planner_node.interpolation import support_edge_factors

    stance, q0 = _standing_on_soles(g1)
    timing = dataclasses.replace(load_settings().timing, edge_slowdown_margin=0.045,  # the vertical ladder's
                                 soles_max_com_acceleration=0.0)  # (its own test, below)
    assert timing.edge_slowdown_max > 1.0
    soles = np.vstack([h.positions for h in stance.holds])
    data = g1.model.createData()
    import pinocchio as pin

    c0 = pin.centerOfMass(g1.model, data, q0)[:2]
    heel_gap = float(c0[0] - soles[:, 0].min())  # [m] CoM in front of the heels' edge at the start
    path = []
    for x in np.linspace(0.0, heel_gap - 0.015, 12):  # back to 1.5 cm in front of the heels
        q = q0.copy()
        q[0] -= x
        path.append(q)
    factors = support_edge_factors(g1.model, path, stance, timing.edge_slowdown_margin, timing.edge_slowdown_max)
    assert factors is not None and len(factors) == len(path) - 1
    assert factors[0] == 1.0 and factors[-1] == timing.edge_slowdown_max  # far: as planned; 1.5 cm: capped
    assert np.all(np.diff(factors) >= 0.0)  # nearer the heels, slower
    free = time_parameterize(g1.model, path, timing.max_joint_speed, timing.max_base_speed,
                             timing.max_base_angular_speed, 0.0, 0.0)
    slowed = time_transition(g1.model, path, stance, dataclasses.replace(timing, min_transition_duration=0.0,
                                                                         ramp_fraction=0.0))
    np.testing.assert_allclose(np.diff(slowed), np.diff(free) * factors)
    off = dataclasses.replace(timing, edge_slowdown_margin=0.0, min_transition_duration=0.0, ramp_fraction=0.0)
    np.testing.assert_allclose(time_transition(g1.model, path, stance, off), free)
    sideways = []
    for y in np.linspace(0.0, 0.05, 12):
        q = q0.copy()
        q[1] += y
        sideways.append(q)
    assert support_edge_factors(g1.model, sideways, stance, timing.edge_slowdown_margin, 2.0) is None
    grasped = Stance(stance.holds[:1] + (dataclasses.replace(stance.holds[1], bilateral=True),), "grasp")
    assert support_edge_factors(g1.model, path, grasped, timing.edge_slowdown_margin, 2.0) is None


def test_on_the_soles_alone_the_com_acceleration_bound_of_the_soles_applies(g1):
    """``timing.soles_max_com_acceleration`` (0.1 m/s^2 by default: G1 tipped over its heels in the
    first hand's mount of 80-90 deg ladders at the planner's speeds, docs/planner.md) bounds the CoM's
    acceleration of the transitions the flat soles carry alone; with a grasp in the stance only
    ``max_com_acceleration`` (0 by default: none) applies."""
    from climb_core.contact import Stance
    from planner_node.interpolation import com_acceleration_bound, on_soles_alone

    stance, q0 = _standing_on_soles(g1)
    timing = dataclasses.replace(load_settings().timing, edge_slowdown_margin=0.0)
    assert timing.soles_max_com_acceleration > 0.0 and timing.max_com_acceleration == 0.0
    grasped = Stance(stance.holds[:1] + (dataclasses.replace(stance.holds[1], bilateral=True),), "grasp")
    assert on_soles_alone(stance) and not on_soles_alone(grasped)
    assert com_acceleration_bound(stance, timing) == timing.soles_max_com_acceleration
    assert com_acceleration_bound(grasped, timing) == 0.0
    both = dataclasses.replace(timing, max_com_acceleration=timing.soles_max_com_acceleration / 2)
    assert com_acceleration_bound(stance, both) == both.max_com_acceleration  # the smaller one
    path = []
    for x in (0.0, 0.01, 0.03, 0.05, 0.04, 0.02, 0.0):  # the base forward, then back
        q = q0.copy()
        q[0] += x
        path.append(q)
    on_soles = time_transition(g1.model, path, stance, timing)
    with_grasp = time_transition(g1.model, path, grasped, timing)
    assert _com_accelerations(g1.model, path, on_soles).max() <= timing.soles_max_com_acceleration * 1.01 + 1e-9
    assert _com_accelerations(g1.model, path, with_grasp).max() > 2 * timing.soles_max_com_acceleration
    assert on_soles[-1] > with_grasp[-1]
