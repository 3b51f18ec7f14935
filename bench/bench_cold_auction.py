"""The auction's cold start by size (issue 43): the central engine's settling of a new image's goal
set on a fresh board (``Participant.settle_alone``), paper-sequence-10000's first image at each robot
count, from the scene's initial poses. Per size: wall and CPU time, Jacobi rounds and bids, one to
one, and with ``--optimal`` the gap to scipy's ``linear_sum_assignment`` on the same positions against
the bound N (epsilon_A + Delta C) (a dense N x N cost matrix: the benchmark's, never the run's).

    .venv/bin/python -m bench.bench_cold_auction --sizes 1000,3000,10000 [--optimal]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from agent.core.bidder import Participant
from agent.core.params import RobotParams
from coordinator.scene import load_scene
from sim.central.engine import _step_goals
from transport.codec import as_sent

from .common import write_results


def cold_start(robots: int, optimal: bool) -> str:
    """One size's row of the table."""
    scene = load_scene("paper-sequence-10000", robots=robots)
    params = RobotParams.from_dict(scene.robot)
    pixels = np.arange(robots)
    goals, _, _ = _step_goals(scene, 0, pixels)
    position = as_sent(scene.poses)[:, :2]
    wall, cpu = time.perf_counter(), time.process_time()
    part = Participant(0, goals, pixels.tolist(), pixels.tolist(), params.assign_eps, params.assign_hysteresis)
    goal = part.settle_alone(position)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    one_to_one = len(set(goal.tolist())) == robots and bool((goal >= 0).all())
    gap = bound = "-"
    if optimal:
        from scipy.optimize import linear_sum_assignment

        cost = ((position[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(cost)
        gap = f"{cost[pixels, goal].sum() - cost[rows, cols].sum():.4g}"
        bound = f"{robots * (params.assign_eps + params.assign_hysteresis):.4g}"
    return f"| {robots} | {wall:.2f} | {cpu:.2f} | {part.rounds} | {part.bids} | {one_to_one} | {gap} | {bound} |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,3000,10000", help="robot counts")
    parser.add_argument("--optimal", action="store_true", help="also scipy's optimum (minutes at 10,000)")
    args = parser.parse_args()
    lines = [
        "| robots | settle wall s | CPU s | rounds | bids | one to one | cost - optimum | N (eps_A + Delta C) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for robots in (int(n) for n in args.sizes.split(",")):
        lines.append(cold_start(robots, args.optimal))
        print(lines[-1], flush=True)
    command = f".venv/bin/python -m bench.bench_cold_auction --sizes {args.sizes}" + " --optimal" * args.optimal
    write_results("cold_auction", "The auction's cold start by size (central engine)", command, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
