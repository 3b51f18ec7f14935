"""Real robots' parts against their emulators: the paper's sequence on emulated e-puck2 robots (the
default), the e-puck2 Wi-Fi backend, the overhead-camera tracker and ROS 2 over rmw_zenoh. One module,
a benchmark per name; each writes bench/results/<name>.md:

    .venv/bin/python -m bench.bench_hardware                  # the paper's sequence, 14 emulated e-puck2
    .venv/bin/python -m bench.bench_hardware epuck2           # the backend's latency and watchdog, 1-50 robots
    .venv/bin/python -m bench.bench_hardware tracker [--frames 100] [--quick]
    .venv/bin/python -m bench.bench_hardware ros2 [--quick]
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from coordinator.scene import load_scene
from hardware.camera import CORNER_REFINEMENT, ArucoTracker, CameraConfig
from hardware.config import load_hardware
from hardware.epuck2 import (
    FIRMWARE_MAX_WHEEL_SPEED,
    Epuck2Backend,
    encode_command,
    make_command,
    metres_per_second,
)
from hardware.ros2 import Ros2Backend, Ros2BackendConfig, Ros2PosesConfig, Ros2PoseSource
from sim.emulators.camera import OverheadCamera, render_frames, wandering_robots
from sim.emulators.mocap import MocapEmulator
from tests.support.outputs import logged
from transport.session import client_of, free_port, loopback_router, open_session

from .common import REPO, parser_for, run_subcommand, write_results

# --- the paper's sequence on emulated e-puck2 robots ------------------------------------------
SEQUENCE_DOC = """The paper's sequence (14 robots) through emulated e-puck2 robots and emulated motion capture.

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


def sequence_main(argv: list[str] | None = None) -> int:
    parser_for("bench.bench_hardware [sequence]", SEQUENCE_DOC).parse_args(argv)
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


# --- the e-puck2 Wi-Fi backend (epuck2) -------------------------------------------------------
EPUCK2_DOC = """e-puck2 Wi-Fi backend against emulated robots: command latency at 10 Hz and the watchdog's stop.

Run from the repository root:

    .venv/bin/python -m bench.bench_hardware epuck2     # prints a table and writes bench/results/epuck2.md

For N emulated robots (`python -m sim.emulators.epuck2` in its own process, on 127.0.0.1), 30 control periods of 0.1 s,
each period's command distinct so the emulator's receive log tells which call it answers. Latency: from
the control loop's call to the emulator receiving the packet. Reference, side by side: a plain client of
the kind the vendor's examples show (one loop sending to each robot in turn and waiting for its answer),
which has no watchdog: when its commands cease the robots keep their last speed.
"""


EPUCK2_PERIOD = 0.1
EPUCK2_PERIODS = 30
COMMAND_TIMEOUT = 0.3
EPUCK2_SIZES = (1, 10, 50)
EPUCK2_COLOUR = (255, 128, 0)


def period_speed(k: int) -> tuple[float, int]:
    """The wheel speed of period k (m/s) and the steps/s it becomes: distinct per period."""
    steps = 100 + k
    return metres_per_second(steps), steps


class EmulatorProcess:
    """`python -m sim.emulators.epuck2` in its own process (as robots are elsewhere); its log is read on exit."""

    def __init__(self, n: int, tmp: Path) -> None:
        self.hardware, self.log_path = tmp / "hw.toml", tmp / "log.json"
        self.hardware.unlink(missing_ok=True)
        args = ["--robots", str(n), "--write-hardware", str(self.hardware), "--log", str(self.log_path)]
        self.proc = subprocess.Popen([sys.executable, "-m", "sim.emulators.epuck2", *args], stdout=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while not self.hardware.exists():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.proc.kill()
                raise RuntimeError("the emulator did not start")
            time.sleep(0.05)

    def finish(self) -> list[list[tuple[float, int, int]]]:
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=60)
        return [[tuple(e) for e in robot["log"]] for robot in json.loads(self.log_path.read_text())["robots"]]


def latencies(logs: list[list[tuple[float, int, int]]], calls: list[float]) -> tuple[list[float], int]:
    found = []
    for log in logs:
        for t, left, _ in log:
            k = left - 100
            if 0 <= k < len(calls):
                found.append(t - calls[k])
    return found, len(logs) * len(calls)


def stopped(logs: list[list[tuple[float, int, int]]]) -> list[float]:
    """For each robot whose last command was a stop: its receive time."""
    return [log[-1][0] for log in logs if log and tuple(log[-1][1:]) == (0, 0)]


def run_backend(n: int, tmp: Path) -> dict:
    emu = EmulatorProcess(n, tmp)
    config = load_hardware(emu.hardware).backend
    config = replace(config, command_timeout=COMMAND_TIMEOUT)
    backend = Epuck2Backend(config)
    backend.start()
    time.sleep(0.5)  # connections made
    ids = list(range(n))
    calls, blocked = [], []
    cpu0, wall0 = time.process_time(), time.monotonic()
    for k in range(EPUCK2_PERIODS):
        speed, _ = period_speed(k)
        calls.append(time.monotonic())
        backend.set_commands(ids, [speed] * n, [-speed] * n, [EPUCK2_COLOUR] * n)
        blocked.append(time.monotonic() - calls[-1])
        time.sleep(max(0.0, calls[-1] + EPUCK2_PERIOD - time.monotonic()))
    cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    time.sleep(COMMAND_TIMEOUT + 2 * EPUCK2_PERIOD)  # commands cease: the watchdog stops the robots
    stats = backend.stats()
    logs = emu.finish()  # before close(): the stops seen are the watchdog's
    backend.close()
    stops = [t - calls[-1] for t in stopped(logs)]
    lat, expected = latencies(logs, calls)
    return {
        "lat": lat,
        "expected": expected,
        "late": sum(s.late_commands for s in stats.values()),
        "blocked": max(blocked),
        "cpu": cpu,
        "stopped": len(stops),
        "stop_after": max(stops) if stops else float("nan"),
    }


def run_sequential(n: int, tmp: Path) -> dict:
    emu = EmulatorProcess(n, tmp)
    socks = [
        socket.create_connection(endpoint, timeout=1.0) for endpoint in load_hardware(emu.hardware).backend.endpoints
    ]
    try:
        calls, blocked = [], []
        cpu0, wall0 = time.process_time(), time.monotonic()
        for k in range(EPUCK2_PERIODS):
            speed, _ = period_speed(k)
            calls.append(time.monotonic())
            for sock in socks:
                sock.sendall(encode_command(make_command(speed, -speed, EPUCK2_COLOUR, FIRMWARE_MAX_WHEEL_SPEED)))
                sock.recv(1)  # the robot's empty answer
            blocked.append(time.monotonic() - calls[-1])
            time.sleep(max(0.0, calls[-1] + EPUCK2_PERIOD - time.monotonic()))
        cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
        time.sleep(COMMAND_TIMEOUT + 2 * EPUCK2_PERIOD)
        logs = emu.finish()
    finally:
        for sock in socks:
            sock.close()
    lat, expected = latencies(logs, calls)
    return {
        "lat": lat,
        "expected": expected,
        "late": 0,
        "blocked": max(blocked),
        "cpu": cpu,
        "stopped": len(stopped(logs)),
        "stop_after": float("nan"),
    }


def epuck2_row(name: str, n: int, r: dict) -> str:
    lat = sorted(r["lat"])
    p95 = lat[min(len(lat) - 1, int(0.95 * len(lat)))]
    return (
        f"| {name} | {n} | {len(lat)}/{r['expected']} | {1e3 * statistics.median(lat):.2f} | {1e3 * p95:.2f} | "
        f"{1e3 * lat[-1]:.2f} | {1e3 * r['blocked']:.2f} | {r['late']} | {100 * r['cpu']:.0f} | {r['stopped']}/{n} | {r['stop_after']:.3f} |"
    )


def epuck2_main(argv: list[str] | None = None) -> int:
    parser_for("bench.bench_hardware epuck2", EPUCK2_DOC).parse_args(argv)
    # the watchdog's stops are expected here, and close() finds the emulator gone once its log is read
    logging.getLogger("hardware.epuck2").setLevel(logging.CRITICAL)
    lines = [
        "| client | N robots | commands received | latency p50 ms | p95 ms | max ms | control loop blocked, max ms | late | CPU % of a core | "
        "stopped after commands ceased | last stop after last call s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for n in EPUCK2_SIZES:
            lines.append(epuck2_row("backend (one asyncio task per robot, watchdog)", n, run_backend(n, Path(tmp))))
            lines.append(epuck2_row("sequential send + wait answer", n, run_sequential(n, Path(tmp))))
            print(lines[-2], lines[-1], sep="\n", flush=True)
    notes = [
        f"Load average {os.getloadavg()[0]:.1f} at the end. Emulator in its own process; CPU is the client's process "
        f"only. {EPUCK2_PERIODS} periods of {EPUCK2_PERIOD} s, command_timeout {COMMAND_TIMEOUT} s.",
        "",
    ]
    write_results(
        "epuck2",
        "e-puck2 Wi-Fi backend against emulated robots",
        ".venv/bin/python -m bench.bench_hardware epuck2",
        notes + lines,
    )
    return 0


# --- the overhead-camera tracker (tracker) ----------------------------------------------------
TRACKER_DOC = """The overhead-camera tracker on one core: frames per second and accuracy on rendered footage.

Rendered 1280x960 frames (sim.emulators.camera: a tilted camera over 2 x 1.5 m of floor, 5 cm
DICT_4X4_50 markers, 14 robots wandering, four reference markers, Gaussian blur and pixel noise) are
tracked by hardware.camera.ArucoTracker with OpenCV's corner refinements none, subpix and contour, and by the ArUco
detection alone (no refinement, no poses) as the reference. All variants see each frame in turn, so
they share the machine's load; cv2.setNumThreads(1) holds each to one core, and speed is read from the
thread's CPU time (a shared machine's wall clock includes waiting for a core). Two conditions: the
emulator's defaults and a harsher camera (more blur, more noise).

    .venv/bin/python -m bench.bench_hardware tracker            # writes bench/results/tracker.md
    .venv/bin/python -m bench.bench_hardware tracker --quick    # a short run, prints only
"""


TRACKER_ROBOTS, TRACKER_FPS, TRACKER_SEED = 14, 10.0, 3
REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
}
CONDITIONS = {
    "defaults (blur 1.0 px, noise 4 grey levels)": OverheadCamera(),
    "harsh (blur 1.5 px, noise 8 grey levels)": OverheadCamera(blur_sigma=1.5, noise_sigma=8.0),
}


@dataclass
class Tally:
    seconds: list[float] = field(default_factory=list)  # wall clock
    cpu: list[float] = field(default_factory=list)  # this thread's CPU time: less swayed by other work
    found: int = 0
    drawn: int = 0
    position: list[float] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)


def tracker_measure(camera: OverheadCamera, frames: int) -> dict[str, Tally]:
    config = CameraConfig.from_table(camera.poses_table(), "bench [poses]")
    truth = wandering_robots(TRACKER_ROBOTS, frames, TRACKER_FPS, TRACKER_SEED)
    images = list(render_frames(camera, truth, TRACKER_SEED))
    detection_only = ArucoTracker(config, cv2.aruco.CORNER_REFINE_NONE)
    trackers = {name: ArucoTracker(config, method) for name, method in REFINEMENTS.items()}
    tallies = {name: Tally() for name in ["detection alone", *trackers]}
    for k, (robots, image) in enumerate(zip(truth, images)):
        start, start_cpu = time.perf_counter(), time.thread_time()
        detection_only.detect(image)
        tallies["detection alone"].seconds.append(time.perf_counter() - start)
        tallies["detection alone"].cpu.append(time.thread_time() - start_cpu)
        for name, tracker in trackers.items():
            start, start_cpu = time.perf_counter(), time.thread_time()
            result = tracker.update(image, k / TRACKER_FPS, k)
            tally = tallies[name]
            tally.seconds.append(time.perf_counter() - start)
            tally.cpu.append(time.thread_time() - start_cpu)
            tally.drawn += len(robots)
            tally.found += len(result.poses)
            for i, pose in result.poses.items():
                x, y, theta = robots[i]
                tally.position.append(math.hypot(pose.x - x, pose.y - y))
                tally.heading.append(abs(math.remainder(pose.theta - theta, 2 * math.pi)))
    return tallies


def tracker_table(tallies: dict[str, Tally]) -> list[str]:
    lines = [
        "| variant | frames/s of CPU (median) | CPU ms per frame (median, p95) | wall ms per frame (median) | found "
        "| position mm (mean, p95, max) | heading deg (mean, p95, max) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, t in tallies.items():
        cpu, wall = np.array(t.cpu) * 1e3, np.array(t.seconds) * 1e3
        label = f"{name} (chosen)" if REFINEMENTS.get(name) == CORNER_REFINEMENT else name
        speed = f"| {label} | {1e3 / np.median(cpu):.1f} | {np.median(cpu):.1f}, {np.percentile(cpu, 95):.1f} | {np.median(wall):.1f} "
        if not t.drawn:
            lines.append(speed + "| - | - | - |")
            continue
        mm, deg = np.array(t.position) * 1e3, np.degrees(t.heading)
        lines.append(
            speed + f"| {100 * t.found / t.drawn:.2f} % | {mm.mean():.2f}, {np.percentile(mm, 95):.2f}, {mm.max():.2f} "
            f"| {deg.mean():.2f}, {np.percentile(deg, 95):.2f}, {deg.max():.2f} |"
        )
    return lines


def tracker_main(argv: list[str] | None = None) -> None:
    parser = parser_for("bench.bench_hardware tracker", TRACKER_DOC)
    parser.add_argument("--frames", type=int, default=100, help="frames per condition (default 100)")
    parser.add_argument("--quick", action="store_true", help="20 frames, print only")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    frames = 20 if args.quick else args.frames
    lines = [
        f"{TRACKER_ROBOTS} robots, {frames} frames of 1280x960 per condition (seed {TRACKER_SEED}), OpenCV {cv2.__version__}, "
        "cv2.setNumThreads(1). Speed from the tracking thread's CPU time per frame (the machine is shared: "
        "wall-clock times include waiting for a core). Found: robot-frames with a pose, of those drawn. "
        "Errors against the rendered truth.",
    ]
    for condition, camera in CONDITIONS.items():
        lines += ["", f"### {condition}", "", *tracker_table(tracker_measure(camera, frames))]
    lines += ["", f"Load average at the end (1, 5, 15 min): {', '.join(f'{x:.1f}' for x in os.getloadavg())}."]
    if args.quick:
        print("\n".join(lines))
        return
    write_results(
        "tracker",
        "Overhead-camera tracker: frames per second on one core, and accuracy",
        f".venv/bin/python -m bench.bench_hardware tracker --frames {frames}",
        lines,
    )


# --- ROS 2 over rmw_zenoh (ros2) --------------------------------------------------------------
ROS2_DOC = """What one control tick costs on the ROS 2 path, against the 0.1 s tick of the paper's 10 Hz loop.

Side by side in one run, through an embedded Zenoh router on loopback:

* `Ros2Backend.set_commands` for N robots with a Twist only, and with a Twist and a ColorRGBA
  (rosbags encodes each message; each is one Zenoh put with rmw_zenoh's attachment);
* `Ros2PoseSource.latest` after one PoseStamped per robot has arrived (rosbags decodes each).

The variants alternate round by round so that both see the same machine load; the median of the
rounds is reported.

    .venv/bin/python -m bench.bench_hardware ros2            # writes bench/results/ros2.md
    .venv/bin/python -m bench.bench_hardware ros2 --quick    # a short smoke run, prints only
"""


ROS2_TICK = 0.1  # s: the paper's 10 Hz control loop
ROS2_ARRIVAL = 0.5  # s allowed for N poses to cross the loopback router before they are read


def time_commands(backend: Ros2Backend, n: int, with_colors: bool) -> float:
    ids = np.arange(n)
    v, w = np.full(n, 0.05), np.full(n, 0.2)
    colors = np.tile([255.0, 128.0, 0.0], (n, 1)) if with_colors else None
    start = time.perf_counter()
    backend.set_commands(ids, v, w, colors)
    return time.perf_counter() - start


def time_poses(source: Ros2PoseSource, mocap: MocapEmulator, n: int) -> float:
    """Time of the one latest() that reads the n poses just published (given time to arrive first)."""
    before = source.stats()["received"]
    mocap.publish_once(0.0)
    time.sleep(ROS2_ARRIVAL)
    start = time.perf_counter()
    source.latest()
    elapsed = time.perf_counter() - start
    if source.stats()["received"] != before + n:
        raise RuntimeError(f"{source.stats()['received'] - before} of {n} poses arrived within {ROS2_ARRIVAL} s")
    return elapsed


def ros2_main(argv: list[str] | None = None) -> None:
    parser = parser_for("bench.bench_hardware ros2", ROS2_DOC)
    parser.add_argument("--quick", action="store_true", help="few rounds, small N, print only")
    args = parser.parse_args(argv)
    sizes, rounds = ((10, 100), 5) if args.quick else ((10, 100, 1000), 30)
    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    router = loopback_router()
    rows = []
    with open_session(router):
        for n in sizes:
            config = Ros2BackendConfig(namespaces=[f"robot{i}" for i in range(n)], watchdog=60.0)
            rows_of_n: dict[str, list[float]] = {"twist": [], "twist+color": [], "poses": []}
            with (
                Ros2Backend(config, client_of(router)) as backend,
                Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as source,
                MocapEmulator(
                    lambda t, n=n: np.zeros((n, 3)), client_of(router), rate=1e-3
                ) as mocap,  # once at start, then by hand
            ):
                deadline = time.monotonic() + 30.0  # the emulator's first publication, at start, all read
                while len(source.latest()) < n or mocap.published < n:
                    if time.monotonic() > deadline:
                        raise RuntimeError("the emulator's first poses did not all arrive")
                    time.sleep(0.05)
                time.sleep(ROS2_ARRIVAL)
                source.latest()
                for _ in range(rounds):
                    rows_of_n["twist"].append(time_commands(backend, n, with_colors=False))
                    rows_of_n["twist+color"].append(time_commands(backend, n, with_colors=True))
                    rows_of_n["poses"].append(time_poses(source, mocap, n))
            medians = {k: statistics.median(v) for k, v in rows_of_n.items()}
            rows.append(
                f"| {n} | {medians['twist'] * 1e3:.2f} | {medians['twist+color'] * 1e3:.2f} | "
                f"{medians['poses'] * 1e3:.2f} | {(medians['twist+color'] + medians['poses']) / ROS2_TICK * 100:.1f}% |"
            )
    lines = [
        f"Median of {rounds} alternating rounds; times in ms per tick for all N robots. "
        f"Load average when the run began: {load:.1f}.",
        "",
        "| N robots | set_commands, Twist | set_commands, Twist + ColorRGBA | latest() of N poses | both, share of a 0.1 s tick |",
        "|---|---|---|---|---|",
        *rows,
    ]
    if args.quick:
        print("\n".join(lines))
    else:
        write_results(
            "ros2", "ROS 2 over rmw_zenoh: the cost of a control tick", "python -m bench.bench_hardware ros2", lines
        )


COMMANDS = {"sequence": sequence_main, "epuck2": epuck2_main, "tracker": tracker_main, "ros2": ros2_main}


if __name__ == "__main__":
    sys.exit(run_subcommand("bench.bench_hardware", COMMANDS, "sequence"))
