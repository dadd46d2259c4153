#!/usr/bin/env python3
"""Plan a ladder climb and execute it in the simulator (in-process, lock-step, no ROS).

    scripts/climb.py --ladder default --robot g1 --rungs 2 --mode qp --out out/climb [--seed 0] [--no-bag]

--ladder: a name in config/ladders/ or a ladder spec file (shared/specs/ladder_spec.md).
Writes DIR/bag (rosbag2 MCAP: joint_states, ft/*, sim/base_truth, joint_command,
controller/state) and DIR/plots.png; progress on standard error; the last line on standard output
is the JSON summary (ladder_spec.md "Results"). Exit codes: 0 climbed, 1 did not, 2 bad spec or
option (`error: <field>: <rule>` on standard error, no traceback).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (loopback profile, private domain)

ROOT = pathlib.Path(__file__).resolve().parents[1]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ladder", default="default", help="ladder spec: name in config/ladders/ or a YAML file")
    ap.add_argument("--robot", default="g1", help="robot config name (config/robots/<name>.yaml)")
    ap.add_argument("--rungs", type=int, default=2, help="climbing cycles after the mount (feet end on rung N)")
    ap.add_argument("--mode", default="qp", help="controller mode: qp | compliance")
    ap.add_argument("--out", default="out/climb", help="output directory (bag, plots)")
    ap.add_argument("--seed", type=int, default=None, help="planner random seed (default: config/planner.yaml)")
    ap.add_argument("--no-bag", action="store_true", help="do not record a bag")
    ap.add_argument("--plan-cycles", type=int, default=None,
                    help="plan this many cycles at a time; the next ones are planned from the reached state")
    ap.add_argument("--descend", action="store_true",
                    help="after the climb, climb back down to the ground (the reverse of the climbing cycles)")
    ap.add_argument("--snapshots", type=int, default=0, help="film strip frames (DIR/film_strip.png)")
    ap.add_argument("--no-plots", action="store_true", help="do not write DIR/plots.png")
    ap.add_argument("--command-delay", type=int, default=0, choices=(0, 1),
                    help="1: every command acts one control period late (a robot's actuation latency; "
                         "the controller then computes each command for the state one period ahead)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from climb_core.errors import ClimbError, SpecError
    from climb_coordinator.climb import ClimbRequest, base_summary, run_climb

    req = ClimbRequest(ladder=args.ladder, robot=args.robot, rungs=args.rungs, mode=args.mode,
                       out_dir=args.out, seed=args.seed, bag=not args.no_bag, snapshots=args.snapshots,
                       descend=args.descend, plan_cycles=args.plan_cycles, command_delay_ticks=args.command_delay)
    summary = base_summary(req)
    try:
        result = run_climb(req, on_progress=lambda m: print(m, file=sys.stderr, flush=True))
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = f"spec: {exc}"
        print(json.dumps(summary))
        return 2
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        summary["failure_reason"] = str(exc)
        print(json.dumps(summary))
        return 1
    try:
        if result.backend is not None:
            from climb_coordinator.plots import film_strip, plot_climb

            if not args.no_plots:
                result.summary["plots"] = str(plot_climb(result, pathlib.Path(args.out) / "plots.png"))
            if result.frames:
                result.summary["film_strip"] = str(film_strip(result.frames, pathlib.Path(args.out) / "film_strip.png"))
    finally:
        result.close()
    print(json.dumps(result.summary))
    return 0 if result.summary["success"] else 1


if __name__ == "__main__":
    sys.exit(main())
