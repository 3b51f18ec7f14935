"""An agent process's CPU per tick, the code of a git revision beside the current code (issue 25).

The same small real-time scene (`pixelswarm run circle`, one robot per agent process, or hosts of
``--agents-per-process`` robots) runs with the code at ``--before REV`` (a temporary ``git
worktree`` of it, run with the same Python from there) and with the current code, alternating,
``--pairs`` times each. Both trees' bytecode is compiled first, as `make run` does, so that a robot's
process runs with the same interpreter flags in each (agent.runtime.interpreter). Per run: each agent process's CPU
(psutil cpu_times, user + system) over the world's stepping, as % of a core (median and mean over
the agents), and the missed ticks the world counted; and where each agent's resident memory lies at
the end of the stepping (psutil memory_maps, by part: the compiled core, numpy, zenoh, ...).

    python -m bench.bench_agent_tick [--before 2f61ee4] [--robots 10] [--duration 20] [--pairs 2]
    python -m bench.bench_agent_tick --robots 250 --agents-per-process 125   # hosts of 125 robots
    python -m bench.bench_agent_tick --tick-alone [--pairs 2]   # one robot's tick in-process, no other process

``--tick-alone`` times AgentHost._step_tick alone, in a process of its own per tree and pair (a zenoh
session on loopback with no peer; NEIGHBOURS neighbours' states heard each tick, and the tracker's
bodies near the robot where the code has them): without the other processes' load, a few percent
tell apart that a loaded machine's run hides.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from agent.core.params import RobotParams

from .bench_runtime import worktree_at
from .common import REPO, write_results

BEFORE = "2f61ee4"  # main before this branch: the code without its per-tick work outside the control step
GOALS_EVERY = 1.0  # s between the coordinator's repeats of its goal set, each checked again
SAMPLE_EVERY = 0.25  # s between CPU samples of the agent processes
EDGE = 1.0  # s left out of each end of the stepping window (the first ticks, the shutdown)
WORLD = {"sim.node.world", "sim.world_node"}  # the world's module, now and in older trees
MAPS_EVERY = 2.0  # s between readings of the agents' memory maps (slower to read than a CPU sample)
PARTS = ("compiled core", "numpy", "zenoh", "Python", "heap", "anonymous", "other")  # of an agent's RSS


def part_of(path: str) -> str:
    """Which part of an agent's memory a mapping is, by its path (memory_maps' grouping)."""
    for needle, part in (("/agent/core/", "compiled core"), ("/sim/bodies/", "compiled core"), ("numpy", "numpy")):
        if needle in path:
            return part
    if "zenoh" in path:
        return "zenoh"
    if "libpython" in path:
        return "Python"
    if path == "[heap]":
        return "heap"
    return "anonymous" if path in ("", "[anon]") or path.startswith("[anon:") else "other"


def memory_parts(process: psutil.Process) -> dict[str, float]:
    """The process's resident bytes by part (PARTS)."""
    out = dict.fromkeys(PARTS, 0.0)
    for m in process.memory_maps(grouped=True):
        out[part_of(m.path)] += m.rss
    return out


def run_scene(cwd: Path, robots: int, duration: float, seed: int, per_process: int = 1) -> dict:
    """One `sim.cli run circle` from ``cwd``: its metrics and the agents' CPU over the stepping."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        args = ["circle", "--robots", str(robots), "--clock", "realtime", "--duration", str(duration)]
        args += ["--agents-per-process", str(per_process)]
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim.cli", "run", *args, "--seed", str(seed), "--out", str(out), "--no-video", "-q"],
            cwd=cwd,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={k: v for k, v in os.environ.items() if k != "PIXELSWARM_PROFILE"},
        )
        series: dict[int, list[tuple[float, float, float]]] = {}  # agent pid -> (wall, CPU seconds, RSS bytes)
        maps: dict[int, list[tuple[float, dict[str, float], float]]] = {}  # agent pid -> (wall, memory_parts, USS)
        watched: dict[int, psutil.Process] = {}  # the agents' processes and the world's
        world = -1
        maps_due = 0.0
        while proc.poll() is None:
            try:
                children = psutil.Process(proc.pid).children(recursive=True)
            except psutil.Error:
                break
            for child in children:
                try:
                    cmdline = child.cmdline()
                    if child.pid not in watched and ("agent" in cmdline or WORLD & set(cmdline)):
                        watched[child.pid] = child
                        world = child.pid if WORLD & set(cmdline) else world
                except psutil.Error:
                    pass
            now = time.monotonic()
            read_maps = now >= maps_due
            if read_maps:
                maps_due = now + MAPS_EVERY
            for pid, p in list(watched.items()):
                try:
                    t, m = p.cpu_times(), p.memory_info()
                    series.setdefault(pid, []).append((now, t.user + t.system, m.rss))
                    if read_maps:
                        maps.setdefault(pid, []).append((now, memory_parts(p), p.memory_full_info().uss))
                except psutil.Error:
                    watched.pop(pid)
            time.sleep(SAMPLE_EVERY)
        _, stderr = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(f"run from {cwd} failed: {stderr[-2000:]}")
        m = json.loads((out / "metrics.json").read_text())
    # The stepping window: it ends when the first agent is stopped, and lasted stepping_wall_s.
    series = {pid: s for pid, s in series.items() if len(s) >= 4}  # not a process seen only in passing
    world_series = series.pop(world, None)
    end = min(s[-1][0] for s in series.values()) - EDGE
    begin = end - float(m["stepping_wall_s"]) + 2 * EDGE
    cpu, rss = [], []
    for s in series.values():
        if (window := _in_window(s, begin, end)) is not None:
            cpu.append(window[0])
            rss.append(window[1])  # at the end of the stepping: a robot's process has its memory by then
    world_window = None if world_series is None else _in_window(world_series, begin, end)
    last = [[(parts, uss) for t, parts, uss in maps.get(pid, []) if t <= end][-1:] for pid in series]  # before the end
    ticks = max(int(m.get("samples", 1)) - 1, 1) * robots
    if not cpu:  # no two samples inside the window (a loaded machine sampled too seldom)
        cpu = [float("nan")]
    return {
        "cpu_median": float(np.median(cpu)),
        "rss_mb": float(np.median(rss)) / 2**20 if rss else float("nan"),
        "uss_mb": float(np.median([x[0][1] for x in last if x])) / 2**20 if any(last) else float("nan"),
        "cpu_mean": float(np.mean(cpu)),
        "missed": int(m["missed_ticks"]),
        "missed_share": m["missed_ticks"] / ticks,
        "load": os.getloadavg()[0],
        "world_cpu": float("nan") if world_window is None else world_window[0],
        "parts": [x[0][0] for x in last if x],  # per agent: its memory_parts at the end of the stepping
    }


def _in_window(samples: list[tuple[float, float, float]], begin: float, end: float) -> tuple[float, float] | None:
    """A process's CPU % of a core between ``begin`` and ``end``, and its RSS at the last sample in them."""
    t, c, r = np.array(samples).T
    i, j = np.searchsorted(t, begin), np.searchsorted(t, end, side="right") - 1
    return (100 * (c[j] - c[i]) / (t[j] - t[i]), r[j]) if j > i else None


NEIGHBOURS = 15  # --tick-alone: states heard a tick (a crowd: more than max_neighbours)
TICK_ALONE = """
import sys, time
import numpy as np
from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import Pose, Poses, State
from transport.session import loopback_router

ticks, n, p = int(sys.argv[1]), int(sys.argv[2]), RobotParams()
near = np.random.default_rng(1).uniform(-0.5, 0.5, (n, 2))
with Bus(loopback_router(), "tick") as bus:
    host = AgentHost(bus, HostConfig(robots=[0], params=p, arena=(-3, -3, 3, 3)))
    bodies = getattr(getattr(host, "inbox", None), "bodies", None)  # the tracker's bodies, where the code has them
    cpu = []
    for k in range(1, ticks + 1):
        for r, (x, y) in enumerate(near.tolist(), 1):
            host.table.update(State(r, k - 1, (k - 1) * p.dt, x, y, 0.05, 0.0, p.radius, 1.0, 1.0, r, State.HAS_GOAL, 1, 1))
        if bodies is not None:  # the bodies after the robot's own record in its pose frame, as the bus gives them
            bodies.hear(k, Poses.records_of(np.arange(1, n + 1), np.column_stack([near, np.zeros(n)])))
        began = time.process_time()
        host.table.advance(k)
        host._step_tick([Pose(0, k, k * p.dt, 0.0, 0.0, 0.0)])
        cpu.append(time.process_time() - began)
print(float(np.median(cpu[ticks // 10:])) * 1e6)
"""


def tick_alone(tree: Path, ticks: int = 1000) -> float:
    """Median CPU us of one robot's AgentHost._step_tick with the code of ``tree`` (TICK_ALONE)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tree), os.environ.get("PYTHONPATH")]))}
    cmd = [sys.executable, "-OO", "-c", TICK_ALONE, str(ticks), str(NEIGHBOURS)]
    return float(subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, check=True).stdout)


def _parts_row(label: str, agents: list[dict[str, float]]) -> str:
    if not agents:
        return f"| {label} |" + " - |" * (len(PARTS) + 1)
    medians = [np.median([a[part] for a in agents]) / 2**20 for part in PARTS]
    total = np.median([sum(a.values()) for a in agents]) / 2**20
    return f"| {label} | " + " | ".join(f"{v:.2f}" for v in medians) + f" | {total:.2f} |"


def checks_per_tick(robots: int, dt: float, reps: int = 2000) -> float:
    """Microseconds of a robot's checks of what it hears in one tick (transport.plausible and
    agent.pose_trust), at most: the states of all the other robots (each key's one-robot rule,
    the tick's future bound, the stamp), its pose (its line, stamp and trust), and the goal set
    of ``robots`` goals the coordinator repeats every GOALS_EVERY s. Timed in this process, as
    the agent calls them."""
    import timeit

    from agent.pose_trust import PoseTrust
    from transport.codec import Goals, State
    from transport.keys import Keys
    from transport.plausible import AHEAD, GoalSets, TickLine, stamp_agrees

    keys = Keys()
    heard = [
        (keys.state((i, 0), i), State(i, 100, 100 * dt, 0.1 * i, 0, 0, 0, 0.045, 0, 0, i, 0)) for i in range(robots - 1)
    ]
    now = 100

    def states() -> None:
        for key, s in heard:
            if Keys.robot_alone(key) != s.robot or s.tick > now + AHEAD or not stamp_agrees(s.tick, s.stamp, dt):
                raise AssertionError("an honest state refused")

    line, trust, tick = TickLine(dt), PoseTrust(0.3, dt, 0.02), [0]

    def pose() -> None:
        tick[0] += 1
        k = tick[0]
        if line.admit(k, k * dt) or not stamp_agrees(k, k * dt, dt) or trust.judge(0, k, 1e-3 * k, 0.0, 0.0) is None:
            raise AssertionError("an honest pose refused")

    rng = np.random.default_rng(0)
    goals = Goals(1, 0, rng.uniform(0, 1, (robots, 2)), np.zeros((robots, 3), np.uint8), np.arange(robots))
    believed = GoalSets((0, 0, 1, 1))
    believed.admit(goals, None)
    seconds = [
        timeit.timeit(states, number=reps) / reps,
        timeit.timeit(pose, number=reps) / reps,
        timeit.timeit(lambda: believed.admit(goals, None), number=reps) / reps * dt / GOALS_EVERY,
    ]
    return 1e6 * sum(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=BEFORE, help="git revision to compare against")
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--duration", type=float, default=20.0, help="s of display per run")
    parser.add_argument("--pairs", type=int, default=2, help="before/after pairs, alternating")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--agents-per-process", "-k", type=int, default=1, help="robots per agent process")
    parser.add_argument("--tick-alone", action="store_true", help="time one robot's tick in-process instead")
    args = parser.parse_args()
    if min(args.robots, args.pairs, args.agents_per_process) < 1 or args.duration <= 0:
        print(
            "bench_agent_tick: error: --robots, --duration, --pairs and --agents-per-process must be positive",
            file=sys.stderr,
        )
        sys.exit(2)
    rev = subprocess.run(["git", "rev-parse", "--short", args.before], cwd=REPO, capture_output=True, text=True)
    if rev.returncode != 0:
        print(f"bench_agent_tick: error: no revision {args.before!r}", file=sys.stderr)
        sys.exit(2)
    before_rev = rev.stdout.strip()
    rows = [
        "| pair | code | load avg | agent CPU % of a core (median) | (mean) | agent RSS MB (median) | USS MB (median) | missed ticks (share) | world CPU % |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    figures: dict[str, list[float]] = {"before": [], "after": []}
    parts: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    with worktree_at(before_rev) as (old, _):
        for tree in (old, REPO):  # what a robot's process imports, optimised too (-OO)
            compile_robot = [sys.executable, "-m", "compileall", "-q", "-o", "0", "-o", "2", "agent", "transport"]
            subprocess.run(compile_robot, cwd=tree, check=True, capture_output=True)
        if args.tick_alone:
            alone(old, before_rev, args.pairs)
            return
        for pair in range(1, args.pairs + 1):
            order = (("before", old), ("after", REPO))
            for what, cwd in order if pair % 2 else order[::-1]:  # each goes first as often: a run warms the next
                r = run_scene(cwd, args.robots, args.duration, args.seed, args.agents_per_process)
                figures[what].append(r["cpu_median"])
                parts[what] += r["parts"]
                label = f"{before_rev} (before)" if what == "before" else "current"
                rows.append(
                    f"| {pair} | {label} | {r['load']:.1f} | {r['cpu_median']:.2f} | {r['cpu_mean']:.2f} | "
                    f"{r['rss_mb']:.1f} | {r['uss_mb']:.1f} | {r['missed']} ({100 * r['missed_share']:.2f}%) | "
                    f"{r['world_cpu']:.1f} |"
                )
                print(rows[-1], flush=True)
    b, a = np.nanmedian(figures["before"]), np.nanmedian(figures["after"])  # nan: a run without a window
    dt = RobotParams().dt
    checks = checks_per_tick(args.robots * 1, dt)
    tick_us = a / 100 * dt * 1e6  # an agent's CPU per tick, after
    rows += [
        "",
        f"Median over the pairs: {b:.2f} % before, {a:.2f} % after ({a / b:.2f}x).",
        "",
        "Where an agent's resident memory lies at the end of the stepping, MB (median over the agents of every pair; "
        "psutil memory_maps, by the mapping's path; each column's median apart, so the total is its own median):",
        "",
        "| code | " + " | ".join(PARTS) + " | total |",
        "|---|" + "---|" * (len(PARTS) + 1),
        *(_parts_row(label, parts[what]) for what, label in (("before", before_rev), ("after", "current"))),
        "",
        f"The checks alone (checks_per_tick: every other robot's state, the pose, the goal set's repeats): "
        f"{checks:.1f} us a tick, {100 * checks / tick_us:.2f} % of the agent's {tick_us:.0f} us of CPU a tick.",
        "",
        f"Scene: `pixelswarm run circle --robots {args.robots} --clock realtime --duration {args.duration:g} "
        f"--seed {args.seed} --agents-per-process {args.agents_per_process}`, before and after alternating, each first in every other pair. "
        "CPU: each agent process's user + system CPU seconds (psutil cpu_times) over the world's stepping (less a second at each "
        "end) per wall second; RSS: each agent process's resident memory at the end of the stepping; USS: the part "
        "of it no other process maps (psutil memory_full_info: without the pages of code and libraries that "
        "every robot's process on the machine maps). Missed ticks: a live agent's command for tick k had not reached the world when "
        "tick k+1 began. World CPU: the world process's, over the same window. Load avg: the machine's 1-minute load "
        "after the run (a shared machine).",
    ]
    command = " ".join(["python -m bench.bench_agent_tick", *sys.argv[1:]])
    write_results(
        f"agent_tick_{args.robots}", "An agent process's CPU per tick, before and after (issue 25)", command, rows
    )


def alone(old: Path, before_rev: str, pairs: int) -> None:
    """--tick-alone: one robot's tick with each tree's code, alternating ``pairs`` times."""
    times: dict[str, list[float]] = {"before": [], "after": []}
    for pair in range(1, pairs + 1):
        for what, tree in (("before", old), ("after", REPO)):
            times[what].append(tick_alone(tree))
        print(f"pair {pair}: {times['before'][-1]:.0f} us before, {times['after'][-1]:.0f} us now", flush=True)
    b, a = np.median(times["before"]), np.median(times["after"])
    rows = [
        "| code | CPU us per tick (median of each run's median) | runs |",
        "|---|---|---|",
        f"| {before_rev} (before) | {b:.0f} | {', '.join(f'{t:.0f}' for t in times['before'])} |",
        f"| current | {a:.0f} | {', '.join(f'{t:.0f}' for t in times['after'])} |",
        "",
        f"{a / b:.2f}x. One robot alone (RobotParams()), AgentHost._step_tick in a process of its own per run, "
        f"{NEIGHBOURS} neighbours' states a tick, bodies near it where the code has them, process CPU time; "
        "the first tenth of the ticks left out.",
    ]
    command = " ".join(["python -m bench.bench_agent_tick", *sys.argv[1:]])
    write_results("agent_tick_alone", "One robot's tick in-process, before and after", command, rows)


if __name__ == "__main__":
    main()
