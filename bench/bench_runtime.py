"""Runtime benchmark (issues 2 and 25): agent processes at 10 Hz beside their floor, in one run.

For each N: N bare zenoh processes doing a robot's messages per tick and nothing else
(bench.floor_node: the floor), then N agent processes of `pixelswarm run circle` in real time; per
process CPU, RSS and USS, the real-time factor, missed ticks, contacts and start-up; then the
circle with every command delayed 0.15 s (``--faults cmd:delay=0.15``) at 20 processes, and
(without --quick) the lock-step rows and 1000 robots in 4 hosts. The machine's load average is
written beside each row: on a shared machine the figures are only as good as it was quiet.

    .venv/bin/python -m bench.bench_runtime [--quick] [--sizes 20,50,100] [--duration 20]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import psutil

from coordinator.scene import load_scene
from sim.tracker import world_of
from transport.bus import Bus
from transport.codec import Pose
from transport.session import client_of, loopback_router

from .common import REPO, run_and_sample, write_results

WARM_UP = 3.0  # s of ticks before the floor is measured (subscriptions travel, processes settle)
DELAYED = "cmd:delay=0.15"  # every command a tick and a half late: bodies must stop, never touch
DELAYED_AT = 20


def load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def floor_row(n: int, duration: float, callbacks: str = "direct") -> dict:
    """N floor processes, clocked at 10 Hz from here as the world clocks agents: the cost of a
    robot's messages alone. Returns CPU (% of a core, each process's mean over the run), RSS and
    USS (MB), and the share of ticks answered."""
    scene = load_scene("circle", robots=n, seed=3, clock="realtime")
    params, _ = world_of(scene)
    router = loopback_router()
    procs: list[subprocess.Popen] = []
    with Bus(router, name="floor-clock") as bus:
        cmds = bus.commands_inbox()
        try:
            for i, (x, y, _) in enumerate(scene.poses):
                procs.append(
                    subprocess.Popen(
                        [sys.executable, "-m", "bench.floor_node", "--robot", str(i), f"--x={x}", f"--y={y}"]
                        + ["--cell-size", str(params.cell_size), "--duration", str(duration + WARM_UP + 30)]
                        + ["--callbacks", callbacks]
                        + client_of(router).to_args(),
                        cwd=REPO,
                        stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE,
                        text=True,
                    )
                )
            for p in procs:  # each says ready once subscribed
                if p.stdout is None or p.stdout.readline().strip() != "ready":
                    raise RuntimeError(f"a floor process failed: {p.communicate()[1][-500:]}")
            watched = [psutil.Process(p.pid) for p in procs]
            ticks = round((duration + WARM_UP) / params.dt)
            start = next_tick = time.monotonic()
            answered = 0
            for tick in range(ticks):
                if tick == round(WARM_UP / params.dt):
                    for w in watched:
                        w.cpu_percent()  # the measured window starts
                    answered = 0
                for i, (x, y, th) in enumerate(scene.poses):
                    bus.publish(bus.keys.pose(i), Pose(i, tick, tick * params.dt, x, y, th))
                next_tick += params.dt
                time.sleep(max(0.0, next_tick - time.monotonic()))
                answered += len(cmds.drain())
            wall = time.monotonic() - start
            cpu = [w.cpu_percent() for w in watched]
            memory = [w.memory_full_info() for w in watched]
        finally:
            for p in procs:
                p.send_signal(signal.SIGTERM)
            outputs = [p.communicate(timeout=30)[0] for p in procs]
    states = [json.loads(o.strip().splitlines()[-1])["states_received"] for o in outputs if o.strip()]
    return {
        "cpu": float(np.median(cpu)),
        "rss": float(np.median([m.rss for m in memory])) / 2**20,
        "uss": float(np.median([m.uss for m in memory])) / 2**20,
        "answered": answered / (n * round(duration / params.dt)),
        "rtf": ticks * params.dt / wall,
        "states_per_tick": float(np.median(states)) / ticks if states else float("nan"),
    }


def agent_row(n: int, duration: float, clock: str = "realtime", faults: str = "") -> dict:
    args = ["circle", "--robots", str(n), "--clock", clock, "--duration", str(duration), "--seed", "3"]
    m, samples = run_and_sample(args + (["--faults", faults] if faults else []))
    ticks = max(m["samples"] - 1, 1) * n  # robot-ticks the world stepped
    per_process: dict[int, list[dict]] = {}
    for s in samples:  # each process's samples (an exiting process reports no memory)
        if s["rss"] > 0:
            per_process.setdefault(s["pid"], []).append(s)
    cpu = [np.median([s["cpu"] for s in ss if s["cpu"] > 0] or [0]) for ss in per_process.values()]
    return {
        "cpu": float(np.median(cpu)),
        "rss": float(np.median([np.median([s["rss"] for s in ss]) for ss in per_process.values()])) / 2**20,
        "uss": float(np.median([np.median([s["uss"] for s in ss]) for ss in per_process.values()])) / 2**20,
        "rtf": m["stepping_realtime_factor"] or 0.0,
        "missed": m["missed_ticks"],
        "missed_share": m["missed_ticks"] / ticks,
        "contacts": m["contacts"],
        "overlap": m["max_overlap_m"],
        "stopped": m["stopped_ticks"],
        "start_and_stop": m["wall_s"] - m["stepping_wall_s"],
        "converged": m["converged"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 20 only, no lock-step or hosted rows")
    parser.add_argument("--sizes", default="", help="comma-separated N (default 20,50,100; --quick: 20)")
    parser.add_argument("--duration", type=float, default=20.0, help="s of display per run")
    args = parser.parse_args()
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s] or ([20] if args.quick else [20, 50, 100])
        if min(sizes) < 1 or args.duration <= 0:
            raise ValueError
    except ValueError:
        print("bench_runtime: error: --sizes takes whole numbers >= 1, --duration a positive number", file=sys.stderr)
        sys.exit(2)
    rows = [
        "| N | process | load avg | RTF | missed ticks (share) | contacts (max overlap m) | CPU per process "
        "(% of a core, median) | x floor | RSS MB (median) | USS MB (median) | start + stop s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n in sizes:
        for callbacks, what in [
            ("thread", "floor: bare zenoh, a thread per subscription"),
            ("direct", "floor: one thread"),
        ]:
            before = load()
            f = floor_row(n, args.duration, callbacks)
            rows.append(
                f"| {n} | {what} | {before} | {f['rtf']:.2f} | {100 * (1 - f['answered']):.2f}% unanswered | "
                f"- | {f['cpu']:.2f} | 1 | {f['rss']:.1f} | {f['uss']:.1f} | - |"
            )
            print(rows[-1], f"(states heard per tick: {f['states_per_tick']:.1f})", flush=True)
        before = load()
        a = agent_row(n, args.duration)
        rows.append(
            f"| {n} | agent | {before} | {a['rtf']:.2f} | {a['missed']} ({100 * a['missed_share']:.2f}%) | "
            f"{a['contacts']} ({a['overlap']:.3f}) | {a['cpu']:.2f} | {a['cpu'] / max(f['cpu'], 1e-9):.1f} | "
            f"{a['rss']:.1f} | {a['uss']:.1f} | {a['start_and_stop']:.1f} |"
        )
        print(rows[-1], flush=True)
    n = DELAYED_AT if not args.sizes else min(sizes)
    before = load()
    d = agent_row(n, args.duration, faults=DELAYED)
    rows.append(
        f"| {n} | agent, `--faults {DELAYED}` | {before} | {d['rtf']:.2f} | {d['missed']} "
        f"({100 * d['missed_share']:.2f}%) | {d['contacts']} ({d['overlap']:.3f}) | {d['cpu']:.1f} | - | "
        f"{d['rss']:.1f} | {d['uss']:.1f} | {d['start_and_stop']:.1f} |"
    )
    print(rows[-1], flush=True)
    extra: list[str] = []
    if not args.quick and not args.sizes:
        for n in sizes:
            before = load()
            a = agent_row(n, args.duration, clock="lockstep")
            extra.append(
                f"| {n} | agent, lock-step | {before} | {a['rtf']:.2f} | {a['missed']} "
                f"({100 * a['missed_share']:.2f}%) | {a['contacts']} ({a['overlap']:.3f}) | {a['cpu']:.1f} | - | "
                f"{a['rss']:.1f} | {a['uss']:.1f} | {a['start_and_stop']:.1f} |"
            )
            print(extra[-1], flush=True)
        m, samples = run_and_sample(
            ["circle", "--robots", "1000", "--clock", "lockstep", "--duration", "10", "--agents-per-process", "250"]
        )
        cpu = np.median([s["cpu"] for s in samples if s["cpu"] > 0] or [0])
        extra += [
            "",
            "| N | hosts (K per process) | clock | RTF | CPU per host (%) | RSS per host MB |",
            "|---|---|---|---|---|---|",
            f"| 1000 | 4 (K = 250) | lockstep | {m['stepping_realtime_factor']:.2f} | {cpu:.0f} | "
            f"{np.median([s['rss'] for s in samples]) / 2**20:.0f} |",
        ]
    command = " ".join(["python -m bench.bench_runtime", *sys.argv[1:]])
    write_results(
        "runtime",
        "Runtime: agent processes over zenoh beside the bare-zenoh floor (issues 2, 25)",
        command,
        rows
        + extra
        + [
            "",
            "Floor: bench.floor_node, a bare zenoh session per robot that per tick hears its pose and the states "
            "of its 5 x 5 cells and puts a state and a command, clocked at 10 Hz by this benchmark (robots standing "
            "at the circle's start), its callbacks on a Python thread per subscription (zenoh-python's default, as "
            "transport.bus does) or on zenoh's receiving thread. Agent: `pixelswarm run circle --seed 3` in real time. x floor: the agent's CPU "
            "over the floor's (one thread) of the same N, in this run. RTF: simulated seconds per wall second while the world "
            "was stepping. Missed ticks: a live agent's command for tick k had not reached the world when tick k+1 "
            "began (a body without a valid command stops: agent.lateness, docs/overload.md). Start + stop: "
            "the run's wall time less its stepping time (start-up to the first tick, and the shutdown). "
            "USS: memory unique to one process. Load avg: the machine's 1-minute load before the row.",
        ],
    )


if __name__ == "__main__":
    main()
