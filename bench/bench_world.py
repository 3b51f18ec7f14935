"""Micro-benchmark of sim.world.World.step(0.1) (10 substeps of 10 ms) at N = 100 and 1000.

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
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import scipy
from scipy.spatial.distance import pdist

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.core.params import EPUCK as EPUCK_PARAMS  # noqa: E402
from sim.world import Body, World  # noqa: E402

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
    w = World([EPUCK] * n, poses, seed=0)
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
        "## sim.world.World.step(0.1): 10 substeps of 10 ms\n\n"
        "Command: `.venv/bin/python bench/bench_world.py`\n\n"
        f"{env}\n\n{table}\n\n"
        "Scenarios: see the docstring of `bench/bench_world.py`. The last column is the detection a\n"
        "world could do naively (scipy `pdist` over all pairs at each substep, nothing else), for scale.\n"
    )
    print(f"\n{env}\nwritten to {out}")


if __name__ == "__main__":
    main()
