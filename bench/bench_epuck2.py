"""e-puck2 Wi-Fi backend against emulated robots: command latency at 10 Hz and the watchdog's stop.

Run from the repository root:

    .venv/bin/python -m bench.bench_epuck2     # prints a table and writes bench/results/epuck2.md

For N emulated robots (`python -m sim.emulators.epuck2` in its own process, on 127.0.0.1), 30 control periods of 0.1 s,
each period's command distinct so the emulator's receive log tells which call it answers. Latency: from
the control loop's call to the emulator receiving the packet. Reference, side by side: a plain client of
the kind the vendor's examples show (one loop sending to each robot in turn and waiting for its answer),
which has no watchdog: when its commands cease the robots keep their last speed.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from hardware.config import load_hardware
from hardware.epuck2 import (
    FIRMWARE_MAX_WHEEL_SPEED,
    Epuck2Backend,
    encode_command,
    make_command,
    metres_per_second,
)

from .common import RESULTS, machine

PERIOD = 0.1
PERIODS = 30
COMMAND_TIMEOUT = 0.3
SIZES = (1, 10, 50)
COLOUR = (255, 128, 0)


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
    for k in range(PERIODS):
        speed, _ = period_speed(k)
        calls.append(time.monotonic())
        backend.set_commands(ids, [speed] * n, [-speed] * n, [COLOUR] * n)
        blocked.append(time.monotonic() - calls[-1])
        time.sleep(max(0.0, calls[-1] + PERIOD - time.monotonic()))
    cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    time.sleep(COMMAND_TIMEOUT + 2 * PERIOD)  # commands cease: the watchdog stops the robots
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
        for k in range(PERIODS):
            speed, _ = period_speed(k)
            calls.append(time.monotonic())
            for sock in socks:
                sock.sendall(encode_command(make_command(speed, -speed, COLOUR, FIRMWARE_MAX_WHEEL_SPEED)))
                sock.recv(1)  # the robot's empty answer
            blocked.append(time.monotonic() - calls[-1])
            time.sleep(max(0.0, calls[-1] + PERIOD - time.monotonic()))
        cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
        time.sleep(COMMAND_TIMEOUT + 2 * PERIOD)
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


def row(name: str, n: int, r: dict) -> str:
    lat = sorted(r["lat"])
    p95 = lat[min(len(lat) - 1, int(0.95 * len(lat)))]
    return (
        f"| {name} | {n} | {len(lat)}/{r['expected']} | {1e3 * statistics.median(lat):.2f} | {1e3 * p95:.2f} | "
        f"{1e3 * lat[-1]:.2f} | {1e3 * r['blocked']:.2f} | {r['late']} | {100 * r['cpu']:.0f} | {r['stopped']}/{n} | {r['stop_after']:.3f} |"
    )


def main() -> int:
    # the watchdog's stops are expected here, and close() finds the emulator gone once its log is read
    logging.getLogger("hardware.epuck2").setLevel(logging.CRITICAL)
    lines = [
        "| client | N robots | commands received | latency p50 ms | p95 ms | max ms | control loop blocked, max ms | late | CPU % of a core | "
        "stopped after commands ceased | last stop after last call s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for n in SIZES:
            lines.append(row("backend (one asyncio task per robot, watchdog)", n, run_backend(n, Path(tmp))))
            lines.append(row("sequential send + wait answer", n, run_sequential(n, Path(tmp))))
            print(lines[-2], lines[-1], sep="\n", flush=True)
    text = "\n".join(
        [
            "# e-puck2 Wi-Fi backend against emulated robots",
            "",
            "Command: `.venv/bin/python -m bench.bench_epuck2`",
            f"Machine: {machine()}, load average {os.getloadavg()[0]:.1f} at the end; measured {time.strftime('%Y-%m-%d')}.",
            "Emulator in its own process; CPU is the client's process only.",
            f"{PERIODS} periods of {PERIOD} s, command_timeout {COMMAND_TIMEOUT} s.",
            "",
            *lines,
            "",
        ]
    )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "epuck2.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
