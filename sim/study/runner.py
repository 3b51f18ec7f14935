"""`pixelswarm study SPEC.toml`: run a grid of conditions x seeds as `pixelswarm run` processes (docs/study.md);
it resumes by skipping the runs whose directory says `"complete": true`."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from sim.args import refuse_if
from sim.processes import handling_signals
from sim.study.cluster import check_address, clear_run_dir, connect, run_task, unpack
from sim.study.spec import Run, Spec, StudyDir, load_spec, lock_study, run_args, write_text

# `pixelswarm --help` and `pixelswarm study --help`
HELP = "run a grid of conditions x seeds (pixelswarm run each) and write a report"
ABOUT = (
    "Run every condition of a study spec for every seed and write runs.csv, summary.csv, "
    "plots and report.html (docs/study.md). Rerun the same command to resume."
)

STOP_GRACE_S = 30.0  # a child stopped by SIGTERM writes what it recorded; after this it is killed
STDERR_TAIL_CHARS = 2000


# --- Running: up to `jobs` children at once, progress on stderr, Ctrl-C stops the children --------
class Progress:
    """One line per event on stderr: a bar, runs done / failed / total, and the time left at the pace so far."""

    def __init__(self, total: int, jobs: int, done: int):
        self.total, self.jobs, self.done, self.failed = total, jobs, done, 0
        self.walls: list[float] = []

    def line(self, running: int, note: str) -> None:
        finished = self.done + self.failed
        left, width = self.total - finished, 20
        filled = round(width * finished / self.total) if self.total else width
        if not left:
            eta = "finished"
        elif self.walls:
            eta = f"~{_duration(sum(self.walls) / len(self.walls) * left / min(self.jobs, left))} left"
        else:
            eta = "time left: after the first run"
        counts = f"{self.done} done, {self.failed} failed of {self.total}, {running} running"
        print(f"[{'#' * filled}{'-' * (width - filled)}] {counts}, {eta}  {note}", file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    seconds = round(seconds)
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s" if m else f"{s}s"


def execute(spec: Spec, study: StudyDir, jobs: int, scheduler: str | None) -> Progress:
    """Run every run not finished yet on a Dask cluster: the scheduler's at ``scheduler``, or a local
    one of ``jobs`` threads (sim.study.cluster); record each one's outcome as it comes back."""
    from distributed import Event, as_completed

    runs = spec.runs()
    todo = [r for r in runs if study.metrics(r) is None]
    client, closing = connect(scheduler, jobs)
    with closing:
        slots = sum(client.nthreads().values()) or jobs if scheduler else jobs
        progress = Progress(len(runs), max(1, slots), len(runs) - len(todo))
        where = f"on the cluster at {scheduler} ({slots} worker threads)" if scheduler else f"{jobs} at a time"
        print(
            f"study {spec.name}: {len(runs)} runs, {progress.done} already done, {len(todo)} to run, "
            f"{where}, in {study.root}",
            file=sys.stderr,
            flush=True,
        )
        study.logs.mkdir(parents=True, exist_ok=True)
        study.runs.mkdir(parents=True, exist_ok=True)
        stop = Event(f"pixelswarm-study-stop-{os.getpid()}-{time.time_ns()}", client=client)
        shared = scheduler is None  # a local worker writes into the study directory itself
        pending: dict[Any, Run] = {}
        try:
            for run in todo:
                clear_run_dir(study.run_dir(run))  # before running it again
                out = str(study.run_dir(run)) if shared else None
                args = (run.id, run_args(spec, run), out, stop.name, STOP_GRACE_S)
                pending[client.submit(run_task, *args, key=f"run-{run.id}", pure=False)] = run
            for future in as_completed(list(pending)):
                run = pending.pop(future)
                _finish(run, future, study, progress)
                running = min(len(pending), progress.jobs)
                progress.line(running, f"{run.id}: {'done' if study.metrics(run) else 'FAILED'}")
        except KeyboardInterrupt:
            stop.set()  # a queued task starts no run, a running one stops its run (SIGTERM, SIGKILL after the grace)
            _wind_down(pending, study, progress)
            raise
        return progress


def _wind_down(pending: dict[Any, Run], study: StudyDir, progress: Progress) -> None:
    """After the stop: wait the grace for the tasks to end (a queued one at once), and record what the
    stopped runs bring back (a run that finished meanwhile is done); a second Ctrl-C ends the wait."""
    from distributed import as_completed

    with contextlib.suppress(KeyboardInterrupt, Exception):  # also the grace over (a TimeoutError)
        for future in as_completed(list(pending), timeout=STOP_GRACE_S + 15):
            _finish(pending[future], future, study, progress, stopping=True)


def _finish(run: Run, future: Any, study: StudyDir, progress: Progress, stopping: bool = False) -> None:
    """Record a task's outcome: its run done or failed, or ``stopping``, interrupted; a task that started
    no run (the study stopped first) leaves nothing."""
    try:
        result = future.result()
    except Exception as err:  # the task itself failed (not the run): e.g. a worker died too often
        result = {"returncode": None, "process_wall_s": 0.0, "command": [], "log": f"task failed: {err!r}"}
    if result.get("not_started"):
        return
    if result.get("archive"):
        unpack(result["archive"], study.runs)
    write_text(study.logs / f"{run.id}.log", result.get("log", ""))
    wall = float(result.get("process_wall_s", 0.0))
    record = {
        "id": run.id,
        "process_wall_s": wall,
        "returncode": result.get("returncode"),
        "command": result.get("command", []),
        "worker": result.get("worker", ""),
    }
    if study.metrics(run) is not None:
        progress.done += 1
        progress.walls.append(wall)
        record.update(status="done", error="")
    elif stopping:  # marked incomplete by its own stop: run again on resuming, not a failure
        record.update(status="interrupted", error="")
    else:
        progress.failed += 1
        tail = result.get("log", "")[-STDERR_TAIL_CHARS:]
        record.update(status="failed", error=tail.strip() or f"exit code {result.get('returncode')}, no output")
    study.write_record(run, record)


# --- The command ----------------------------------------------------------------------------------
def default_jobs() -> int:
    # a distributed run is several processes (router, world, agents): half the cores each
    return max(1, (os.cpu_count() or 1) // 2)


def add_study_parser(subparsers: Any) -> None:
    p = subparsers.add_parser("study", help=HELP, description=ABOUT)
    p.add_argument("spec", type=Path, help="the study spec (TOML; see studies/ and docs/study.md)")
    p.add_argument("--out", type=Path, help="study directory (default runs/study-<name>); reused to resume")
    p.add_argument(
        "--jobs", "-j", type=int, default=None, help=f"runs at once (default: half the cores, here {default_jobs()})"
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="send the runs to the workers of this Dask scheduler (docs/study.md); default: a local cluster "
        "of --jobs threads on 127.0.0.1",
    )
    p.set_defaults(func=cmd_study)


def cmd_study(args: argparse.Namespace) -> int:
    """The command; a spec, flag or scheduler that cannot be used is a UsageError (one line, exit code 2)."""
    from sim.study.report import write_report  # matplotlib only once runs are done

    refuse_if(args.jobs is not None and args.jobs < 1, f"--jobs must be at least 1, not {args.jobs}")
    if args.scheduler is not None:
        check_address(args.scheduler)
    spec = load_spec(args.spec)
    if args.scheduler is not None:  # reached before anything is written or started
        connect(args.scheduler, 1)[1].close()
    study = StudyDir(args.out or Path("runs") / f"study-{spec.name}")
    refuse_if(study.root.exists() and not study.root.is_dir(), f"--out {study.root} is a file, not a directory")
    study.check_same(spec)
    jobs = args.jobs or default_jobs()
    with lock_study(study.root):
        study.hold(spec)
        stopped_by: list[int] = []  # the first signal's number: the study exits with 128 + it, as `pixelswarm run` does

        def interrupt(signum: int, frame: Any) -> None:
            stopped_by.append(signum)
            raise KeyboardInterrupt

        try:
            with handling_signals(interrupt):
                progress = execute(spec, study, jobs, args.scheduler)
                command = f"pixelswarm study {study.root / 'spec.toml'} --out NEW_DIR --jobs {jobs}"
                report = write_report(spec, study, command)  # each file whole or not at all
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM, also one that came before the runs were queued or after
            done = sum(study.metrics(r) is not None for r in spec.runs())
            first = stopped_by[0] if stopped_by else signal.SIGINT
            print(
                f"pixelswarm study: stopped by {signal.Signals(first).name}; {done} of {len(spec.runs())} runs done "
                "and kept, the stopped ones marked incomplete. Run the same command again to resume.",
                file=sys.stderr,
            )
            return 128 + first
        print(report)
    return 1 if progress.failed else 0
