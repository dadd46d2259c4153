#!/usr/bin/env python3
"""Benchmark of the shared core: model setup, quasi-static feasibility, distance queries.

Prints, beside each measurement, a baseline measured in the same run:
- feasibility: the same force problem solved as an LP by scipy.optimize.linprog (HiGHS);
- distances: the same 20 robot-link / rung pairs on the raw link meshes (coal BVH) instead of
  the convex hulls.
The last line is one JSON object (units in the keys).

    .venv/bin/python scripts/bench_core.py [--robot g1] [--ladder default] [--calls 1000]
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)
import time
import xml.etree.ElementTree as ET

import numpy as np


def _percentiles(samples_s: list[float]) -> tuple[float, float]:
    arr = np.asarray(samples_s) * 1e3
    return float(np.median(arr)), float(np.percentile(arr, 99))


def _timed(fn, n: int) -> list[float]:
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out.append(time.perf_counter() - t0)
    return out


def _raw_mesh_query(robot, env, links: list[str], rungs: list[str]):
    """A pin.GeometryModel with the URDF's raw collision meshes of ``links`` and the rungs."""
    import coal
    import pinocchio as pin

    meshes = {}
    for link in ET.parse(robot.config.urdf_path).getroot().iter("link"):
        files = [m.get("filename") for c in link.iter("collision") for m in c.iter("mesh")]
        if len(files) == 1 and files[0].startswith("package://"):
            rel = files[0].removeprefix("package://")
            for base in robot.config.package_dirs:
                if (pathlib.Path(base) / rel).is_file():
                    meshes[f"{link.get('name')}_0"] = str(pathlib.Path(base) / rel)
    loader = coal.MeshLoader()
    gm = pin.GeometryModel()
    for go in robot.collision_model.geometryObjects:
        if go.name in links:
            gm.addGeometryObject(pin.GeometryObject(go.name, go.parentJoint, go.parentFrame, go.placement,
                                                    loader.load(meshes[go.name], np.ones(3))))
    objects = {name: (g, tf) for name, g, tf in env.collision_objects()}
    for rung in rungs:
        g, tf = objects[rung]
        gm.addGeometryObject(pin.GeometryObject(rung, 0, 0, pin.SE3(tf.getRotation(), tf.getTranslation()), g))
    index = {go.name: i for i, go in enumerate(gm.geometryObjects)}
    for link in links:
        for rung in rungs:
            gm.addCollisionPair(pin.CollisionPair(index[link], index[rung]))
    return gm, pin.GeometryData(gm), meshes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--ladder", default="default")
    ap.add_argument("--calls", type=int, default=1000, help="feasibility / distance calls timed")
    args = ap.parse_args(argv)

    import pinocchio as pin

    from climb_core import collision, feasibility, fixtures
    from climb_core.environment import build_environment
    from climb_core.ladder import load_scenario
    from climb_core.robot import RobotModel, load_robot, load_robot_config

    # ---- setup
    t0 = time.perf_counter()
    robot = load_robot(args.robot)
    t_robot = time.perf_counter() - t0
    t1 = time.perf_counter()
    env = build_environment(load_scenario(args.ladder))
    t_env = time.perf_counter() - t1
    t2 = time.perf_counter()
    checker = collision.checker(robot, env)
    t_coll = time.perf_counter() - t2
    t_setup = time.perf_counter() - t0
    t3 = time.perf_counter()
    RobotModel(load_robot_config(args.robot))  # a second, uncached model build
    t_model = time.perf_counter() - t3
    print(f"setup: robot {t_robot * 1e3:.0f} ms + environment {t_env * 1e3:.1f} ms + collision model "
          f"{t_coll * 1e3:.1f} ms ({checker.n_pairs} pairs) = {t_setup * 1e3:.0f} ms; model rebuild "
          f"{t_model * 1e3:.0f} ms")

    # ---- feasibility, 4 holds
    cfg = feasibility.load_config()
    stance, q0 = fixtures.get("ladder_4_contacts", robot, env)
    rng = np.random.default_rng(0)
    qs = [q0.copy() for _ in range(args.calls)]
    for q in qs:
        q[7:] += rng.normal(0.0, 1e-3, len(q) - 7)  # [rad] distinct configurations, same stance
    first = feasibility.check(robot, env, q0, stance, cfg)
    feasibility.check_equilibrium(robot, q0, stance, cfg, env=env)  # warm the stance cache
    eq = _timed(lambda i: feasibility.check_equilibrium(robot, qs[i], stance, cfg, env=env), args.calls)
    nocol = _timed(lambda i: feasibility.check(robot, env, qs[i], stance, cfg, collision=False), args.calls)
    full = _timed(lambda i: feasibility.check(robot, env, qs[i], stance, cfg), args.calls)
    highs_cfg = feasibility.with_check(cfg, solver="highs")
    feasibility.check_equilibrium(robot, q0, stance, highs_cfg, env=env)
    n_base = max(50, args.calls // 5)
    highs = _timed(lambda i: feasibility.check_equilibrium(robot, qs[i], stance, highs_cfg, env=env), n_base)
    # the solver alone, on one problem
    ws = feasibility.workspace(robot)
    cs = ws.compiled(env, stance, cfg)
    pin.computeJointJacobians(robot.model, ws.data, q0)
    g = pin.computeGeneralizedGravity(robot.model, ws.data, q0).copy()
    Jc = feasibility.contact_jacobians(ws, cs, q0)
    problem = feasibility.build_force_problem(ws, cs, g, Jc, cfg.check)
    solve_daqp = _timed(lambda i: feasibility.solve_force_problem(problem, cfg.check, "daqp"), args.calls)
    solve_highs = _timed(lambda i: feasibility.solve_force_problem(problem, cfg.check, "highs"), n_base)
    lp_daqp = feasibility.solve_force_problem(problem, cfg.check, "daqp")
    lp_highs = feasibility.solve_force_problem(problem, cfg.check, "highs")
    print(f"feasibility ({robot.config.name}, {len(stance.holds)} holds, {cs.n_forces} force variables, "
          f"{problem.A.shape[0]} rows): {first.summary()}")
    for label, samples in (("equilibrium only (daqp)", eq), ("check without collision", nocol),
                           ("check with collision", full), ("baseline: equilibrium, scipy HiGHS LP", highs),
                           ("  solver call daqp", solve_daqp), ("  solver call HiGHS", solve_highs)):
        med, p99 = _percentiles(samples)
        print(f"  {label:<40s} median {med:7.3f} ms  p99 {p99:7.3f} ms  (n={len(samples)})")
    print(f"  load ratio daqp {lp_daqp.x[-1]:.4f} vs HiGHS {lp_highs.x[-1]:.4f}")

    # ---- distances, 20 link / rung pairs
    _, _, meshes = _raw_mesh_query(robot, env, [], [])
    links = [g for g in checker.robot_geoms if g in meshes][:10]
    rungs = ["rung_2", "rung_3"]
    pairs = [(link, collision.ENV_PREFIX + rung) for link in links for rung in rungs]
    query = checker.pair_query(pairs)
    hull_t = _timed(lambda i: query.compute(qs[i]), args.calls)
    gm, gd, _ = _raw_mesh_query(robot, env, links, rungs)
    data = robot.model.createData()
    n_raw = max(50, args.calls // 5)
    raw_t = _timed(lambda i: pin.computeDistances(robot.model, data, gm, gd, qs[i]), n_raw)
    d_hull = query.compute(q0)
    pin.computeDistances(robot.model, data, gm, gd, q0)
    d_raw = np.array([r.min_distance for r in gd.distanceResults])
    full_dist = _timed(lambda i: checker.distances(qs[i], contacts=[(h.limb, h.env_surface) for h in stance.holds]),
                       args.calls)
    hm, hp = _percentiles(hull_t)
    rm, rp = _percentiles(raw_t)
    fm, fp = _percentiles(full_dist)
    print(f"distances, {len(pairs)} link/rung pairs: hulls median {hm * 1e3:.1f} us p99 {hp * 1e3:.1f} us; "
          f"baseline raw meshes median {rm * 1e3:.1f} us p99 {rp * 1e3:.1f} us; "
          f"max |hull - mesh| {np.max(np.abs(d_hull - d_raw)) * 1e3:.3f} mm, max (hull - mesh) "
          f"{np.max(d_hull - d_raw) * 1e6:.2f} um")
    print(f"all {checker.n_pairs} pairs (culled, exact minimum): median {fm:.3f} ms p99 {fp:.3f} ms")

    em, ep = _percentiles(eq)
    nm, npp = _percentiles(nocol)
    cm, cp = _percentiles(full)
    bm, bp = _percentiles(highs)
    summary = {
        "robot": robot.config.name, "ladder": args.ladder, "holds": len(stance.holds), "calls": args.calls,
        "setup_s": round(t_setup, 3), "robot_load_s": round(t_robot, 3), "model_rebuild_s": round(t_model, 3),
        "environment_build_ms": round(t_env * 1e3, 2), "collision_model_build_ms": round(t_coll * 1e3, 2),
        "feasibility_median_ms": round(em, 4), "feasibility_p99_ms": round(ep, 4),
        "feasibility_check_no_collision_median_ms": round(nm, 4),
        "feasibility_check_no_collision_p99_ms": round(npp, 4),
        "feasibility_check_full_median_ms": round(cm, 4), "feasibility_check_full_p99_ms": round(cp, 4),
        "baseline_highs_feasibility_median_ms": round(bm, 4), "baseline_highs_feasibility_p99_ms": round(bp, 4),
        "distance_20_pairs_median_us": round(hm * 1e3, 2), "distance_20_pairs_p99_us": round(hp * 1e3, 2),
        "baseline_raw_mesh_20_pairs_median_us": round(rm * 1e3, 2),
        "baseline_raw_mesh_20_pairs_p99_us": round(rp * 1e3, 2),
        "distance_all_pairs_median_ms": round(fm, 4), "distance_all_pairs_p99_ms": round(fp, 4),
        "collision_pairs": checker.n_pairs,
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
