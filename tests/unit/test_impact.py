"""controller_node.impact without a controller: a blow read on the F/T and on the joint
velocities, against a contact's force ramp and a guarded placement that must not read as one."""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from controller_node.ft_monitor import FtMonitor
from controller_node.impact import ImpactMonitor
from controller_node.params import load_controller_params


def monitors(**impact):
    params = load_controller_params(**{f"impact.{k}": v for k, v in impact.items()})
    ft = FtMonitor({"ankle": 0}, [("foot", "ankle")], params.guarded, params.control_period_s)
    return ft, ImpactMonitor(params.impact, params.control_period_s), [pin.SE3.Identity()], params


def feed(ft, mon, oMf, forces, t0=0.0, v=None, qdd=None, dt=0.005):
    """Feed force vectors (one per tick); the first impact or None."""
    found = None
    for k, f in enumerate(forces):
        ft.update(oMf, {"ankle": np.concatenate([f, np.zeros(3)])})
        hit = mon.update(t0 + k * dt, ft, np.zeros(3) if v is None else v[k], qdd)
        found = found or hit
    return found


def test_a_force_ramp_and_a_placement_are_no_impact_a_blow_is():
    ft, mon, oMf, p = monitors()
    rng = np.random.default_rng(1)
    noise = lambda n: rng.normal(0.0, 2.0, (n, 3))  # noqa: E731 (0.2 % of a 1 kN range)
    # a foot loaded from 0 to 300 N over the engage ramp (0.2 s), then held
    ramp = np.linspace(0.0, 300.0, 40)[:, None] * np.array([0.0, 0.0, 1.0]) + noise(40)
    held = np.tile([0.0, 0.0, 300.0], (200, 1)) + noise(200)
    assert feed(ft, mon, oMf, np.vstack([ramp, held])) is None
    assert mon.peaks.force_ratio < 0.5
    # a guarded placement: the foot creeps onto its rung at 4 cm/s against 20 kN/m (800 N/s)
    creep = np.array([0.0, 0.0, 300.0]) + np.linspace(0.0, 80.0, 20)[:, None] * np.array([0.0, 0.0, 1.0])
    assert feed(ft, mon, oMf, creep, t0=1.2) is None
    # a blow: 1.5 kN more within 10 ms (a 7 kg ball at 5.5 m/s measured 1-5 kN at the ankles)
    blow = np.tile([0.0, 0.0, 380.0], (3, 1)) + np.array([[0.0, 0.0, 0.0], [900.0, 0.0, 600.0], [1200.0, 0.0, 900.0]])
    hit = feed(ft, mon, oMf, blow, t0=1.4)
    assert hit is not None and hit.source == "ft:foot" and hit.value > p.impact.force_jump
    assert abs(hit.time - 1.405) < 1e-9  # the tick of the blow


def test_a_joint_velocity_the_last_accelerations_do_not_explain_is_an_impact():
    ft, mon, oMf, p = monitors()
    qdd = np.array([100.0, 0.0, -50.0])  # [rad/s^2] what the QP asked for
    dt = p.control_period_s
    v = [np.zeros(3)]
    for _ in range(20):  # tracked: the velocity follows the accelerations (plus small errors)
        v.append(v[-1] + qdd * dt + 0.05)
    assert feed(ft, mon, oMf, [np.zeros(3)] * len(v), v=v, qdd=qdd) is None
    assert mon.peaks.joint_velocity_jump < 0.1
    v2 = [v[-1], v[-1] + qdd * dt + np.array([0.0, 15.0, 0.0])]  # a 15 rad/s kick on joint 1
    hit = feed(ft, mon, oMf, [np.zeros(3)] * 2, t0=1.0, v=v2, qdd=qdd)
    assert hit is not None and hit.source == "joint:1" and abs(hit.value - 15.0) < 1e-6


def test_muted_and_disabled_monitors_keep_their_peaks_but_report_nothing():
    ft, mon, oMf, p = monitors()
    blow = [np.zeros(3), np.array([0.0, 0.0, 2000.0])]
    mon.mute_until(10.0)
    assert feed(ft, mon, oMf, blow) is None and mon.peaks.force_ratio > 1.0
    ft, mon, oMf, p = monitors(enabled=False)
    assert feed(ft, mon, oMf, blow) is None and mon.peaks.force_ratio > 1.0
