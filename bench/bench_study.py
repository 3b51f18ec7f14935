"""Runs per hour of a study (`pixelswarm study`), one run at a time beside two at a time, and with
``--cluster`` the same through a loopback Dask cluster of as many one-thread workers
(``--scheduler``: a real ``dask scheduler`` and ``dask worker`` processes on 127.0.0.1, Dask's periodic
work slowed as docs/study.md says).

    .venv/bin/python -m bench.bench_study [--spec studies/smoke.toml] [--jobs 1 2] [--cluster] [--repeat N]

Each setting runs the whole study from scratch in a temporary directory, one after the other in this
process; the figures are the study's wall time start to report, the runs per hour that makes, and
the mean wall time of one run (its `pixelswarm run` process, from runs.csv), and the CPU seconds a
run cost (the study process, every run, the cluster's scheduler and workers while the study ran: on a
loaded machine a steadier figure than wall time). With ``--cluster`` and
``--repeat N`` the local study and the cluster's alternate N times (local first, then cluster first,
...: a drift in the machine's load falls on both) and the medians are compared; the results go to
bench/results/study_cluster.md.
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

from sim.processes import stop_processes
from sim.study.cluster import QUIET

from .common import REPO, write_results


def quiet_env() -> dict[str, str]:
    """:data:`sim.study.cluster.QUIET` as the environment variables Dask reads its configuration from."""
    return {"DASK_" + key.upper().replace(".", "__").replace("-", "_"): str(v) for key, v in QUIET.items()}


def run_study(spec: Path, jobs: int, cluster: bool = False) -> tuple[float, float, list[dict[str, str]]]:
    """The study's wall time (s), the CPU seconds it cost (the study process, every run, and the
    cluster's scheduler and workers while it ran), and its runs.csv."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "study"
        command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), "--jobs", str(jobs)]
        processes = _loopback_cluster(Path(tmp), jobs, command) if cluster else []
        try:
            cpu_before, children_before = _cpu(processes), resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            result = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
            wall = time.perf_counter() - start  # not the cluster's stop: it outlives a study
            children = resource.getrusage(resource.RUSAGE_CHILDREN)  # the study process and what it waited for
            cpu = (
                _cpu(processes)
                - cpu_before
                + sum(getattr(children, f) - getattr(children_before, f) for f in ("ru_utime", "ru_stime"))
            )
        finally:
            _stop(processes)
        if result.returncode != 0:
            raise SystemExit(f"study failed (exit {result.returncode}): {result.stderr[-2000:]}")
        with open(out / "runs.csv", newline="") as f:
            return wall, cpu, list(csv.DictReader(f))


def _cpu(processes: list[subprocess.Popen]) -> float:
    """CPU seconds of these processes and of the children they waited for (a worker's runs)."""
    total = 0.0
    for p in processes:
        times = psutil.Process(p.pid).cpu_times()
        total += times.user + times.system + times.children_user + times.children_system
    return total


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
    # Dask's periodic work slowed as docs/study.md tells a cluster's owner (sim.study.cluster.QUIET)
    env = dict(os.environ, **quiet_env())
    quiet = {"cwd": REPO, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
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
    parser.add_argument("--repeat", type=int, default=1, help="with --cluster: alternate local and cluster N times")
    args = parser.parse_args()
    lines = [
        "| where | --jobs / workers | runs | study wall s | runs per hour | mean run wall s | CPU s per run |",
        "|---|---|---|---|---|---|---|",
    ]
    per_hour: dict[tuple[int, bool], list[float]] = {}
    cpu_per_run: dict[tuple[int, bool], list[float]] = {}
    for jobs in args.jobs:
        for k in range(args.repeat if args.cluster else 1):
            order = (False, True) if k % 2 == 0 else (True, False)
            for cluster in order if args.cluster else (False,):
                wall, cpu, rows = run_study(args.spec.resolve(), jobs, cluster)
                per_run = sum(float(r["process_wall_s"]) for r in rows) / len(rows)
                where = "loopback Dask cluster" if cluster else "local"
                per_hour.setdefault((jobs, cluster), []).append(len(rows) / wall * 3600)
                cpu_per_run.setdefault((jobs, cluster), []).append(cpu / len(rows))
                lines.append(
                    f"| {where} | {jobs} | {len(rows)} | {wall:.0f} | {len(rows) / wall * 3600:.0f} | {per_run:.1f} "
                    f"| {cpu / len(rows):.2f} |"
                )
                print(lines[-1], flush=True)
    notes = []
    if args.cluster:
        for jobs in args.jobs:
            local, cluster = (statistics.median(per_hour[jobs, c]) for c in (False, True))
            cpu_local, cpu_cluster = (statistics.median(cpu_per_run[jobs, c]) for c in (False, True))
            notes.append(
                f"- `--jobs {jobs}`, medians: {local:.0f} runs an hour here, {cluster:.0f} through the cluster "
                f"(a run takes {100 * (local / cluster - 1):+.1f} % wall time); {cpu_local:.2f} and "
                f"{cpu_cluster:.2f} CPU s a run ({100 * (cpu_cluster / cpu_local - 1):+.1f} %)."
            )
    spec = args.spec.resolve().relative_to(REPO) if args.spec.resolve().is_relative_to(REPO) else args.spec
    write_results(
        "study_cluster" if args.cluster else "study",
        f"Study throughput: {spec}, runs at once side by side"
        + (", here and on a Dask cluster" if args.cluster else ""),
        f".venv/bin/python -m bench.bench_study --spec {spec} --jobs {' '.join(map(str, args.jobs))}"
        + (f" --cluster --repeat {args.repeat}" if args.cluster else ""),
        [
            *lines,
            "",
            *notes,
            *([""] if notes else []),
            "Every run is a `pixelswarm run --no-video -q` process (distributed: router, world, coordinator "
            "and agent processes); the study's own work (spec check, scheduling, report) is in the study "
            "wall time (not the cluster's start: a cluster serves many studies). On a shared machine the figures "
            "move with the other load.",
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
