"""The auction's warm start sent with a goal set (transport.codec.WarmStart): the robots' own auction
(agent.core.bidder), settled once as if a robot stood on each old goal, so each host only corrects it."""

from __future__ import annotations

import numpy as np

from agent.core.bidder import Participant
from agent.core.params import RobotParams

from .goals import GoalError


def goal_matching(a: np.ndarray, b: np.ndarray, eps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For each goal of ``b``, the goal of ``a`` matched to it by the settled auction, and its prices in
    ``eps``-equilibrium (lowest zero; eps: epsilon_A). Raises GoalError unless both sets have one size."""
    a, b = np.asarray(a, float).reshape(-1, 2), np.asarray(b, float).reshape(-1, 2)
    if len(a) != len(b) or len(a) == 0:
        raise GoalError(f"goal matching needs two non-empty goal sets of one size, not {len(a)} and {len(b)}")
    robots = list(range(len(a)))
    auction = Participant(0, b, robots, robots, RobotParams().assign_eps if eps is None else eps)
    goal = auction.settle_alone(a)
    matched = np.empty(len(b), np.int64)
    matched[goal] = robots
    price = np.asarray(auction.board.price, float)
    return matched, price - price.min()
