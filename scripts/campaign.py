#!/usr/bin/env python3
"""Perturbation campaign: each case an executed in-process climb of G1 on the default ladder
(2 steps, QP), the perturbation known to the simulator only (climb_coordinator.campaign).

    scripts/campaign.py [--families rung_dz,rung_dx,ball_4_contacts,...,ft_noise] [--workers 2]
                        [--ft-noise 1.0] [--out-dir docs/robustness]
                        [--journal build/campaign/journal.jsonl] [--fresh]

Resumable: every finished case is appended to the journal; a rerun skips the cases already there
(--fresh starts over). Writes OUT/campaign.csv and OUT/success.png from every case of the journal.
The last line on standard output is one JSON object: the largest perturbation survived per
family (offsets up and down [m], masses [kg], F/T noise [%]), cases run, wall time. --ft-noise:
the F/T noise (sigma in % of each sensor's range, bias half of it) of every case outside the
ft_noise family (default 0.5 %, the largest level the nominal climb survived; 0: off).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

from climb_core.ros_env import apply_local_dds_env

apply_local_dds_env()  # DDS stays on this machine (nothing here talks DDS; the rule holds anyway)

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    import functools

    from climb_coordinator.campaign import (DEFAULT_FT_NOISE, FAMILIES, _worker, cases, read_journal, run_campaign,
                                            write_outputs)

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--families", default="rung_dz,rung_dx", help=f"comma-separated, of {', '.join(FAMILIES)}")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out-dir", default=str(ROOT / "docs" / "robustness"))
    ap.add_argument("--journal", default=str(ROOT / "build" / "campaign" / "journal.jsonl"))
    ap.add_argument("--fresh", action="store_true", help="ignore the journal (start over)")
    ap.add_argument("--ft-noise", type=float, default=DEFAULT_FT_NOISE,
                    help="[%%] F/T noise sigma of the cases outside the ft_noise family (bias: half of it)")
    args = ap.parse_args(argv)
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        print(f"error: --families: unknown {unknown or 'none given'} (known: {', '.join(FAMILIES)})", file=sys.stderr)
        return 2
    if args.workers < 1:
        print("error: --workers: must be >= 1", file=sys.stderr)
        return 2
    if not 0.0 <= args.ft_noise <= 100.0:
        print("error: --ft-noise: must be in [0, 100] [%]", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    todo = cases(families)
    rows = run_campaign(todo, pathlib.Path(args.journal), args.workers, resume=not args.fresh,
                        run=functools.partial(_worker, ft_noise_percent=args.ft_noise),
                        say=lambda m: print(m, file=sys.stderr, flush=True))
    # the table and the plots cover every case of the journal (earlier runs of other families too)
    everything = list(read_journal(pathlib.Path(args.journal)).values())
    figures = write_outputs(everything, pathlib.Path(args.out_dir))
    figures.update({"cases": len(rows), "succeeded": sum(bool(r["success"]) for r in rows),
                    "journal_cases": len(everything), "wall_time_s": round(time.perf_counter() - t0, 1)})
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
