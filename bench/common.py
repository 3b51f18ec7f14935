"""Helpers for benchmarks: run the real command, sample its processes, write a results table."""
from __future__ import annotations

import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "bench" / "results"


def machine() -> str:
    return f"{platform.machine()}, {psutil.cpu_count()} cores, Python {platform.python_version()}"


def run_and_sample(args: list[str], period: float = 0.5) -> tuple[dict, list[dict]]:
    """Run `pixelswarm run ...` and sample every agent process's CPU and memory while it runs."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"],
                                cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        samples: list[dict] = []
        tracked: dict[int, psutil.Process] = {}
        while proc.poll() is None:
            for child in psutil.Process(proc.pid).children(recursive=True):
                try:
                    if "agent" in child.cmdline() and child.pid not in tracked:
                        child.cpu_percent()  # start the CPU counter
                        tracked[child.pid] = child
                except psutil.Error:
                    pass
            time.sleep(period)
            for pid, p in list(tracked.items()):
                try:
                    mem = p.memory_full_info()
                    samples.append({"pid": pid, "cpu": p.cpu_percent(), "rss": mem.rss, "uss": mem.uss,
                                    "pss": getattr(mem, "pss", mem.uss)})
                except psutil.Error:
                    tracked.pop(pid)
        stdout, stderr = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(f"run failed: {stderr[-2000:]}")
        return json.loads((out / "metrics.json").read_text()), samples


def write_results(name: str, title: str, command: str, lines: list[str]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.md"
    text = [f"## {title}", "", f"Command: `{command}`", f"Machine: {machine()}; "
            f"measured {time.strftime('%Y-%m-%d', time.gmtime())}.", "", *lines, ""]
    path.write_text("\n".join(text))
    print("\n".join(text))
    return path


def run_cli_scene(args: list[str]) -> tuple[dict, dict, float] | None:
    """`pixelswarm run ARGS --out TMP --no-video -q` in a child process: (metrics, trajectory
    arrays, wall seconds), or None after printing the run's error output."""
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        start = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"],
                              cwd=REPO, capture_output=True, text=True)
        wall = time.monotonic() - start
        if proc.returncode != 0:
            print(proc.stderr[-2000:], file=sys.stderr)
            return None
        return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz")), wall
