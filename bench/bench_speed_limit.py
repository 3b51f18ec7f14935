"""The speed limit within hearing (agent.core.policy.heard_speed_limit) side by side with none: a
20-robot circle crossing on the central engine, every state a tick late, hearing only within a short
range. Contacts and least clearance with the limit and with it lifted (patched to no limit).

    .venv/bin/python -m bench.bench_speed_limit
"""

from __future__ import annotations

import numpy as np

import agent.core.policy as policy
from coordinator.scene import load_scene
from sim.central import simulate
from sim.link import InProcessLink

from .common import write_results

REACHES = (0.12, 0.13, 0.15)
SEEDS = (4, 5)


def _run(reach: float, seed: int) -> tuple[int, float, float]:
    scene = load_scene("circle", robots=20, seed=seed, duration=60.0)
    out = simulate(scene, link=InProcessLink(20, late=1.0, reach=reach), progress=None)
    return len(out.contacts), out.min_clearance, float(out.arrays["t"][-1])


def main() -> int:
    limit = policy.heard_speed_limit
    lines = [
        "| range m | seed | contacts (limit, none) | least clearance mm (limit, none) | ended at s (limit, none) |",
        "|---|---|---|---|---|",
    ]
    for reach in REACHES:
        for seed in SEEDS:
            policy.heard_speed_limit = limit
            with_limit = _run(reach, seed)
            policy.heard_speed_limit = lambda params, reach, latency: np.full(np.shape(latency), np.inf)
            without = _run(reach, seed)
            policy.heard_speed_limit = limit
            lines.append(
                f"| {reach} | {seed} | {with_limit[0]}, {without[0]} | {1e3 * with_limit[1]:.1f}, {1e3 * without[1]:.1f} "
                f"| {with_limit[2]:.1f}, {without[2]:.1f} |"
            )
            print(lines[-1], flush=True)
    write_results(
        "speed_limit",
        "Speed within hearing: a short range with late states, with the limit and without",
        ".venv/bin/python -m bench.bench_speed_limit",
        [
            *lines,
            "",
            "Circle of 20 holonomic robots (RVO2's Circle at display scale), central engine, lock-step, every "
            "state heard a tick late (InProcessLink late=1.0) and only within the range. The limit caps the "
            "preferred velocity at (R - 2 r - noise) / (2 (age + 2 dt)); ended at: convergence or the 60 s cap.",
        ],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
