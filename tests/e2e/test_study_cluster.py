"""Studies on a Dask cluster (sim.study.cluster): a real `dask scheduler` and two `dask worker` processes
on 127.0.0.1, free ports, each worker with a directory of the test's; stopped by their ids at the end."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from sim.cli.main import main
from sim.processes import start_session, stop_processes
from tests.conftest import REPO, wait_for
from tests.support.study import GRID, read_csv, study
from transport.session import free_port, listening

pytest.importorskip("distributed")

DASK = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
WORKER = [sys.executable, "-m", "distributed.cli.dask_worker"]
# what a run's wall clock decides, not its seed: left out where two studies are compared
TIMED = {"process_wall_s", "wall_s", "realtime_factor", "stepping_wall_s", "stepping_realtime_factor"}


class Cluster:
    def __init__(self, root: Path, workers: int = 2):
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.logs = root / "dask-logs"
        self.logs.mkdir(parents=True)
        self.env = dict(os.environ, DASK_TEMPORARY_DIRECTORY=str(root))  # Dask's scratch, not /tmp's
        self.scheduler = self._start(
            "scheduler", [*DASK, "--host", "127.0.0.1", "--port", str(self.port), "--no-dashboard"]
        )
        assert wait_for(lambda: listening(self.port), timeout=60), (self.logs / "scheduler.log").read_text()
        self.workers = [self.add_worker(root, f"w{k}") for k in range(workers)]

    def _start(self, name: str, command: list[str]) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "w")  # noqa: SIM115 - closed with the process
        return start_session(command, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env=self.env)

    def add_worker(self, root: Path, name: str) -> subprocess.Popen:
        command = [*WORKER, self.address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny"]
        command += ["--no-dashboard", "--name", name, "--local-directory", str(root / name)]
        return self._start(name, command)

    def wait_workers(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout=30) as client:
            client.wait_for_workers(n, timeout=120)

    def close(self) -> None:
        """The workers, then the scheduler (a worker whose scheduler has gone keeps trying to reach it)."""
        stop_processes(self.workers, 30)
        stop_processes([self.scheduler], 30)


@pytest.fixture
def cluster(tmp_path):
    c = Cluster(tmp_path)
    try:
        c.wait_workers(2)
        yield c
    finally:
        c.close()


def _comparable(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k not in TIMED} for row in read_csv(path)]


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.xdist_group("study-grid")
def test_a_study_through_a_dask_cluster_is_the_local_study(grid, cluster, tmp_path):
    out = tmp_path / "out"
    result = study(grid / "grid.toml", out, "--scheduler", cluster.address, timeout=540)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"on the cluster at {cluster.address} (2 worker threads)" in result.stderr
    assert _comparable(out / "runs.csv") == _comparable(grid / "out" / "runs.csv")  # reproducible runs
    workers = {json.loads(p.read_text())["worker"] for p in (out / "records").glob("*.json")}
    assert len(workers) == 2  # both workers ran some
    assert (out / "report.html").is_file()


# 4 distributed lock-step runs (a run is a launcher, a world, a coordinator and agent hosts): the
# killed worker's run must take all of its processes with it
KILLED_SPEC = GRID.replace('engine = "central"', 'engine = "distributed"\nclock = "lockstep"\nagents_per_process = 2')
KILLED_SPEC = KILLED_SPEC.replace("robots = [2, 4]", "robots = [4]")


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_worker_killed_mid_study_leaves_every_run_done_once(cluster, tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(KILLED_SPEC)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), "--scheduler", cluster.address]
    runner = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    victim = psutil.Process(cluster.workers[0].pid)
    try:
        # a run under way on the first worker, with its processes beyond the launcher started
        assert wait_for(lambda: _runs_under(victim) and len(_tree(victim)) >= 3, timeout=180)
        killed_runs = _tree(victim)
        victim.send_signal(signal.SIGKILL)
        stdout, stderr = runner.communicate(timeout=480)
    finally:
        if runner.poll() is None:
            runner.kill()
            runner.wait()
    assert runner.returncode == 0, stderr[-3000:]
    rows = read_csv(out / "runs.csv")
    assert sorted(r["id"] for r in rows) == sorted({r["id"] for r in rows}) and len(rows) == 4
    assert [r["status"] for r in rows] == ["done"] * 4
    assert stderr.count(": done") == 4  # each run reported once
    records = [json.loads(p.read_text()) for p in (out / "records").glob("*.json")]
    assert len(records) == 4 and all(r["status"] == "done" for r in records)
    deadline = time.monotonic() + 60  # the killed worker's run was told (its parent died) and stopped
    while any(map(_alive, killed_runs)):  # the run and every process of it
        assert time.monotonic() < deadline, f"a process of the killed worker's run outlived it: {killed_runs}"
        time.sleep(0.5)
    with open(out / "runs.csv", newline="") as f:
        assert len(list(csv.reader(f))) == 5


def _alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _tree(worker: psutil.Process) -> list[psutil.Process]:
    """Every process under the worker: its runs and all their processes."""
    try:
        return worker.children(recursive=True)
    except psutil.Error:
        return []


def _runs_under(worker: psutil.Process) -> list[psutil.Process]:
    try:
        return [p for p in worker.children(recursive=True) if "sim.cli" in " ".join(p.cmdline())]
    except psutil.Error:
        return []


def test_a_worker_process_finds_this_checkouts_code_first():
    """A worker starts a run's processes with this installation's code ahead on PYTHONPATH."""
    from sim.study.cluster import _child_env

    first = _child_env()["PYTHONPATH"].split(os.pathsep)[0]
    assert Path(first) == REPO


def test_a_bad_scheduler_address_is_one_line_exit_2_and_starts_nothing(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_text(GRID)
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    assert main(["study", str(spec), "--out", str(tmp_path / "out"), "--scheduler", "banana"]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "--scheduler must be tcp://HOST:PORT, not 'banana'" in err
    assert not (tmp_path / "out").exists()
    assert {p.pid for p in psutil.Process().children(recursive=True)} <= before  # no run, no local cluster


def test_a_study_directory_that_cannot_be_made_is_one_line_exit_2(tmp_path, capsys):
    spec, blocker = tmp_path / "spec.toml", tmp_path / "a-file"
    spec.write_text(GRID)
    blocker.write_text("")
    assert main(["study", str(spec), "--out", str(blocker / "out")]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "cannot make the study directory" in err and "Traceback" not in err


@pytest.mark.slow
def test_a_scheduler_that_does_not_answer_is_one_line_exit_2_and_starts_nothing(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(GRID)
    _refused(spec, tmp_path / "out", f"tcp://127.0.0.1:{free_port()}", "cannot reach the Dask scheduler")


def _refused(spec: Path, out: Path, address: str, says: str) -> None:
    result = study(spec, out, "--scheduler", address, timeout=60)
    assert result.returncode == 2 and says in result.stderr, result.stderr
    assert result.stderr.strip().count("\n") == 0 and "Traceback" not in result.stderr
    assert not out.exists()
