"""Runs per hour of a study (`pixelswarm study`), one run at a time beside two at a time, and with
``--cluster`` the same through a loopback Dask cluster of as many one-thread workers
(``--scheduler``: a real ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1).

    .venv/bin/python -m bench.bench_study [--spec studies/smoke.toml] [--jobs 1 2] [--cluster]

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

from sim.processes import stop_processes

from .common import REPO, write_results


def run_study(spec: Path, jobs: int, cluster: bool = False) -> tuple[float, list[dict[str, str]]]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "study"
        command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), "--jobs", str(jobs)]
        processes = _loopback_cluster(Path(tmp), jobs, command) if cluster else []
        start = time.perf_counter()
        try:
            result = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
        finally:
            _stop(processes)
        wall = time.perf_counter() - start
        if result.returncode != 0:
            raise SystemExit(f"study failed (exit {result.returncode}): {result.stderr[-2000:]}")
        with open(out / "runs.csv", newline="") as f:
            return wall, list(csv.DictReader(f))


def _stop(processes: list[subprocess.Popen]) -> None:
    """The workers (all but the first), then the scheduler: a worker whose scheduler is gone keeps
    trying to reach it instead of closing."""
    stop_processes(processes[1:], 30)
    stop_processes(processes[:1], 30)


def _loopback_cluster(root: Path, workers: int, command: list[str]) -> list[subprocess.Popen]:
    """A scheduler and ``workers`` one-thread workers on 127.0.0.1; ``command`` gets --scheduler."""
    from distributed import Client

    from transport.session import free_port

    address = f"tcp://127.0.0.1:{free_port()}"
    quiet = {"cwd": REPO, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1"]
    processes = [subprocess.Popen([*scheduler, "--port", address.rsplit(":", 1)[1], "--no-dashboard"], **quiet)]
    worker = [sys.executable, "-m", "distributed.cli.dask_worker", address, "--host", "127.0.0.1", "--nthreads", "1"]
    for k in range(workers):
        extra = ["--no-nanny", "--no-dashboard", "--local-directory", str(root / f"w{k}")]
        processes.append(subprocess.Popen([*worker, *extra], **quiet))
    deadline = time.monotonic() + 60
    while True:
        try:
            with Client(address, timeout=5) as client:
                client.wait_for_workers(workers, timeout=60)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
    command += ["--scheduler", address]
    return processes


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--spec", type=Path, default=REPO / "studies" / "smoke.toml")
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--cluster", action="store_true", help="also through a loopback Dask cluster, side by side")
    args = parser.parse_args()
    lines = [
        "| where | --jobs / workers | runs | study wall s | runs per hour | mean run wall s |",
        "|---|---|---|---|---|---|",
    ]
    for jobs in args.jobs:
        for cluster in (False, True) if args.cluster else (False,):
            wall, rows = run_study(args.spec.resolve(), jobs, cluster)
            per_run = sum(float(r["process_wall_s"]) for r in rows) / len(rows)
            where = "loopback Dask cluster" if cluster else "local"
            lines.append(
                f"| {where} | {jobs} | {len(rows)} | {wall:.0f} | {len(rows) / wall * 3600:.0f} | {per_run:.1f} |"
            )
            print(lines[-1], flush=True)
    spec = args.spec.resolve().relative_to(REPO) if args.spec.resolve().is_relative_to(REPO) else args.spec
    write_results(
        "study",
        f"Study throughput: {spec}, runs at once side by side",
        f".venv/bin/python -m bench.bench_study --spec {spec} --jobs {' '.join(map(str, args.jobs))}"
        + (" --cluster" if args.cluster else ""),
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
