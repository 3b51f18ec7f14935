"""One row of agent figures for comparing two versions of the code on one machine: run it from each
version's worktree in turn (alternating), and it prints one line of JSON.

    cd WORKTREE && .venv/bin/python -m bench.pair_runtime --robots 50 --duration 15
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from .common import REPO, run_and_sample


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pair_runtime")
    parser.add_argument("--robots", type=int, default=50)
    parser.add_argument("--duration", type=float, default=15.0, help="s of display")
    args = parser.parse_args()
    if args.robots < 1 or args.duration <= 0:
        print("pair_runtime: error: --robots must be >= 1 and --duration positive", file=sys.stderr)
        return 2
    load = os.getloadavg()[0]
    run = ["circle", "--robots", str(args.robots), "--clock", "realtime", "--duration", str(args.duration)]
    m, samples = run_and_sample(run + ["--seed", "3"], agents=args.robots)
    alive = [s for s in samples if s["rss"]]  # memory readings (an exiting process reports none)
    ticks = round(args.duration / 0.1) * args.robots
    row = {
        "repo": str(REPO),
        "robots": args.robots,
        "load": round(load, 1),
        "rtf": round(m["stepping_realtime_factor"] or 0.0, 2),
        "missed": m["missed_ticks"],
        "missed_share": round(m["missed_ticks"] / ticks, 3),
        "contacts": m["contacts"],
        "min_clearance_m": m["min_clearance_m"],
        "cpu": float(np.median([s["cpu"] for s in samples if s["cpu"] > 0] or [0])),
        "rss_mb": round(float(np.median([s["rss"] for s in alive])) / 2**20, 1),
        "uss_mb": round(float(np.median([s["uss"] for s in alive])) / 2**20, 1),
        "start_and_stop_s": round(m["wall_s"] - m["stepping_wall_s"], 1),
    }
    print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
