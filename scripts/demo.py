#!/usr/bin/env python3
"""`make demo`: G1 plans and executes a 2-step climb of the default ladder in QP mode
(in-process, lock-step) and writes out/demo/: bag/ (rosbag2 MCAP), plots.png (CoM path, contact
forces against their cones, the most loaded joints' torques against their limits, controller tick
times), film_strip.png (headless snapshots). The last stdout line is the JSON summary."""
from __future__ import annotations

import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import climb  # noqa: E402  (scripts/climb.py)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    defaults = ["--ladder", "default", "--robot", "g1", "--rungs", "2", "--mode", "qp",
                "--out", str(ROOT / "out" / "demo"), "--snapshots", "8"]
    return climb.main(defaults + argv)  # later options override the defaults


if __name__ == "__main__":
    sys.exit(main())
