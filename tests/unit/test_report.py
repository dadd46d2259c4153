"""The run report from a bag alone (climb_coordinator.report, scripts/report.py) and the
trajectory comparison of replay --reexecute, on a synthetic G1 bag."""
from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
FSM = ["hold"] * 20 + ["unload"] * 15 + ["transfer"] * 30 + ["load"] * 15 + ["hold"] * 20  # 100 ticks


def _stamp(msg, t: float) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t - int(t)) * 1e9))


def write_synthetic_bag(path: pathlib.Path, g1, env, *, reset_first: bool = True) -> None:
    """100 ticks of 20 ms: G1 standing, its base rising 1 mm per tick, an FSM going through a
    transfer, contacts on both feet, the request latched; optionally a short earlier run (a sim
    reset rewinds the stamps) that the report must drop."""
    from climb_msgs.msg import ControllerState, SimContacts, WholeBodyPlan
    from geometry_msgs.msg import WrenchStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from climb_core import fixtures
    from msgs_py.bag import BagRecorder, qos_profile

    _, q = fixtures.get("standing", g1, env)
    names = list(g1.joint_names)
    limits = g1.effort_limits()
    with BagRecorder(path, close_on_signals=False) as rec:
        rec.add_topic("/climb/request", "std_msgs/msg/String", [qos_profile(durability="transient_local", depth=1)])
        rec.write("/climb/request", String(data=json.dumps({"robot": "g1", "scenario": "default", "mode": "qp"})), 1)
        log = 10
        runs = ([5] if reset_first else []) + [100]
        for n in runs:
            for k in range(n):
                t = 0.02 * k
                log += 20_000_000
                js = JointState(name=names, position=[float(x) for x in q[7:]],
                                effort=[float(0.5 * lim * np.sin(0.1 * k + j)) for j, lim in enumerate(limits)])
                js.effort[3] = float(0.9 * limits[3])  # the most loaded joint
                _stamp(js, t)
                rec.write("/joint_states", js, log)
                od = Odometry()
                _stamp(od, t)
                p = od.pose.pose.position
                p.x, p.y, p.z = float(q[0]), float(q[1]), float(q[2] + 0.001 * k)
                o = od.pose.pose.orientation
                o.x, o.y, o.z, o.w = (float(x) for x in q[3:7])
                rec.write("/sim/base_truth", od, log + 1)
                cs = ControllerState(fsm_state=FSM[k] if n == 100 else "hold", mode="qp",
                                     transition_index=0 if k < 60 else 1, tick_time_ms=0.5 + 0.01 * k,
                                     qp_solve_time_ms=0.3)
                _stamp(cs, t)
                rec.write("/controller/state", cs, log + 2)
                sc = SimContacts(limbs=["left_foot", "right_foot", "left_hand", "right_hand"],
                                 normal_force=[150.0, 150.0, 0.0, 0.0], tangential_force=[10.0 + k, 12.0, 0.0, 0.0],
                                 surface=["ground", "ground", "", ""], rung=[-1, -1, -1, -1],
                                 grasped=[False, False, False, False])
                _stamp(sc, t)
                rec.write("/sim/contacts", sc, log + 3)
                ft = WrenchStamped()
                _stamp(ft, t)
                ft.wrench.force.z = 150.0
                rec.write("/ft/left_ankle", ft, log + 4)
                if n == 100 and k == 18:
                    rec.write("/whole_body_plan", WholeBodyPlan(robot="g1"), log + 5)


@pytest.fixture(scope="module")
def bag(tmp_path_factory, g1, env):
    path = tmp_path_factory.mktemp("report") / "bag"
    write_synthetic_bag(path, g1, env)
    return path


def test_load_run_reads_the_series_and_drops_the_run_before_a_reset(bag):
    from climb_coordinator.report import fsm_segments, load_run, plan_start_stamps

    run = load_run(bag)
    assert run.robot == "g1" and run.scenario == "default" and run.mode == "qp"
    assert len(run.js_t) == 100 and run.js_t[0] == 0.0  # the 5-tick earlier run is gone
    assert run.base_pose.shape == (100, 7) and run.base_pose[-1, 2] - run.base_pose[0, 2] == pytest.approx(0.099)
    assert [s for s, _, _ in fsm_segments(run.cs_t, run.fsm)] == ["hold", "unload", "transfer", "load", "hold"]
    assert run.limbs[0] == "left_foot" and run.normal.shape == (100, 4)
    assert run.topics["joint_states"] == 105 and run.plans_transitions == [0]
    # the plan arrived before tick 19; the FSM left hold at tick 20
    assert plan_start_stamps(run) == [400_000_000]
    sub = load_run(bag, max_rate_hz=10.0)
    assert 15 <= len(sub.js_t) <= 25


def test_plan_start_from_the_controllers_acceptance_not_from_the_recorders_arrival_order(tmp_path):
    """A recorder may log the plan after the controller states of the ticks that took it (two
    topics, two readers). The controller's acceptance diagnostic names its last tick before the plan:
    the start is the next tick, whatever the arrival order. Without it the old rule (first FSM change
    logged after the plan) is the fallback, and it picks a later change in such a bag."""
    from climb_msgs.msg import ControllerState, WholeBodyPlan
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from climb_coordinator.report import load_run, plan_start_stamps
    from msgs_py.bag import BagRecorder

    def write(path, with_diagnostic: bool, periodic: bool = False) -> None:
        with BagRecorder(path, close_on_signals=False) as rec:
            log = 10
            for k in range(100):
                log += 20_000_000
                cs = ControllerState(fsm_state=FSM[k], mode="qp")
                _stamp(cs, 0.02 * k)
                rec.write("/controller/state", cs, log)
                if k == 25:  # logged six ticks after the controller took it (tick 20)
                    rec.write("/whole_body_plan", WholeBodyPlan(robot="g1"), log + 1)
                    if with_diagnostic:
                        status = DiagnosticStatus(name="controller/plan", message="accepted whole_body_plan: 1 transitions",
                                                  values=[KeyValue(key="after_tick_ns", value=str(380_000_000))])
                        rec.write("/diagnostics", DiagnosticArray(status=[status]), log + 2)
                if periodic and k == 50:  # the controller's periodic diagnostic repeats every acceptance
                    status = DiagnosticStatus(name="controller", message="transfer",
                                              values=[KeyValue(key="fsm_state", value="transfer"),
                                                      KeyValue(key="plans_after_tick_ns", value="380000000")])
                    rec.write("/diagnostics", DiagnosticArray(status=[status]), log + 2)

    write(tmp_path / "with", True)
    write(tmp_path / "without", False)
    write(tmp_path / "periodic", False, periodic=True)
    run = load_run(tmp_path / "with")
    assert run.plans_after_tick_ns == [380_000_000]
    assert plan_start_stamps(run) == [400_000_000]
    assert plan_start_stamps(load_run(tmp_path / "without")) == [700_000_000]  # the next FSM change
    # the acceptance itself missed by the recorder (its subscription matched late): the periodic
    # diagnostic's copy gives the same start
    repeated = load_run(tmp_path / "periodic")
    assert repeated.plans_after_tick_ns == [380_000_000] and plan_start_stamps(repeated) == [400_000_000]


def test_plan_start_from_the_controllers_count_on_every_state(tmp_path):
    """controller/state counts the plans the controller took (plans_taken): a plan starts on the
    first state that counts it, with no diagnostic in the bag and whatever the arrival order; two
    plans between two ticks, a plan on the first tick and a count that does not match the bag's
    plans (it falls back to the FSM rule) too."""
    from climb_msgs.msg import ControllerState, WholeBodyPlan

    from climb_coordinator.report import load_run, plan_start_stamps, plan_taking_stamps
    from msgs_py.bag import BagRecorder

    with BagRecorder(tmp_path / "counted", close_on_signals=False) as rec:
        log = 10
        for k in range(100):
            log += 20_000_000
            cs = ControllerState(fsm_state=FSM[k], mode="qp", plans_taken=int(k >= 20) + int(k >= 60))
            _stamp(cs, 0.02 * k)
            rec.write("/controller/state", cs, log)
            if k in (25, 65):  # logged after the controller states of the ticks that took them
                rec.write("/whole_body_plan", WholeBodyPlan(robot="g1"), log + 1)
    run = load_run(tmp_path / "counted")
    assert list(run.plans_taken[[0, 20, 60, 99]]) == [0, 1, 2, 2]
    assert plan_start_stamps(run) == [400_000_000, 1_200_000_000]
    assert plan_taking_stamps([5, 10, 15], [0, 2, 2], 2) == [10, 10]
    assert plan_taking_stamps([5, 10, 15], [1, 1, 2], 2) == [5, 15]
    assert plan_taking_stamps([5, 10, 15], [0, 0, 0], 1) is None
    assert plan_taking_stamps([5, 10, 15], [3, 3, 4], 3) is None


def test_compare_base_aligns_on_stamps():
    from climb_coordinator.report import compare_base

    t = np.arange(100) * 0.005
    p = np.zeros((100, 3))
    p[:, 2] = t
    q = p.copy()
    q[50:, 0] += 0.002  # 2 mm off from tick 50
    r = compare_base(t, p, t[10:], q[10:])
    assert r["compared"] == 90 and r["max_mm"] == pytest.approx(2.0) and r["at_s"] >= 0.25
    assert r["rms_mm"] == pytest.approx(np.sqrt(50 / 90) * 2.0, abs=1e-4)
    assert compare_base(t, p, t + 1e-3 / 3, p)["compared"] == 0


def test_report_script_writes_the_report_from_the_bag_alone(bag, tmp_path):
    out = tmp_path / "report"
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "report.py"), str(bag), "--out", str(out),
                           "--film", "3"], capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    for name in ("report_png", "film_strip_png", "report_md"):
        assert pathlib.Path(result[name]).is_file() and pathlib.Path(result[name]).stat().st_size > 500, name
    md = (out / "report.md").read_text()
    assert "| 0.400 | 0.700 | unload |" in md or "unload" in md
    assert result["summary"]["fsm_final"] == "hold" and result["summary"]["plans"] == 1
    import matplotlib.image as mpimg

    strip = mpimg.imread(out / "film_strip.png")
    assert strip.shape[1] > 2 * strip.shape[0]  # three frames side by side
    assert float(np.std(strip[..., :3])) > 0.02  # not a blank image: the robot and ladder are drawn


def test_report_script_refuses_a_missing_bag(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "report.py"), str(tmp_path / "nope")],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and "does not exist" in proc.stderr
