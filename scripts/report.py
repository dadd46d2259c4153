#!/usr/bin/env python3
"""The run report from a bag alone: report.png (CoM path, contact forces against their cones, the
most loaded joints against their limits, controller tick times, FSM timeline), film_strip.png
(re-rendered headless from the recorded joint states and the recorded request) and report.md.

    scripts/report.py out/demo/bag [--out out/demo/report] [--film 8]

Prints the paths written; the last line on standard output is one JSON object
({"report_png": ..., "film_strip_png": ..., "report_md": ..., "summary": {...}}).
Exit code 2 with a one-line message when the bag cannot be read.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="rosbag2 bag directory")
    ap.add_argument("--out", default=None, help="output directory (default: <bag>/../report)")
    ap.add_argument("--film", type=int, default=8, help="film strip frames (0: none)")
    ap.add_argument("--max-rate", type=float, default=50.0,
                    help="[Hz] decimate joint states / base / contacts to this rate (0: every message)")
    args = ap.parse_args(argv)
    from climb_core.errors import ClimbError
    from climb_coordinator.report import load_run, summary, write_report

    bag = pathlib.Path(args.bag)
    out = pathlib.Path(args.out) if args.out else bag.resolve().parent / "report"
    try:
        run = load_run(bag, max_rate_hz=args.max_rate or None)
    except ClimbError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - an unreadable bag: say so in one line
        print(f"error: cannot read {bag}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    paths = write_report(run, out, film=args.film)
    for note in paths.pop("notes", []):
        print(f"note: {note}", file=sys.stderr)
    for name, path in paths.items():
        print(f"{name}: {path}")
    print(json.dumps({**{k: str(v) for k, v in paths.items()}, "summary": summary(run)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
