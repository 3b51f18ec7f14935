"""Micro-benchmark of sim.bodies.world.World.step(0.1) (10 substeps of 10 ms) at N = 100 and 1000.

Run from the repository root:

    .venv/bin/python bench/bench_world.py            # prints a table and writes bench/results/world.md

Scenarios (e-puck bodies, radius 0.045 m, actuation noise 0.02, seed 0):
  sparse   grid spaced 0.3 m, every robot driving straight in parallel: nobody near anybody
  packed   grid spaced 0.1 m (1 cm clearance), robots turning on the spot: a formed display
  crowded  uniform random positions at 200 robots per m^2 (the discs would cover 1.3 times the
           floor), random wheel speeds: contacts start and end all the time (the event
           bookkeeping's worst case)

Reference, side by side: the naive detection a world could do instead, scipy's pdist over all
pairs at each of the 10 substeps (detection only: no integration, no event bookkeeping).

The neighbour searches alone (agent.core.grid), beside the code of another revision in one run:

    .venv/bin/python bench/bench_world.py --neighbours [--before REV]

times, on the same points (a formed display: a lattice 0.12 m apart, jittered by up to 2 cm; and
one 0.6 m apart, fewer than 16 within reach) at
1000 and 10,000 robots, the central engine's neighbour search (sim.central.link's, 1.2 m and 16 as
paper-sequence-1000), the RVO2-shaped engine's (sim.central.rvo.CentralOrca.neighbours), the
world's contact search (sim.bodies.proximity.close_pairs over a step of 10 substeps) and one robot's
gather in its own process (NeighbourTable.gather among 14 and 200 states). With ``--before``, a
git worktree of REV (bench.bench_runtime.worktree) runs the same code first; rows alternate.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import scipy
from scipy.spatial.distance import pdist

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.core.params import EPUCK as EPUCK_PARAMS  # noqa: E402
from sim.bodies.world import ActuationNoise, Body, World  # noqa: E402

EPUCK = Body.from_params(EPUCK_PARAMS)
STEPS = 40
REPEATS = 5


def grid(n: int, spacing: float) -> np.ndarray:
    side = int(np.ceil(np.sqrt(n)))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * spacing
    return np.column_stack([g, np.zeros(n)])


def scenario(name: str, n: int, rng: np.random.Generator) -> tuple[World, np.ndarray]:
    if name == "sparse":
        poses, cmds = grid(n, 0.3), np.tile([0.12, 0.12], (n, 1))
    elif name == "packed":
        poses, cmds = grid(n, 0.1), np.tile([-0.05, 0.05], (n, 1))
    elif name == "crowded":
        side = np.sqrt(n * 0.005)  # 200 robots per m^2: discs cover ~1.3 times the floor
        poses = np.column_stack([rng.uniform(0, side, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
        cmds = rng.uniform(-0.13, 0.13, (n, 2))
    else:
        raise ValueError(name)
    w = World([EPUCK] * n, poses, noise=ActuationNoise(seed=0))
    for i in range(n):
        w.set_command(i, *cmds[i])
    return w, cmds


def time_world(name: str, n: int) -> tuple[float, float, int]:
    """Median and 90th percentile of step(0.1) in ms, and contact events started, over fresh runs."""
    samples = []
    events = 0
    for rep in range(REPEATS):
        w, _ = scenario(name, n, np.random.default_rng(rep))
        w.step(0.1)  # warm-up
        for _ in range(STEPS):
            t = time.perf_counter()
            events += len(w.step(0.1))
            samples.append(time.perf_counter() - t)
    s = np.array(samples) * 1e3
    return float(np.median(s)), float(np.percentile(s, 90)), events


def time_naive(n: int) -> float:
    """Median ms of pdist + min + overlap test at 10 substeps of N random positions."""
    rng = np.random.default_rng(0)
    states = [rng.uniform(0, np.sqrt(n) * 0.3, (n, 2)) for _ in range(10)]
    samples = []
    for _ in range(REPEATS * 4):
        t = time.perf_counter()
        for p in states:
            d = pdist(p) - 0.09
            d.min()
            np.flatnonzero(d < 0.0)
        samples.append(time.perf_counter() - t)
    return float(np.median(samples) * 1e3)


def main() -> None:
    rows = []
    for n in (100, 1000):
        naive = time_naive(n)
        for name in ("sparse", "packed", "crowded"):
            med, p90, events = time_world(name, n)
            rows.append((n, name, med, p90, events / REPEATS, naive))
    header = "| N | scenario | step(0.1) median ms | p90 ms | contact events per 4 s run | naive pdist detection ms |"
    lines = [header, "|---|---|---|---|---|---|"]
    lines += [f"| {n} | {name} | {m:.2f} | {p:.2f} | {e:.0f} | {nv:.2f} |" for n, name, m, p, e, nv in rows]
    table = "\n".join(lines)
    print(table)
    env = (
        f"Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs; {REPEATS} runs x {STEPS} steps per row; "
        f"load average at the end {os.getloadavg()[0]:.1f} (other work on the machine inflates the figures)."
    )
    out = Path(__file__).resolve().parent / "results" / "world.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        "## sim.bodies.world.World.step(0.1): 10 substeps of 10 ms\n\n"
        "Command: `.venv/bin/python bench/bench_world.py`\n\n"
        f"{env}\n\n{table}\n\n"
        "Scenarios: see the docstring of `bench/bench_world.py`. The last column is the detection a\n"
        "world could do naively (scipy `pdist` over all pairs at each substep, nothing else), for scale.\n"
    )
    print(f"\n{env}\nwritten to {out}")


# Runs in the tree being measured (its own agent and sim): only what both sides of a comparison have.
NEIGHBOUR_TIMINGS = r"""
import inspect, json, sys, time
import numpy as np
try:  # CentralOrca was agent.core.rvo before it moved to sim
    from sim.central.rvo import CentralOrca
except ImportError:
    from agent.core.rvo import CentralOrca
from agent.neighbour_table import Heard, NeighbourTable
from sim.bodies.proximity import close_pairs
from transport.codec import State
try:  # before agent.core.grid the central engine had its own compiled copy
    from sim.bodies.proximity import nearest_heard_compiled as central_search
except ImportError:
    from agent.neighbour_table import nearest_heard as central_search

REPEATS = int(sys.argv[1])

def points(n, spacing=0.12):
    rng = np.random.default_rng(n)
    side = int(np.ceil(np.sqrt(n)))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * spacing
    return g + rng.uniform(-0.02, 0.02, (n, 2)), rng

def timed(f):
    f()  # warm-up (a JIT compiles here)
    samples = []
    for _ in range(REPEATS):  # CPU time: what a busy machine's other work inflates least
        t = time.process_time()
        f()
        samples.append(time.process_time() - t)
    return float(np.median(samples) * 1e3)

out = {}
for n in (1000, 10000):
    p, rng = points(n)
    ids = np.arange(n)
    heard = Heard(ids, p, rng.normal(0, 0.1, (n, 2)), np.full(n, 0.045), np.zeros(n), np.ones(n, bool))
    out[f"central engine: each robot's 16 nearest heard within 1.2 m, {n} robots"] = timed(
        lambda: central_search(ids, p, 0.1, heard, 1.2, 16))
    sim = CentralOrca(0.1, 1.2, 16, 2.0, 2.0, 0.045, 0.13)
    sim.position, sim.radius = p.copy(), np.full(n, 0.045)  # add_agent, n at once
    out[f"RVO2-shaped engine: CentralOrca.neighbours, {n} robots"] = timed(sim.neighbours)
    motion = 0.013  # 0.13 m/s for 0.1 s
    traj = p[None] + np.cumsum(rng.uniform(-motion / 10, motion / 10, (11, n, 2)), axis=0)
    radius = np.full(n, 0.045)
    out[f"world: close_pairs over a step of 10 substeps, {n} robots"] = timed(
        lambda: close_pairs(traj, radius, 0.09 + 2 * motion + 0.0225, motion, 1))
    p, rng = points(n, 0.6)  # sparse: about 12 within reach, fewer than 16
    heard = Heard(ids, p, rng.normal(0, 0.1, (n, 2)), np.full(n, 0.045), np.zeros(n), np.ones(n, bool))
    out[f"central engine, sparse (0.6 m apart): 16 nearest heard within 1.2 m, {n} robots"] = timed(
        lambda: central_search(ids, p, 0.1, heard, 1.2, 16))
for s in (14, 200):
    p, rng = points(s + 1)
    table = NeighbourTable(0.1)
    for r in range(1, s + 1):
        table.update(State(r, 1, 0.1, float(p[r, 0]), float(p[r, 1]), 0.0, 0.0, 0.045, 0.0, 0.0, -1, 0, 0, 0))
    if "sensed" in inspect.signature(NeighbourTable.gather).parameters:  # what the robot senses, as one
        from agent.core.params import RobotParams
        from agent.loop import Sensed
        one = Sensed(np.zeros(1, np.int64), p[:1], np.zeros(1), 2, 0.2, RobotParams(neighbour_dist=1.2,
                     max_neighbours=16), np.zeros(1, bool))
        gather = lambda: table.gather(one, 1.2, {}, None)
    else:
        gather = lambda: table.gather([0], p[:1], 0.2, 2, 1.2, 16)
    out[f"agent: one robot's gather among {s} states"] = timed(gather)
print(json.dumps(out))
"""


def neighbour_timings(tree: Path, repeats: int) -> dict[str, float]:
    """The neighbour searches' median ms, measured by the code in ``tree`` (a fresh process)."""
    done = subprocess.run(
        [sys.executable, "-B", "-c", NEIGHBOUR_TIMINGS, str(repeats)],
        cwd=tree,
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def neighbours_main(before: str | None, repeats: int, rounds: int) -> None:
    """The neighbour searches of this tree, beside those of ``before`` (rounds alternate)."""
    here = Path(__file__).resolve().parents[1]
    with contextlib.ExitStack() as stack:
        trees = {"this tree": here}
        if before:
            from bench.bench_runtime import worktree_at

            old, commit = stack.enter_context(worktree_at(before))
            trees = {f"before ({commit})": old, "this tree": here}
        runs: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
        for _ in range(rounds):
            for name, tree in trees.items():
                runs[name].append(neighbour_timings(tree, repeats))
    names = list(trees)
    best = {name: {k: min(r[k] for r in runs[name]) for k in runs[name][0]} for name in names}
    lines = [
        "| search | " + " | ".join(f"{name} ms" for name in names) + (" | before / this |" if before else " |"),
        "|---|" + "---|" * (len(names) + bool(before)),
    ]
    for key in best[names[-1]]:
        cells = [f"{best[name][key]:.3f}" for name in names]
        ratio = f" | {best[names[0]][key] / best[names[-1]][key]:.2f}x" if before else ""
        lines.append(f"| {key} | " + " | ".join(cells) + ratio + " |")
    print("\n".join(lines))
    print(
        f"\nmedian CPU time of {repeats} calls, best of {rounds} alternating rounds; Python {platform.python_version()}, "
        f"{platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--neighbours", action="store_true", help="time the neighbour searches only")
    parser.add_argument("--before", help="a git revision to time beside this tree (with --neighbours)")
    parser.add_argument("--repeats", type=int, default=50, help="calls per figure (with --neighbours)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (with --neighbours)")
    args = parser.parse_args()
    if args.neighbours:
        neighbours_main(args.before, args.repeats, args.rounds)
    else:
        main()
