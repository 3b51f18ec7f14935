"""The auction's goal tree (agent.core.bidding): a robot ranks the goals near it and those whose
price makes them competitive, not every goal, and its rankings are those of a scan of every goal,
so the agreement is what it was: one to one, within N (epsilon_A + Delta C) of the optimum."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.core.bidder import Participant
from agent.core.bidding import goal_tree

EPS, HYSTERESIS = 1e-3, 5e-3


def test_goal_tree_holds_every_goal_once_in_boxes_that_hold_them() -> None:
    """Every goal is in exactly one leaf, and each node's box holds its goals."""
    goals = np.random.default_rng(4).uniform(-5, 5, (1001, 2))
    order, left, right, start, end, box = goal_tree(goals)
    assert sorted(order.tolist()) == list(range(len(goals)))
    leaves = np.flatnonzero(left < 0)
    assert sum(int(end[n] - start[n]) for n in leaves) == len(goals)
    for node in range(len(box)):
        pts = goals[order[start[node] : end[node]]]
        assert (pts[:, 0] >= box[node, 0]).all() and (pts[:, 0] <= box[node, 1]).all()
        assert (pts[:, 1] >= box[node, 2]).all() and (pts[:, 1] <= box[node, 3]).all()
        if left[node] >= 0:
            assert (start[left[node]], end[right[node]]) == (start[node], end[node])


@pytest.mark.parametrize("board", ["uniform", "grid", "graded"])
def test_rankings_by_the_tree_are_those_over_every_goal(board: str) -> None:
    """After bids have raised prices here and there (and on a grid, where values tie; and from prices
    that climb across the goals, as a warm board's do, where the tree bounds its nodes by a plane
    under their prices), each robot's best goal and value are a scan's over every goal, the lower
    index first among equals."""
    rng = np.random.default_rng(7)
    n = 300
    if board == "grid":
        xs = np.arange(20, dtype=float) * 0.25
        goals = np.stack(np.meshgrid(xs, xs), axis=-1).reshape(-1, 2)[:n]
        pos = np.round(rng.uniform(-1, 6, (n, 2)) * 4) / 4
    else:
        goals, pos = rng.uniform(-3, 3, (n, 2)), rng.uniform(-6, 0, (n, 2))
    part = Participant(1, goals, range(n), range(n), EPS, HYSTERESIS)
    if board == "graded":  # robots to one side pay more for the near goals, and the prices say so
        part.board.price[:] = 12.0 * (3.0 - goals[:, 0]) + 2.0 * goals[:, 1] + rng.uniform(0, 4, n)
        part.board.version += 1
    part.begin_block(pos)
    for _ in range(40):
        part.bid()
        best, value = part.ranking()
        values = -((pos[:, None, :] - goals[None, :, :]) ** 2).sum(-1) - part.board.price
        np.testing.assert_array_equal(best, values.argmax(axis=1))
        np.testing.assert_array_equal(value, values.max(axis=1))


def cold_start(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A new image far from the robots: robots in a block to one side, goals on a ring."""
    side = int(np.ceil(np.sqrt(n)))
    cells = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1).reshape(-1, 2)[:n]
    pos = cells * 0.1 + rng.normal(0, 0.01, (n, 2)) + np.array([-12.0, 0.0])
    angle, radius = rng.uniform(0, 2 * np.pi, n), rng.uniform(3.0, 4.0, n)
    return pos, np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def dual_bound(cost: np.ndarray, price: np.ndarray) -> float:
    """A lower bound of the optimal assignment's cost from any prices (linear programming duality):
    every robot's cheapest goal net of its price, plus every price, is at most any one-to-one
    assignment's cost. The auction's own prices make it tight (Bertsekas 1991)."""
    return float((cost + price).min(axis=1).sum() - price.sum())


# 3000 goals: scipy's optimum takes half a minute; the dual bound of the auction's prices is a
# certificate of the same check (the bound is at most the optimum) in a fraction of a second
@pytest.mark.parametrize("n", [1000, pytest.param(3000, marks=pytest.mark.slow)])
def test_cold_start_is_one_to_one_and_within_n_epsilon_of_the_optimum(n: int) -> None:
    """The central engine's cold start (settle_alone on a fresh board): every robot its own goal,
    at most N (epsilon_A + Delta C) above the optimal assignment: scipy's (at 1000), and a lower bound
    of it from the board's prices (at every size)."""
    rng = np.random.default_rng(n)
    pos, goals = cold_start(rng, n)
    part = Participant(1, goals, range(n), range(n), EPS, HYSTERESIS)
    goal = part.settle_alone(pos)
    assert len(set(goal.tolist())) == n and (goal >= 0).all()
    cost = ((pos[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
    ours, slack = cost[np.arange(n), goal].sum(), n * (EPS + HYSTERESIS) + 1e-9
    assert ours <= dual_bound(cost, part.board.price) + slack
    if n <= 1000:
        rows, cols = linear_sum_assignment(cost)
        assert dual_bound(cost, part.board.price) <= cost[rows, cols].sum() + 1e-6  # the bound is one
        assert ours <= cost[rows, cols].sum() + slack
