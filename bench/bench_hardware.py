"""The paper's sequence (14 robots) through emulated e-puck2 robots and emulated motion capture.

Run from the repository root (a few minutes: the sequence holds each of its six images 30 s):

    .venv/bin/python -m bench.bench_hardware    # prints a table and writes bench/results/hardware.md

Two real processes on 127.0.0.1 with free ports, as a user runs them: the lab
(`python -m sim.emulators.lab --scene paper-sequence`, embedding the router) and
`pixelswarm run paper-sequence --hardware FILE` joining it. Everything measured on the robots' side comes
from the lab's log (the emulated bodies' TRUE poses and the commands each robot received); the run's
metrics.json gives its own counts (late commands, missed ticks). The end of each image's hold is mapped
from the run's tick (the recorder's log.mcap stamps each tick's Truth with the wall time it arrived) to
the lab's clock, both read on this machine.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from coordinator.scene import load_scene
from sim.mcaplog import logged
from transport.session import free_port

from .common import REPO, write_results

SCENE = "paper-sequence"
TOLERANCE = 0.01  # m: an image is formed when every robot is this close to its goal (true pose)
RATE = 10.0  # Hz: the control rate the commands should reach the robots at
LOAD_EVERY = 2.0  # s: how often the load average is sampled during the run
START_TIMEOUT = 120.0  # s: the lab writes its hardware file
RUN_TIMEOUT = 900.0  # s: the whole run, start-up included


def start_lab(tmp: Path, endpoint: str) -> tuple[subprocess.Popen, Path, Path]:
    hw, log = tmp / "hw.toml", tmp / "lab.json"
    args = ["--scene", SCENE, "-m", "router", "-l", endpoint, "--write-hardware", str(hw), "--log", str(log)]
    lab = subprocess.Popen([sys.executable, "-m", "sim.emulators.lab", *args], cwd=REPO, stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + START_TIMEOUT
    while not hw.exists():
        if lab.poll() is not None or time.monotonic() > deadline:
            lab.kill()
            lab.wait()
            raise RuntimeError("the lab did not start")
        time.sleep(0.1)
    return lab, hw, log


def run_scene(tmp: Path, hw: Path, endpoint: str) -> tuple[Path, list[float], float]:
    """`pixelswarm run` on the lab: (run directory, load averages sampled meanwhile, wall-minus-monotonic)."""
    out = tmp / "run"
    cmd = ["run", SCENE, "--hardware", str(hw), "-e", endpoint, "--out", str(out), "--no-video", "-q"]
    run = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", *cmd], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    offset = time.time() - time.monotonic()  # both clocks are the machine's: maps the run's wall times
    loads, deadline = [], time.monotonic() + RUN_TIMEOUT
    try:
        while run.poll() is None and time.monotonic() < deadline:
            loads.append(os.getloadavg()[0])
            time.sleep(LOAD_EVERY)
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)  # the run stops every robot on its way out
        _, err = run.communicate(timeout=120)
    if run.returncode != 0:
        raise RuntimeError(f"the run failed: {err.strip()[-2000:]}")
    return out, loads, offset


def truth_walls(run: Path) -> dict[float, float]:
    """Each tick's time in the run (s) -> the wall time its Truth reached the recorder (s)."""
    walls: dict[float, float] = {}
    for log_time, _, truth in logged(run / "log.mcap", {"/sim/truth"}):
        walls.setdefault(float(truth["stamp"]), log_time * 1e-9)
    return walls


def images(run: Path, lab: dict, offset: float) -> list[dict]:
    """Per image: the largest distance of a robot from its goal at the end of its hold, by TRUE pose
    (the last image: where the robots stand when the run has ended), and by the tracked pose the run saw."""
    scene = load_scene(SCENE)
    traj = np.load(run / "trajectory.npz")
    t, goal, tracked = traj["t"], traj["goal"], traj["pose"]
    walls = truth_walls(run)
    lab_t = np.asarray(lab["trajectory"]["t"]) + lab["started"]  # time.monotonic()
    lab_pose = np.asarray(lab["trajectory"]["pose"])
    rows = []
    for k, step in enumerate(scene.steps):
        last_image = k == len(scene.steps) - 1
        last = len(t) - 1 if last_image else int(np.searchsorted(t, scene.step_starts[k + 1] - 1e-9)) - 1
        if last_image:
            true_xy = np.array([robot["pose"][:2] for robot in lab["robots"]])
        else:
            when = walls[float(t[last])] - offset
            true_xy = lab_pose[min(int(np.searchsorted(lab_t, when)), len(lab_t) - 1), :, :2]
        error = np.hypot(*(true_xy - goal[last]).T)
        seen = np.hypot(*(tracked[last, :, :2] - goal[last]).T)
        rows.append(
            {
                "image": step.name,
                "t_end": float(t[last]),
                "formed": bool(np.all(error <= TOLERANCE)),
                "max_error": float(np.max(error)),
                "max_error_tracked": float(np.max(seen)),
            }
        )
    return rows


def command_rates(lab: dict, metrics: dict, walls: dict[float, float], offset: float) -> list[dict]:
    """Per robot, between the run's first and last tick: commands received per second, the longest gap
    between two, and the run's late commands (its own and the backend's) as shares of those sent."""
    first, last = min(walls.values()) - offset, max(walls.values()) - offset
    rows = []
    for robot, stats in zip(lab["robots"], metrics["hardware"]["robots"], strict=True):
        times = np.array([c[0] for c in robot["log"]], float)
        times = times[(times >= first) & (times <= last)]
        rows.append(
            {
                "rate": len(times) / (last - first),
                "max_gap": float(np.max(np.diff(times))) if len(times) > 1 else float("inf"),
                "late": stats["late_commands"] / max(1, stats["commands_sent"]),
                "backend_late": stats["backend_late_commands"] / max(1, stats["packets_sent"]),
            }
        )
    return rows


def report(
    metrics: dict, lab: dict, formed: list[dict], rates: list[dict], loads: list[float], ticks: int
) -> list[str]:
    robots = len(lab["robots"])
    late = sum(r["late_commands"] for r in metrics["hardware"]["robots"])
    sent = sum(r["commands_sent"] for r in metrics["hardware"]["robots"])
    backend_late = sum(r["backend_late_commands"] for r in metrics["hardware"]["robots"])
    packets = sum(r["packets_sent"] for r in metrics["hardware"]["robots"])
    hz = [r["rate"] for r in rates]
    lines = [
        f"{robots} emulated e-puck2 robots, motion capture at 50 Hz over rmw_zenoh, control at {RATE:g} Hz; "
        f"the run ended: {metrics['end_reason']}. Load average (1 min) during the run: "
        f"min {min(loads):.1f}, mean {statistics.fmean(loads):.1f}, max {max(loads):.1f} (2 cores, shared).",
        "",
        f"| image | end of its hold, s | formed (every robot within {100 * TOLERANCE:g} cm, true pose) | "
        "largest error, true pose mm | largest error, tracked pose mm |",
        "|---|---|---|---|---|",
    ]
    for row in formed:
        lines.append(
            f"| {row['image']} | {row['t_end']:.1f} | {'yes' if row['formed'] else 'NO'} | "
            f"{1e3 * row['max_error']:.1f} | {1e3 * row['max_error_tracked']:.1f} |"
        )
    lines += [
        "",
        "| measure | value |",
        "|---|---|",
        f"| contacts between the emulated bodies (true poses, 50 Hz) | {len(lab['contacts'])} |",
        f"| commands received per robot, Hz (min / median / max) | {min(hz):.2f} / {statistics.median(hz):.2f} / "
        f"{max(hz):.2f} |",
        f"| longest gap between two commands to a robot, s | {max(r['max_gap'] for r in rates):.3f} |",
        f"| late commands (run: for a tick already over or superseded) | {late} of {sent} "
        f"({100 * late / max(1, sent):.2f} %; worst robot {100 * max(r['late'] for r in rates):.2f} %) |",
        f"| late commands (backend: replaced before they could leave) | {backend_late} of {packets} "
        f"({100 * backend_late / max(1, packets):.2f} %) |",
        f"| missed ticks (a live robot without a command for its tick) | {metrics['missed_ticks']} of "
        f"{ticks * robots} robot-ticks |",
        f"| watchdog stops sent by the run | {sum(r['watchdog_stops'] for r in metrics['hardware']['robots'])} |",
        f"| robots not stopped at the end | {len(metrics['hardware']['not_stopped_at_end'])} |",
    ]
    return lines


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        lab, hw, log = start_lab(tmp, endpoint)
        try:
            run, loads, offset = run_scene(tmp, hw, endpoint)
        finally:
            lab.send_signal(signal.SIGTERM)  # the lab writes its log on exit
            lab.wait(timeout=120)
        lab_log = json.loads(log.read_text())
        metrics = json.loads((run / "metrics.json").read_text())
        formed = images(run, lab_log, offset)
        rates = command_rates(lab_log, metrics, truth_walls(run), offset)
        ticks = len(np.load(run / "trajectory.npz")["t"])
    lines = report(metrics, lab_log, formed, rates, loads, ticks)
    write_results(
        "hardware", "The paper's sequence on emulated e-puck2 robots", ".venv/bin/python -m bench.bench_hardware", lines
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
