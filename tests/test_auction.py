"""The goal auction's pure core against scipy's optimal assignment (paper 5.1.1)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.core.auction import AuctionView, Bid, make_bid, merge, solve


def _cost(positions, goals, owner):
    return sum(float(np.sum((goals[j] - positions[owner[j]]) ** 2)) for j in range(len(goals)) if owner[j] >= 0)


@pytest.mark.parametrize("n, seed", [(5, 0), (14, 1), (14, 2), (40, 3), (80, 4)])
def test_within_n_epsilon_of_optimal_and_one_to_one(n, seed):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-1, 1, (n, 2))
    goals = rng.uniform(-0.5, 0.5, (n, 2))
    eps = 1e-3
    view, _ = solve({i: positions[i] for i in range(n)}, goals, eps)
    assert sorted(view.owner.tolist()) == list(range(n))
    cost = ((goals[None] - positions[:, None]) ** 2).sum(-1)
    r, c = linear_sum_assignment(cost)
    assert _cost(positions, goals, view.owner) <= cost[r, c].sum() + n * eps + 1e-12


def test_grid_ties_are_broken_the_same_way_every_time():
    g = np.array([(x, y) for x in range(4) for y in range(4)], float) * 0.1
    p = g + 1.0  # every robot equally far from many goals
    a, _ = solve({i: p[i] for i in range(16)}, g, 1e-3)
    b, _ = solve({i: p[i] for i in range(16)}, g, 1e-3)
    assert np.array_equal(a.owner, b.owner) and np.array_equal(a.prices, b.prices)


def test_warm_start_keeps_assignment_when_nothing_moved_and_takes_one_round():
    rng = np.random.default_rng(5)
    positions = {i: p for i, p in enumerate(rng.uniform(-1, 1, (20, 2)))}
    goals = rng.uniform(-1, 1, (20, 2))
    view, _ = solve(positions, goals, 1e-3)
    again, rounds = solve(positions, goals, 1e-3, view=view)
    assert rounds == 1 and np.array_equal(again.owner, view.owner)


def test_hysteresis_keeps_a_goal_against_a_small_gain():
    goals = np.array([[0.0, 0.0], [1.0, 0.0]])
    view = AuctionView(np.zeros(2), np.array([-1, 0]))  # robot 0 holds goal 1
    pos = np.array([0.45, 0.0])  # goal 0 is better by 1 - 0.55^2 - 0.45^2 ... = 0.1 m^2
    assert not make_bid(0, pos, goals, view, eps=1e-3).holds
    assert make_bid(0, pos, goals, view, eps=1e-3, hysteresis=0.2).holds


def test_merge_highest_bid_wins_ties_to_lower_id_and_outbid_owner_loses():
    view = AuctionView(np.array([1.0, 0.0]), np.array([7, -1]))
    out, changes = merge(view, [Bid(3, 0, 2.0, False), Bid(2, 0, 2.0, False), Bid(5, 1, 0.5, False)])
    assert out.owner.tolist() == [2, 5] and out.prices.tolist() == [2.0, 0.5] and changes == 2
    # a lower bid than the current price does not take the goal
    out2, changes2 = merge(out, [Bid(9, 0, 1.5, False)])
    assert out2.owner[0] == 2 and changes2 == 0


def test_deadlock_penalty_moves_a_robot_off_its_goal():
    goals = np.array([[0.0, 0.0], [0.3, 0.0]])
    positions = {0: np.array([0.0, 0.05]), 1: np.array([0.3, 0.05])}
    view, _ = solve(positions, goals, 1e-4)
    assert view.goal_of(0) == 0
    penalty = {0: np.array([1.0, 0.0]), 1: np.zeros(2)}  # C_d on robot 0's goal
    view2, _ = solve(positions, goals, 1e-4, view=view, penalties=penalty)
    assert view2.goal_of(0) == 1 and view2.goal_of(1) == 0
