"""Faults injected mid-show, each with its safe behaviour and recovery (docs/faults.md): real
`pixelswarm run` processes over zenoh on loopback, zero contacts in every run."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import numpy as np
import psutil
import pytest

from sim.mcaplog import read_mcap
from sim.ticklog import TICKS_FILE, read_ticks

from .conftest import REPO, descendants, pixelswarm_cmd, reap, wait_for

DISK = """
name = "faults"
robots = {robots}
seed = 5
clock = "{clock}"
[layout]
kind = "grid"
spacing = 0.2
[[steps]]
shape = "disk"
hold = {hold}
[end]
converge_hold = {converge_hold}
{events}
"""

TOLERANCE = 0.01  # m: the show completes when every robot is this close to its goal at the end


def write_disk(tmp_path: Path, robots: int = 10, clock: str = "lockstep", hold: float = 30.0, **kw: object) -> Path:
    path = tmp_path / "faults.toml"
    text = DISK.format(
        robots=robots, clock=clock, hold=hold, converge_hold=kw.get("converge_hold", 100.0), events=kw.get("events", "")
    )
    path.write_text(text)
    return path


def start(spawned: list, scene: Path, out: Path, *extra: str) -> subprocess.Popen:
    proc = subprocess.Popen(
        pixelswarm_cmd("run", str(scene), "--out", str(out), "--no-video", "-q", *extra),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(proc)
    return proc


def ticks_so_far(out: Path) -> int:
    path = Path(str(out) + ".partial") / TICKS_FILE
    try:
        return len(read_ticks(path)["t"])
    except (OSError, ValueError):
        return 0


def alive(pids: list[int]) -> list[int]:
    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.mark.slow
def test_sigkill_of_the_launcher_leaves_no_process_and_a_readable_partial_run(tmp_path, spawned):
    scene = write_disk(tmp_path, hold=120.0)
    out = tmp_path / "run"
    proc = start(spawned, scene, out)
    assert wait_for(lambda: ticks_so_far(out) >= 30, timeout=120), proc.stderr.read() if proc.poll() else ""
    everyone = [p.pid for p in descendants(proc.pid)]
    assert len(everyone) >= 12  # coordinator, world, 10 agents
    partial = Path(str(out) + ".partial")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    seen = read_ticks(partial / TICKS_FILE)["t"]  # the launcher is gone: nothing is appended any more
    # every process it started goes too (they watch their parent)
    assert wait_for(lambda: not alive(everyone), timeout=15), alive(everyone)
    assert not reap(everyone)
    assert not out.exists()  # never committed: the directory's name says it is incomplete
    # the trajectory holds every tick up to the kill, one after another
    ticks = read_ticks(partial / TICKS_FILE)
    assert len(ticks["t"]) == len(seen) >= 30
    np.testing.assert_allclose(np.diff(ticks["t"]), 0.1, atol=1e-9)
    assert ticks["pose"].shape == (len(seen), 10, 3) and np.isfinite(ticks["pose"]).all()
    # the MCAP log, never closed, is read by mcap's reader up to its last flushed chunk (once a second)
    log = read_mcap(partial / "log.mcap", topics=["/sim/truth"])
    stamps = [m["stamp"] for m in log["/sim/truth"]]
    assert len(stamps) >= 10 and stamps == sorted(stamps)
    assert stamps[-1] <= ticks["t"][-1] + 1e-9
    assert json.dumps(log["/sim/truth"][0])  # decoded messages
