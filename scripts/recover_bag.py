#!/usr/bin/env python3
"""Repair a rosbag2 (MCAP) bag whose recorder was killed (no metadata.yaml, no MCAP summary):
every message up to the last flushed chunk is kept, the bag is rewritten complete in place.

    scripts/recover_bag.py out/demo/bag

The last line on standard output is one JSON object: {"bag": ..., "messages": N}.
"""
from __future__ import annotations

import argparse
import json
import sys

from climb_core.errors import SpecError
from msgs_py.bag import recover_bag


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="bag directory")
    args = ap.parse_args(argv)
    try:
        n = recover_bag(args.bag)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"bag": args.bag, "messages": n}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
