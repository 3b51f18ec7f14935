"""Runs per hour of a study (`pixelswarm study`), one run at a time beside two at a time.

    .venv/bin/python -m bench.bench_study [--spec studies/smoke.toml] [--jobs 1 2]

Each setting runs the whole study from scratch in a temporary directory, one after the other in this
process; the figures are the study's wall time start to report, the runs per hour that makes, and
the mean wall time of one run (its `pixelswarm run` process, from runs.csv).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .common import REPO, write_results


def run_study(spec: Path, jobs: int) -> tuple[float, list[dict[str, str]]]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "study"
        start = time.perf_counter()
        command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), "--jobs", str(jobs)]
        result = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
        wall = time.perf_counter() - start
        if result.returncode != 0:
            raise SystemExit(f"study failed (exit {result.returncode}): {result.stderr[-2000:]}")
        with open(out / "runs.csv", newline="") as f:
            return wall, list(csv.DictReader(f))


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--spec", type=Path, default=REPO / "studies" / "smoke.toml")
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    lines = ["| --jobs | runs | study wall s | runs per hour | mean run wall s |", "|---|---|---|---|---|"]
    for jobs in args.jobs:
        wall, rows = run_study(args.spec.resolve(), jobs)
        per_run = sum(float(r["process_wall_s"]) for r in rows) / len(rows)
        lines.append(f"| {jobs} | {len(rows)} | {wall:.0f} | {len(rows) / wall * 3600:.0f} | {per_run:.1f} |")
        print(lines[-1], flush=True)
    spec = args.spec.resolve().relative_to(REPO) if args.spec.resolve().is_relative_to(REPO) else args.spec
    write_results(
        "study",
        f"Study throughput: {spec}, runs at once side by side",
        f".venv/bin/python -m bench.bench_study --spec {spec} --jobs {' '.join(map(str, args.jobs))}",
        [
            *lines,
            "",
            "Every run is a `pixelswarm run --no-video -q` process (distributed: router, world, coordinator "
            "and agent processes); the study's own work (spec check, scheduling, report) is in the study "
            "wall time. On a shared machine the figures move with the other load.",
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
