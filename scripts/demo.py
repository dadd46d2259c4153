#!/usr/bin/env python3
"""`make demo`: G1 climbs 2 rungs of the default ladder in QP mode through the ROS 2 graph (every
node of config/graph.yaml in its own process, lock-step, headless; each command acts one control
period late, as between a controller and its robot, which lets the bridge's physics run while the
controller computes: about twice the speed on 2 cores) and writes out/demo/: bag/
(rosbag2 MCAP of every topic, by the recorder node), report/ (scripts/report.py: CoM path, contact
forces against their cones, the most loaded joints against their limits, tick times, FSM
timeline, film strip), logs/ (one per node). The last stdout line is the JSON summary.
Options are scripts/climb.py's (later ones override the defaults, e.g. --graph inprocess)."""
from __future__ import annotations

import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import climb  # noqa: E402  (scripts/climb.py)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    defaults = ["--scenario", "default", "--robot", "g1", "--rungs", "2", "--mode", "qp",
                "--out", str(ROOT / "out" / "demo"), "--snapshots", "8", "--graph", "processes",
                "--command-delay", "1"]
    return climb.main(defaults + argv)  # later options override the defaults


if __name__ == "__main__":
    sys.exit(main())
