"""A study's runs on a Dask cluster (this machine's, in-process, or one with workers elsewhere), a task a run
(:func:`run_task`): a dead worker's tasks go to another; a cluster-wide event stops every run on Ctrl-C or SIGTERM."""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

from sim.args import UsageError
from sim.processes import start_session

CONNECT_TIMEOUT_S = 10
STOP_POLL_S = 0.5
_PR_SET_PDEATHSIG = 1
ADDRESS = re.compile(r"^(tcp|tls)://[^\s/:]+:\d{1,5}$")


# Dask's own periodic work, slowed for tasks that only wait on a subprocess: its CPU is the runs' on a small
# machine. docs/study.md gives these as environment variables for `dask scheduler` and `dask worker`.
QUIET = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
}


def check_address(address: str) -> None:
    if not ADDRESS.match(address):
        raise UsageError(f"--scheduler must be tcp://HOST:PORT, not {address!r} (a Dask scheduler's address)")


def connect(address: str | None, jobs: int) -> tuple[Any, contextlib.ExitStack]:
    """A client of the scheduler at ``address``, or of a local cluster of ``jobs`` worker threads on
    127.0.0.1; closing the stack returned second closes the client, then the cluster and its scratch folder."""
    import dask  # a dependency (pyproject.toml), imported only when a study runs: it takes a while
    from distributed import Client, LocalCluster

    closing = contextlib.ExitStack()
    scheduler: Any = address
    if address is None:
        # in this process, over Dask's in-process transport: no port is opened at all; the worker's
        # scratch folder is ours, removed at the end (Dask's default outlives the study in /tmp)
        scratch = closing.enter_context(tempfile.TemporaryDirectory(prefix="pixelswarm-study-"))
        with dask.config.set({**QUIET, "temporary-directory": scratch}):  # read as the scheduler and worker are made
            scheduler = LocalCluster(n_workers=1, threads_per_worker=jobs, processes=False, dashboard_address=None)
        closing.callback(scheduler.close)
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as err:  # a scheduler elsewhere that does not answer
        closing.close()
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise UsageError(f"cannot reach the Dask scheduler at {address}: {first}") from None
    closing.callback(client.close)
    return client, closing


def _die_with_parent() -> None:
    """In the run's process: SIGTERM when the worker that started it dies (Linux), so a killed
    worker leaves no run behind; the run stops its own processes on SIGTERM."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def _child_env() -> dict[str, str]:
    root = str(Path(__file__).resolve().parents[2])  # the folder holding this installation's sim/
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
    return env


def _stopped(event_name: str) -> bool:
    from distributed import Event

    try:
        return bool(Event(event_name).is_set())
    except Exception:  # the scheduler gone: the study is gone, stop
        return True


def _stop(process: subprocess.Popen, grace: float) -> None:
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(grace)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)  # the session it leads, made here
        process.wait()


def clear_run_dir(final: Path) -> None:
    """Remove what an interrupted or killed attempt of a run left (its final or .partial directory)."""
    for leftover in (final, final.with_name(final.name + ".partial")):
        if leftover.exists():
            shutil.rmtree(leftover)


def run_task(run_id: str, args: list[str], out: str | None, stop_event: str, grace: float) -> dict[str, Any]:
    """One run on this worker: ``pixelswarm run ARGS --out DIR``; ``out`` None: into a directory of the
    worker's, sent back as ``archive`` (tar of the run directory, under its final or ``.partial`` name).
    A task the study's stop reaches before its run starts returns ``not_started``: a stopped study starts nothing."""
    from distributed import get_worker

    if _stopped(stop_event):
        return {"not_started": True}
    worker = get_worker()  # a task runs on a worker: the run's scratch folder goes in the worker's
    base = Path(worker.local_directory)
    scratch = None if out is not None else Path(tempfile.mkdtemp(prefix=f"run-{run_id}-", dir=base))
    target = Path(out) if out is not None else scratch / run_id  # type: ignore[operator]  # scratch is set where out is not
    clear_run_dir(target)  # an earlier attempt's, on a worker that died
    command = [sys.executable, "-m", "sim.cli", "run", *args, "--out", str(target)]
    started = time.monotonic()
    log = tempfile.TemporaryFile(dir=base)
    try:
        process = start_session(
            command, stdout=log, stderr=subprocess.STDOUT, env=_child_env(), preexec_fn=_die_with_parent
        )
        while process.poll() is None:
            try:
                process.wait(STOP_POLL_S)
            except subprocess.TimeoutExpired:
                if _stopped(stop_event):
                    _stop(process, grace)
        log.seek(0)
        output = log.read().decode(errors="replace")
        return {
            "returncode": process.returncode,
            "process_wall_s": time.monotonic() - started,
            "command": command,
            "log": output,
            "worker": str(worker.address),
            "archive": None if scratch is None else _archive(scratch),
        }
    finally:
        log.close()
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def _archive(folder: Path) -> bytes | None:
    """The run directory in ``folder`` (final or .partial), as an uncompressed tar."""
    entries = [p for p in folder.iterdir() if p.is_dir()]
    if not entries:
        return None
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for entry in entries:
            tar.add(entry, arcname=entry.name)
    return buffer.getvalue()


def unpack(archive: bytes, runs: Path) -> None:
    """A run directory sent back by a worker, into the study's ``runs/`` (under a temporary name,
    then renamed: a reader never sees half a run)."""
    staging = Path(tempfile.mkdtemp(prefix=".incoming-", dir=runs))
    try:
        with tarfile.open(fileobj=io.BytesIO(archive), mode="r") as tar:
            tar.extractall(staging, filter="data")
        for entry in staging.iterdir():
            destination = runs / entry.name
            if destination.exists():
                shutil.rmtree(destination)
            os.replace(entry, destination)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
