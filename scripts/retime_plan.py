#!/usr/bin/env python3
"""Time a stored whole-body plan (scripts/plan.py --out) again, its paths unchanged.

    scripts/retime_plan.py IN.json OUT.json --speed-scale 0.5 [--set timing.FIELD=VALUE ...]

Every transition's way-points are timed again as the planner times them
(planner_node.interpolation.time_parameterize) under config/planner.yaml's ``timing`` group with
the joint and base speed limits multiplied by ``--speed-scale`` and any ``--set`` applied. A
quasi-static plan does not change with its speed; how well it is executed does (narrow_passage's
single-support steps at the planner's 0.08 m/s tipped G1 forward, at half of it they did not:
docs/multicontact.md). The last line on standard output is a JSON summary (durations [s]); a bad
option or plan prints ``error: <field>: <rule>`` on standard error and exits with code 2.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("plan", help="whole-body plan JSON (scripts/plan.py --out)")
    parser.add_argument("out", help="where to write the retimed plan")
    parser.add_argument("--speed-scale", type=float, default=1.0,
                        help="factor on timing.max_joint_speed, max_base_speed, max_base_angular_speed")
    parser.add_argument("--set", action="append", default=[], metavar="timing.FIELD=VALUE",
                        help="override a field of config/planner.yaml's timing group")
    args = parser.parse_args(argv)
    from climb_core.errors import SpecError
    from climb_core.robot import load_robot
    from planner_node import plan_io
    from planner_node.settings import apply_overrides, load_settings, parse_overrides

    try:
        if not 0.0 < args.speed_scale <= 10.0:
            raise SpecError("speed-scale", f"must be in (0, 10], got {args.speed_scale}")
        overrides = parse_overrides(args.set)
        if any(not key.startswith("timing.") for key in overrides):
            raise SpecError("--set", f"only timing.* fields are retimed, got {sorted(overrides)}")
        timing = apply_overrides(load_settings(), overrides, where="--set").timing
        s = args.speed_scale
        timing = dataclasses.replace(timing, max_joint_speed=timing.max_joint_speed * s,
                                     max_base_speed=timing.max_base_speed * s,
                                     max_base_angular_speed=timing.max_base_angular_speed * s)
        plan, metadata = plan_io.load_plan(args.plan)
        robot = load_robot(plan.robot)
        out = plan_io.retimed(plan, robot.model, timing)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    metadata = dict(metadata or {})
    metadata["retimed"] = {"speed_scale": s, "timing": dataclasses.asdict(timing)}
    plan_io.save_plan(args.out, out, metadata)
    before = sum(float(t.times[-1]) for t in plan.transitions)
    after = sum(float(t.times[-1]) for t in out.transitions)
    print(json.dumps({"plan": args.out, "transitions": len(out.transitions), "duration_before_s": round(before, 2),
                      "duration_s": round(after, 2)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
