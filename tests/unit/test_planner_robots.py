"""Ladder planner for the other robots (TALOS, Romeo): their primitive designs and the physical
result that stops Romeo (docs/robots_climbing.md).

Romeo's binding stance is the one every climbing cycle passes through: one foot on the rung above
the other, the lower foot unloaded (about to move), both hands on the rung above. Its arms
(wrists 0.6 / 0.86 / 2.2 N m, elbow yaw 6 N m, shoulders 19 / 9 N m) and hip pitch (46.6 N m)
cannot hold it; G1 holds the same stance."""
from __future__ import annotations

import dataclasses
import importlib.util
import pathlib

import numpy as np
import pinocchio as pin
import pytest
import yaml
from scipy.optimize import linprog

from climb_core import feasibility as fz
from climb_core import fixtures, holds
from climb_core.contact import Stance
from climb_core.robot import load_robot
from planner_node import pcik
from planner_node.primitives import SEQUENCE_NAMES, library_dir
from planner_node.settings import load_settings

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _design(robot: str) -> dict:
    return yaml.safe_load((library_dir(robot, "forward") / "design.yaml").read_text())


@pytest.mark.parametrize("name", ["talos", "romeo"])
def test_design_names_the_robots_own_joints_and_defined_primitives(name):
    robot = load_robot(name)
    design = _design(name)
    assert design["robot"] == name
    cues = dict(design["posture"]["climbing"] or {})
    cues.update(design["posture"]["standing"] or {})
    for spec in design["primitives"].values():
        cues.update(spec.get("posture") or {})
    assert cues, "the design gives posture cues"
    unknown = [j for j in cues if j not in robot.joint_names]
    assert not unknown, f"posture cues name joints {name} does not have: {unknown}"
    for seq, names in design["sequences"].items():
        assert seq in SEQUENCE_NAMES
        assert all(n in design["primitives"] for n in names)
    # seed holds inside the ladder's 0.5 m clear width, with room for the sole / gripper
    half_clear = 0.25  # [m] default ladder
    assert design["holds"]["foot_s"] + 0.5 * 0.12 < half_clear
    assert design["holds"]["hand_s"] + 0.5 * 0.095 < half_clear


def test_design_foot_offset_reaches_the_ik_targets_not_the_frozen_check(env):
    """make_primitives applies the TALOS design's foot_on_rung_offset to the hold targets; the
    hold points (what the frozen check judges) are the same rung line either way."""
    spec = importlib.util.spec_from_file_location("make_primitives", ROOT / "scripts" / "make_primitives.py")
    mp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mp)
    talos = load_robot("talos")
    base = fz.load_config()
    cfg = mp.design_hold_config(base, _design("talos"))
    assert cfg.holds.foot_on_rung_offset == pytest.approx(0.05)
    assert cfg.holds.foot_on_rung_pitch_deg == pytest.approx(10.0)  # the design's pitched soles too
    assert mp.design_hold_config(base, _design("g1")) is base
    pitched = dataclasses.replace(base.holds, foot_on_rung_pitch_deg=10.0)  # the same pitch, no offset
    h0 = holds.make_hold(talos, env, "left_foot", "rung_2", 0.085, params=pitched)
    h1 = holds.make_hold(talos, env, "left_foot", "rung_2", 0.085, params=cfg.holds)
    np.testing.assert_allclose(h0.positions, h1.positions)
    T0 = holds.hold_target(talos, env, h0, params=pitched).T_world_surface
    T1 = holds.hold_target(talos, env, h1, params=cfg.holds).T_world_surface
    # the sole centre moves 5 cm toward the robot along the sole (ball of the foot on the rung),
    # the sole pitched 10 deg toes up
    d = T0[:3, 3] - T1[:3, 3]
    assert np.linalg.norm(d) == pytest.approx(0.05, abs=1e-6)
    assert d[0] == pytest.approx(0.05 * np.cos(np.radians(10.0)), abs=1e-6)


def _staggered(robot, env, foot_s, hand_s):
    """Left foot on rung 2, right foot on rung 1 (unloaded, about to move), hands on rung 5."""
    cfg = fz.load_config()
    side = {"left_foot": 1.0, "right_foot": -1.0, "left_hand": 1.0, "right_hand": -1.0}
    hs = [holds.make_hold(robot, env, "left_foot", "rung_2", foot_s, params=cfg.holds),
          holds.make_hold(robot, env, "right_foot", "rung_1", -foot_s, params=cfg.holds)]
    hs += [holds.make_hold(robot, env, limb, "rung_5", side[limb] * hand_s, params=cfg.holds)
           for limb in ("left_hand", "right_hand")]
    return Stance(tuple(hs))


def _min_torque_ratio_lp(robot, q, stance, mu, grip=None):
    """Independent lower bound on max |tau| / effort over contact forces (scipy LP): gravity from
    pin.computeGeneralizedGravity, point forces at the hold points, friction pyramids mu on the
    feet, free 3D forces on the grasps whose sum per hand lies in the box |F_x|, |F_y|, |F_z| <=
    grip [N] (a relaxation of |F| <= grip; no box when grip is None)."""
    m, d = robot.model, robot.model.createData()
    g = pin.computeGeneralizedGravity(m, d, q).copy()
    pin.computeJointJacobians(m, d, q)
    pin.framesForwardKinematics(m, d, q)
    cols, bounds, normals, hands = [], [], [], []
    for h in stance.holds:
        fid = m.getFrameId(robot.config.limbs[h.limb].surface.frame)
        J = pin.getFrameJacobian(m, d, fid, pin.LOCAL_WORLD_ALIGNED)
        o = d.oMf[fid].translation
        for pt in h.points:
            Jp = J[:3] - pin.skew(pt.position - o) @ J[3:]
            if h.bilateral:
                hands.append((h.limb, len(cols)))
                cols += list(Jp)
                bounds += [(None, None)] * 3
            else:
                n = pt.normal / np.linalg.norm(pt.normal)
                t1 = np.cross(n, [0.0, 1.0, 0.0])
                t1 /= np.linalg.norm(t1)
                normals.append(len(cols))
                cols += [n @ Jp, t1 @ Jp, np.cross(n, t1) @ Jp]
                bounds += [(0.0, None), (None, None), (None, None)]
    JT = np.array(cols).T
    nf, eff = JT.shape[1], robot.effort_limits()
    A_ub = [np.hstack([-JT[6:], -eff[:, None]]), np.hstack([JT[6:], -eff[:, None]])]
    b_ub = [-g[6:], g[6:]]
    for i in normals:
        for t in (i + 1, i + 2):
            for sgn in (1.0, -1.0):
                row = np.zeros(nf + 1)
                row[t], row[i] = sgn, -mu
                A_ub.append(row[None, :])
                b_ub.append(np.zeros(1))
    for limb in {lb for lb, _ in hands} if grip is not None else ():
        for k in range(3):
            row = np.zeros(nf + 1)
            for _, i in (x for x in hands if x[0] == limb):
                row[i + k] = 1.0
            A_ub += [row[None, :], -row[None, :]]
            b_ub += [np.array([grip]), np.array([grip])]
    c = np.zeros(nf + 1)
    c[-1] = 1.0
    res = linprog(c, A_ub=np.vstack(A_ub), b_ub=np.concatenate(b_ub), A_eq=np.hstack([JT[:6], np.zeros((6, 1))]),
                  b_eq=g[:6], bounds=bounds + [(0.0, None)], method="highs")
    assert res.status == 0
    tau = g[6:] - JT[6:] @ res.x[:nf]
    return float(res.x[-1]), np.abs(tau) / eff


def test_romeo_cannot_shift_its_weight_to_the_upper_foot_torque_limits_named(env):
    romeo = load_robot("romeo")
    stance = _staggered(romeo, env, 0.12, 0.15)
    _, q4 = fixtures.get("ladder_4_contacts", romeo, env)  # feet rung 1, hands rung 5
    contacts = [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE if h.limb == "right_foot" else pcik.REGULAR, hold=h)
                for h in stance.holds]
    res = pcik.solve(romeo, env, q4, contacts, params=load_settings().pcik)
    assert not res.success
    torque = [v.split(":", 1)[1] for v in res.violated if v.startswith("torque_limit:")]
    assert torque, res.violated
    # the arms' distal joints and the support leg's hip pitch are the ones named
    assert any("Wrist" in j for j in torque), torque
    assert set(torque) <= {j for j in romeo.joint_names if j.startswith(("L", "R"))}
    # independent check at the closest configuration that makes the contacts: with the ladder's
    # friction on the single foot and the hands' grip strength, the torque limits are exceeded
    sub = stance.without("right_foot")
    q = res.q
    chk = fz.check(romeo, env, q, sub, collision=False)
    if chk.details.get("contact_errors") and max(e[1] for e in chk.details["contact_errors"]) > 0.003:
        q = pcik.solve(romeo, env, q4, contacts, params=load_settings().pcik, physics=False).q
    lb, ratio = _min_torque_ratio_lp(romeo, q, sub, mu=env.scenario.ladder.friction,
                                     grip=romeo.config.grip_strength)
    assert lb > 1.0, lb
    binding = {romeo.joint_names[i] for i in np.flatnonzero(ratio > 0.99 * lb)}
    assert any("Wrist" in j or "Elbow" in j or "Shoulder" in j or "HipPitch" in j for j in binding), binding


def test_g1_holds_the_same_stance(g1, env):
    """Contrast (the same construction can succeed): G1 carries the stance within its limits."""
    stance = _staggered(g1, env, 0.12, 0.12)
    _, q4 = fixtures.get("ladder_4_contacts", g1, env)
    contacts = [pcik.ContactSpec(h.limb, pcik.ZERO_FORCE if h.limb == "right_foot" else pcik.REGULAR, hold=h)
                for h in stance.holds]
    res = pcik.solve(g1, env, q4, contacts, params=load_settings().pcik)
    assert res.success, res.violated
    chk = fz.check(g1, env, res.q, stance.without("right_foot"))
    assert chk.feasible and chk.details["load_ratio_variable"] < 0.95


def test_talos_plans_the_default_ladder_two_steps_and_the_frozen_check_passes_the_plan(env):
    """TALOS's library (config/primitives/talos/forward, its design's soles pitched 10 deg toes up
    with the ball of the foot on the rung: the shin then clears the next rung) plans the default
    ladder's mount and two cycles; the frozen feasibility check re-verifies every configuration
    of the plan and its feet end on rung 2."""
    from planner_node.climb_planner import plan_climb
    from planner_node.verify import verify_plan

    talos = load_robot("talos")
    settings = load_settings()
    res = plan_climb(talos, env, 2, settings=settings, seed=0, timeout_s=120.0)
    assert res.success, (res.failure_constraint, res.failure_detail)
    assert res.summary()["rungs_reached"] == 2 and res.plan.robot == "talos"
    feet = [h for h in res.plan.transitions[-1].target_stance.holds if h.limb.endswith("_foot")]
    assert sorted(h.env_surface for h in feet) == ["rung_2", "rung_2"]
    rep = verify_plan(talos, env, res.plan, refine=1, settings=settings, goal_feet_rung=2)
    assert rep.ok, rep.summary()
