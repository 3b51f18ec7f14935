"""The auction's warm start that the coordinator sends with a goal set (transport.codec.WarmStart).

At an image change (paper 7.2) or a keyframe (6.1) the robots stand within millimetres of the last
set's goals, so the coordinator settles the auction once as if a robot stood on each old goal: every
host then starts from that matching and its prices, and its auction only corrects what the
millimetres change. The first set of a run with rounds per tick bounded is matched from where the
robots start. It is the robots' own auction (agent.core.bidder, settled alone as the central engine
settles it): candidate goals from a goal tree, no N x N array, so it scales to large swarms.
"""

from __future__ import annotations

import numpy as np

from agent.core.bidder import Participant
from agent.core.params import RobotParams

from .goals import GoalError


def goal_matching(a: np.ndarray, b: np.ndarray, eps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For each goal of ``b``, the goal of ``a`` matched to it, and prices in ``eps``-equilibrium for
    that matching, lowest zero: the auction of robots standing on the goals of ``a`` for the goals
    of ``b``, settled (its total squared distance within len(a) ``eps`` of the least). ``eps``: the
    robots' epsilon_A (default RobotParams'). Raises GoalError unless both sets have one size."""
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
