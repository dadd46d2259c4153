#!/usr/bin/env python3
"""How well a sole's line on a round rung is located from ankle F/T (controller_node.line_contact),
on synthetic readings: a foot on a rung where planned and 2 cm off, F/T noise of sigma 0.5 % and
2 % of the ankle's ranges (1 kN / 50 N m) with a bias of half that, a 90 N load with a 5 N push
along the ladder, 0.55 s of readings after 0.3 s in the air, one seed per case.

    .venv/bin/python scripts/bench_line_contact.py [--seeds 200]

Prints per case: moved (cases with any move), false moves (>= min_shift on a line where planned),
the first move's median time, the final line's mean and spread; last line one JSON object.
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import pinocchio as pin

from controller_node.line_contact import GRAVITY, LineContactLocator
from controller_node.params import ControllerParams

FOOT_MASS = 0.6  # [kg]
FOOT_COM = np.array([0.03, 0.0, -0.02])  # [m] sensor frame
POINTS = np.array([[0.04, -0.03, -0.035], [0.04, 0.03, -0.035]])  # the planned line [m]
RANGES = (1000.0, 50.0)  # [N], [N m] the ankle sensor's (config/robots/g1.yaml)


def foot_model() -> tuple[pin.Model, int]:
    model = pin.Model()
    jid = model.addJoint(0, pin.JointModelRY(), pin.SE3.Identity(), "ankle")
    model.appendBodyToJoint(jid, pin.Inertia(FOOT_MASS, FOOT_COM, np.eye(3) * 1e-3), pin.SE3.Identity())
    return model, model.addFrame(pin.Frame("foot", jid, 0, pin.SE3.Identity(), pin.FrameType.BODY))


def reading(R, line_x, normal, tangential, rng, sigma_f, sigma_m):
    F = R.T @ np.array([tangential, 0.0, normal])
    g = FOOT_MASS * (R.T @ GRAVITY)
    wrench = np.concatenate([F + g, np.cross([line_x, 0.0, POINTS[0, 2]], F) + np.cross(FOOT_COM, g)])
    return wrench + np.concatenate([rng.normal(0, sigma_f, 3), rng.normal(0, sigma_m, 3)])


def run_case(noise_percent: float, shift: float, seeds: int, params) -> dict:
    moved, false, firsts, totals = 0, 0, [], []
    sigma_f, sigma_m = RANGES[0] * noise_percent / 100, RANGES[1] * noise_percent / 100
    for seed in range(seeds):
        model, fid = foot_model()
        R = pin.utils.rotate("y", -0.05)
        oMf = {fid: pin.SE3(R, np.zeros(3))}
        locator = LineContactLocator(model, {"foot": ("ankle", fid)}, params)
        rng = np.random.default_rng(seed)
        bias = np.concatenate([rng.normal(0, 0.5 * sigma_f, 3), rng.normal(0, 0.5 * sigma_m, 3)])
        for _ in range(60):  # 0.3 s in the air
            locator.observe({"ankle": reading(R, 0.04, 0.0, 0.0, rng, sigma_f, sigma_m) + bias}, ["foot"])
        locator.tare("foot", oMf)
        locator.start("foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
        t, total, first = 0.0, 0.0, None
        while t < 0.55:
            t += 0.005
            for move in locator.update(t, oMf, {"ankle": reading(R, 0.04 + shift, 90.0, 5.0, rng, sigma_f, sigma_m)
                                                 + bias}):
                total, first = move.total, first or t
        moved += first is not None
        false += shift == 0.0 and abs(total) >= params.min_shift
        if first is not None:
            firsts.append(first)
        totals.append(total)
    return {"moved": moved, "false": false, "first_ms": 1e3 * float(np.median(firsts)) if firsts else None,
            "mean_mm": 1e3 * float(np.mean(totals)), "sd_mm": 1e3 * float(np.std(totals))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=200)
    args = ap.parse_args()
    params = ControllerParams().line_contact
    figures = {}
    for noise in (0.5, 2.0):
        for shift in (0.0, 0.02):
            r = run_case(noise, shift, args.seeds, params)
            first = "-" if r["first_ms"] is None else f"{r['first_ms']:.0f} ms"
            print(f"noise {noise} %, line {100 * shift:.0f} cm off: moved {r['moved']}/{args.seeds}, false moves "
                  f"{r['false']}, first move {first} (median), found {r['mean_mm']:.1f} +- {r['sd_mm']:.1f} mm")
            key = f"noise{noise:g}pct_off{100 * shift:g}cm"
            if shift == 0.0:
                figures[f"{key}_false_moves_percent"] = round(100.0 * r["false"] / args.seeds, 2)
            else:
                figures[f"{key}_found_percent"] = round(100.0 * r["moved"] / args.seeds, 2)
                figures[f"{key}_first_move_ms"] = r["first_ms"]
                figures[f"{key}_error_mm"] = round(r["mean_mm"] - 1e3 * shift, 2)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
