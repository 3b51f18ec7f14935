"""Soak: agent processes in real time for a long show with message loss; memory, CPU, missed ticks
and contacts over time (issue 24).

A `pixelswarm run` of ROBOTS robots, one agent process each, real-time clock, a scene that changes
image every HOLD seconds for the whole length, and the fault plan dropping LOSS of every message kind
an agent receives. Every SAMPLE seconds the bench reads each agent process's resident memory and its
CPU share since the last sample (psutil). An observer on the run's router (loopback, no loss) counts,
per minute of display, the robot-ticks for which no command was sent at all (missed ticks) and the
contacts the world reports.

    .venv/bin/python -m bench.bench_soak --minutes 60      # the figures in BENCHMARKS.md: a quiet machine
    .venv/bin/python -m bench.bench_soak --minutes 3 --results /tmp/soak.md   # a check that it works
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import psutil

from transport.bus import Bus
from transport.codec import Command, Contact, Tick
from transport.faults import format_faults, parse_faults
from transport.session import TransportError, ZenohSettings, free_port

from .common import REPO, RESULTS, machine

ROBOTS = 20
LOSS = 0.05  # of every message kind an agent receives
LOSSY_KINDS = ("pose", "state", "auction", "goals")
HOLD = 60.0  # s each image is held
SHAPES = ("disk", "ring", "line", "triangle")
SAMPLE = 60.0  # s between samples of the agent processes
DT = 0.1  # s, the control period


def soak_scene(minutes: float, robots: int) -> str:
    steps = max(1, round(minutes * 60.0 / HOLD))
    text = [
        'name = "soak"',
        f"robots = {robots}",
        "seed = 11",
        'clock = "realtime"',
        "[layout]",
        'kind = "grid"',
        "spacing = 0.2",
        "[end]",
        "converge_hold = 1e9",  # never ends early: the soak runs its whole length
    ]
    for k in range(steps):
        text += ["[[steps]]", f'shape = "{SHAPES[k % len(SHAPES)]}"', f"hold = {HOLD}"]
    return "\n".join(text) + "\n"


@dataclass
class Observer:
    """Commands and contacts per minute of display, heard on the router without loss."""

    bus: Bus
    robots: int
    ticks: dict[int, set[int]] = field(default_factory=dict)  # minute -> ticks announced
    answered: dict[int, set[tuple[int, int]]] = field(default_factory=dict)  # minute -> (robot, tick) commanded
    contacts: dict[int, int] = field(default_factory=dict)  # minute -> contacts that began in it

    def __post_init__(self) -> None:
        keys = self.bus.keys
        self.clock = self.bus.subscribe(keys.clock, Tick)
        self.cmd = self.bus.subscribe(keys.all_of("cmd"), Command)
        self.contact = self.bus.subscribe(keys.contact, Contact)

    def poll(self) -> None:
        for _, tick in self.clock.drain():
            self.ticks.setdefault(minute_of(tick.tick), set()).add(tick.tick)
        for _, cmd in self.cmd.drain():
            self.answered.setdefault(minute_of(cmd.tick), set()).add((cmd.robot, cmd.tick))
        for _, c in self.contact.drain():
            self.contacts[int(c.t_start // 60.0)] = self.contacts.get(int(c.t_start // 60.0), 0) + 1

    def missed(self, minute: int) -> int:
        return self.robots * len(self.ticks.get(minute, ())) - len(self.answered.get(minute, ()))


def minute_of(tick: int) -> int:
    return int(tick * DT // 60.0)


def agent_processes(pid: int) -> list[psutil.Process]:
    out = []
    for p in psutil.Process(pid).children(recursive=True):
        try:
            if "agent" in p.cmdline():
                out.append(p)
        except psutil.Error:
            pass
    return out


def sample(agents: dict[int, psutil.Process]) -> tuple[np.ndarray, np.ndarray]:
    """Each live agent process's RSS (MB) and CPU % since the last sample."""
    rss, cpu = [], []
    for pid, p in list(agents.items()):
        try:
            rss.append(p.memory_info().rss / 2**20)
            cpu.append(p.cpu_percent())
        except psutil.Error:
            agents.pop(pid)
    return np.array(rss), np.array(cpu)


def join(endpoint: str, proc: subprocess.Popen) -> Bus:
    """A session on the run's router, once the run has opened it."""
    end = time.monotonic() + 120.0
    while True:
        try:
            return Bus(ZenohSettings(mode="client", connect=[endpoint]), name="soak")
        except TransportError:
            if proc.poll() is not None or time.monotonic() > end:
                proc.kill()
                raise SystemExit("bench_soak: the run's router never came up") from None
            time.sleep(0.5)


def soak(minutes: float, robots: int, every: float) -> tuple[dict, list[dict], Observer]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    plan = parse_faults(";".join(f"{kind}:drop={LOSS}" for kind in LOSSY_KINDS))
    with tempfile.TemporaryDirectory() as tmp:
        scene, out = Path(tmp) / "soak.toml", Path(tmp) / "run"
        scene.write_text(soak_scene(minutes, robots))
        command = [sys.executable, "-m", "sim.cli", "run", str(scene), "--out", str(out), "--no-video", "-q"]
        command += ["-l", endpoint, "--faults", format_faults(plan), "--duration", str(minutes * 60.0)]
        proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rows: list[dict] = []
        with join(endpoint, proc) as bus:
            observer = Observer(bus, robots)
            agents: dict[int, psutil.Process] = {}
            started = time.monotonic()
            due = started
            while proc.poll() is None:
                observer.poll()
                for p in agent_processes(proc.pid):
                    if p.pid not in agents:
                        p.cpu_percent()  # starts its CPU counter
                        agents[p.pid] = p
                if time.monotonic() >= due and len(agents) == robots:
                    rss, cpu = sample(agents)
                    if due > started and len(rss) == robots:  # the first sample only starts the CPU counters
                        rows.append({"wall_min": (time.monotonic() - started) / 60.0, "rss": rss, "cpu": cpu})
                        print(f"soak: {rows[-1]['wall_min']:.1f} min, RSS {np.median(rss):.0f} MB", flush=True)
                    due = time.monotonic() + every
                time.sleep(0.1)
            observer.poll()
        _, stderr = proc.communicate()
        if proc.returncode != 0:
            raise SystemExit(f"bench_soak: the run failed: {stderr.strip().splitlines()[-1:]}")
        return json.loads((out / "metrics.json").read_text()), rows, observer


def report(minutes: float, robots: int, every: float, metrics: dict, rows: list[dict], obs: Observer) -> list[str]:
    lines = [
        f"{robots} agent processes, one robot each, real-time clock, {minutes:g} min of display (an image every "
        f"{HOLD:g} s), {LOSS:.0%} of every {', '.join(LOSSY_KINDS)} message dropped where an agent receives it. "
        f"Load average at the end: {', '.join(f'{x:.1f}' for x in psutil.getloadavg())}.",
        "",
        f"Contacts: {metrics['contacts']}; missed ticks in the world (no command in time): {metrics['missed_ticks']}; "
        f"commands expired: {metrics.get('expired_commands', 0)}; real-time factor "
        f"{metrics.get('stepping_realtime_factor') or 0:.2f}.",
        "",
        "| wall min | RSS per agent MB (median, max) | CPU per agent % (median, max) |",
        "|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['wall_min']:.1f} | {np.median(r['rss']):.0f}, {r['rss'].max():.0f} "
            f"| {np.median(r['cpu']):.1f}, {r['cpu'].max():.1f} |"
        )
    lines += ["", "| display minute | ticks | missed ticks (no command sent) | contacts |", "|---|---|---|---|"]
    for minute in sorted(obs.ticks):
        lines.append(f"| {minute} | {len(obs.ticks[minute])} | {obs.missed(minute)} | {obs.contacts.get(minute, 0)} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_soak", description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the show (default 60)")
    parser.add_argument("--robots", type=int, default=ROBOTS)
    parser.add_argument("--sample", type=float, default=SAMPLE, help="seconds between samples (default 60)")
    parser.add_argument("--results", type=Path, default=RESULTS / "soak.md")
    args = parser.parse_args()
    if not (args.minutes > 0 and args.robots > 0 and args.sample > 0):
        print("bench_soak: error: --minutes, --robots and --sample must be positive", file=sys.stderr)
        return 2
    metrics, rows, obs = soak(args.minutes, args.robots, args.sample)
    command = f".venv/bin/python -m bench.bench_soak --minutes {args.minutes:g} --robots {args.robots}"
    if args.sample != SAMPLE:
        command += f" --sample {args.sample:g}"
    text = [
        f"## Soak: {args.robots} agent processes for {args.minutes:g} min with {LOSS:.0%} message loss",
        "",
        f"Command: `{command}`",
        f"Machine: {machine()}; measured {time.strftime('%Y-%m-%d', time.gmtime())}.",
        "",
        *report(args.minutes, args.robots, args.sample, metrics, rows, obs),
        "",
    ]
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text("\n".join(text))
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
