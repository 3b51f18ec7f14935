"""Shared helpers: run the real `pixelswarm` command, find and reap the processes it starts."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from hypothesis import HealthCheck, settings

# Property tests are seeded (same examples every run) and never fail for being slow on a loaded
# 2-core machine: a health check on generation time is not something a user relies on.
settings.register_profile(
    "pixelswarm", derandomize=True, database=None, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("pixelswarm")

REPO = Path(__file__).resolve().parent.parent


def pixelswarm_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "sim.cli", *args]


def run_pixelswarm(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run(pixelswarm_cmd(*args), capture_output=True, text=True, timeout=timeout, cwd=REPO)


def run_scene(tmp_path: Path, scene: str, *extra: str, name: str = "run", timeout: float = 600) -> tuple[dict, dict]:
    """`pixelswarm run` of a shipped scene, a scene file or inline scene TOML, without video; returns
    metrics.json and trajectory.npz."""
    if scene.lstrip().startswith(("robots", "name", "[", "seed")):
        path = tmp_path / f"{name}.toml"
        path.write_text(scene)
        scene = str(path)
    out = tmp_path / name
    result = run_pixelswarm("run", scene, "--out", str(out), "--no-video", "-q", *extra, timeout=timeout)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))


def start_run(spawned: list, scene: Path | str, out: Path, *extra: str) -> subprocess.Popen:
    """`pixelswarm run` of a scene in the background, without video; ``spawned`` reaps it."""
    proc = subprocess.Popen(
        pixelswarm_cmd("run", str(scene), "--out", str(out), "--no-video", "-q", *extra),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(proc)
    return proc


def descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def agent_processes(pid: int) -> list[psutil.Process]:
    out = []
    for p in descendants(pid):
        try:
            cmd = p.cmdline()
        except psutil.Error:
            continue
        if "-m" in cmd and "agent" in cmd:
            out.append(p)
    return out


def wait_for(predicate, timeout: float, interval: float = 0.1):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    return predicate()


def reap(pids: list[int]) -> list[int]:
    """Kill whatever of these (our own children) is still alive; return the ones that were."""
    alive = []
    for pid in pids:
        try:
            p = psutil.Process(pid)
            if p.status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
                p.kill()
        except psutil.NoSuchProcess:
            pass
    return alive


@pytest.fixture
def spawned():
    """Processes a test starts; any left at the end are killed (and the test fails on its own checks)."""
    procs: list[subprocess.Popen] = []
    yield procs
    for p in procs:
        for child in descendants(p.pid):
            try:
                child.kill()
            except psutil.Error:
                pass
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
