"""Per-robot control-step time (issue 3): what one agent spends per tick on preferred velocity,
ORCA / NH-ORCA and controls, with 10 neighbours; alone (B = 1, one process per robot) and per
robot in a host batch (B = 250). Reference in the same run: RVO2's per-agent share of `do_step`
(pyrvo, 250 agents with 10 neighbours each).

    .venv/bin/python -m bench.bench_control_step
"""

from __future__ import annotations

import time

import numpy as np

from agent.core.params import DIFFDRIVE, HOLONOMIC, RobotParams
from agent.core.step import NeighbourStates, control_step

from .common import write_results


def neighbours(batch: int, m: int, rng: np.random.Generator) -> NeighbourStates:
    nb = NeighbourStates.empty(batch, m)
    ang = rng.uniform(0, 2 * np.pi, (batch, m))
    dist = rng.uniform(0.1, 0.5, (batch, m))
    nb.position[:] = np.stack([dist * np.cos(ang), dist * np.sin(ang)], axis=-1)
    nb.velocity[:] = rng.normal(0, 0.05, (batch, m, 2))
    nb.radius[:] = 0.045
    nb.age[:] = 0.1
    nb.valid[:] = True
    return nb


def per_robot_ms(kinematics: str, batch: int, repeat: int) -> float:
    rng = np.random.default_rng(0)
    p = RobotParams(kinematics=kinematics)
    nb = neighbours(batch, 10, rng)
    args = (
        p,
        np.arange(batch),
        np.zeros((batch, 2)),
        rng.uniform(-3, 3, batch),
        rng.normal(0, 0.05, (batch, 2)),
        rng.uniform(-1, 1, (batch, 2)),
        nb,
        None,
    )
    control_step(*args)
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(repeat):
            control_step(*args)
        best = min(best, (time.perf_counter() - t) / repeat / batch * 1000)
    return best


def rvo2_per_agent_ms() -> float | None:
    try:
        import pyrvo
    except ImportError:
        return None

    sim = pyrvo.RVOSimulator(0.1, 0.6, 10, 2.0, 2.0, 0.045, 0.13)
    rng = np.random.default_rng(0)
    side = 16
    for k in range(250):
        sim.add_agent((float((k % side) * 0.12 + rng.uniform(0, 0.01)), float((k // side) * 0.12)))
    for k in range(250):
        vx, vy = rng.normal(0, 0.1, 2)
        sim.set_agent_pref_velocity(k, (float(vx), float(vy)))
    t = time.perf_counter()
    for _ in range(50):
        sim.do_step()
    return (time.perf_counter() - t) / 50 / 250 * 1000


def main() -> None:
    rows = ["| kinematics | batch (robots per call) | ms per robot per step |", "|---|---|---|"]
    for kin in [HOLONOMIC, DIFFDRIVE]:
        for batch, repeat in [(1, 200), (250, 5)]:
            ms = per_robot_ms(kin, batch, repeat)
            rows.append(f"| {kin} | {batch} | {ms:.3f} |")
            print(rows[-1], flush=True)
    ref = rvo2_per_agent_ms()
    rows.append(
        f"| RVO2 (pyrvo), holonomic | 250 (do_step) | {ref:.4f} |"
        if ref is not None
        else "| RVO2 (pyrvo) | - | not installed |"
    )
    write_results(
        "control_step",
        "Control step per robot, 10 neighbours (issue 3)",
        ".venv/bin/python -m bench.bench_control_step",
        rows + ["", "Target: at most 1 ms per robot with 10 neighbours inside an agent process (batch 1)."],
    )


if __name__ == "__main__":
    main()
