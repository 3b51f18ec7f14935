"""The goal auction's compiled rounds (agent.core.bidding, through agent.core.bidder) against scipy's
optimal assignment and hand-computed cases (paper 5.1.1)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.core.bidder import RECORD, RELEASED, Participant


def _cost(positions, goals, owner):
    return sum(float(np.sum((goals[j] - positions[owner[j]]) ** 2)) for j in range(len(goals)) if owner[j] >= 0)


def _solve(positions: np.ndarray, goals: np.ndarray, eps: float, hysteresis: float = 0.0) -> Participant:
    n = len(positions)
    part = Participant(1, goals, list(range(n)), list(range(n)), eps, hysteresis)
    part.settle_alone(positions)
    return part


@pytest.mark.parametrize("n, seed", [(5, 0), (14, 1), (14, 2), (40, 3), (80, 4)])
def test_within_n_epsilon_of_optimal_and_one_to_one(n, seed):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-1, 1, (n, 2))
    goals = rng.uniform(-0.5, 0.5, (n, 2))
    eps = 1e-3
    part = _solve(positions, goals, eps)
    assert sorted(part.board.owner.tolist()) == list(range(n)) and not part.board.released.any()
    cost = ((goals[None] - positions[:, None]) ** 2).sum(-1)
    r, c = linear_sum_assignment(cost)
    assert _cost(positions, goals, part.board.owner) <= cost[r, c].sum() + n * eps + 1e-12


def test_grid_ties_are_broken_the_same_way_every_time():
    g = np.array([(x, y) for x in range(4) for y in range(4)], float) * 0.1
    p = g + 1.0  # every robot equally far from many goals
    a, b = _solve(p, g, 1e-3), _solve(p, g, 1e-3)
    assert np.array_equal(a.board.owner, b.board.owner) and np.array_equal(a.board.price, b.board.price)
    assert sorted(a.board.owner.tolist()) == list(range(16))


def test_warm_start_keeps_assignment_when_nothing_moved_and_bids_nothing():
    rng = np.random.default_rng(5)
    positions = rng.uniform(-1, 1, (20, 2))
    goals = rng.uniform(-1, 1, (20, 2))
    part = _solve(positions, goals, 1e-3)
    owner, bids, rounds = part.board.owner.copy(), part.bids, part.rounds
    part.settle_alone(positions)
    assert (part.bids, part.rounds) == (bids, rounds) and np.array_equal(part.board.owner, owner)


def test_a_bid_raises_the_price_by_best_minus_second_best_plus_epsilon():
    """Hand-computed: a robot at the origin, goals at (1, 0) and (2, 0): net values -1 and -4 at
    prices zero, so it bids 3 + epsilon on the first; with one goal, epsilon twice."""
    part = Participant(1, np.array([[1.0, 0.0], [2.0, 0.0]]), [0], [0], 1e-3)
    part.begin(part.phases - 1, {0: np.zeros(2)})  # the final phase: epsilon_A
    assert part.goal.tolist() == [0] and part.board.owner.tolist() == [0, -1]
    assert part.board.price.tolist() == [3.0 + 1e-3, 0.0]
    one = Participant(1, np.array([[1.0, 0.0]]), [0], [0], 1e-3)
    one.begin(0, {0: np.zeros(2)})
    assert one.board.price.tolist() == [0.0 + (-1.0 - (-1.0 - 1e-3)) + 1e-3]  # in the bid's float operations


@pytest.mark.parametrize("hysteresis, keeps", [(0.0, False), (0.2, True)])
def test_hysteresis_keeps_a_goal_against_a_small_gain(hysteresis, keeps):
    goals = np.array([[0.0, 0.0], [1.0, 0.0]])
    part = Participant(1, goals, [0], [0], 1e-3, hysteresis)
    part.board.owner[1] = 0  # robot 0 holds goal 1
    part.goal[0] = 1
    pos = np.array([0.45, 0.0])  # goal 0 is better by 0.55^2 - 0.45^2 = 0.1 m^2
    part.begin(part.phases - 1, {0: pos})  # the final phase: slack epsilon_A + Delta C
    assert part.goal[0] == (1 if keeps else 0) and part.bids == (0 if keeps else 1)


def test_merge_highest_bid_wins_ties_to_lower_id_and_outbid_owner_loses():
    part = Participant(1, np.zeros((2, 2)), list(range(10)), [], 1e-3)
    board = part.board
    board.price[:], board.owner[:] = [1.0, 0.0], [7, -1]

    def merge(goal, price, robot, released=False) -> bool:  # records of another host, as absorb takes them
        recs = np.zeros(len(goal), RECORD)
        recs["goal"], recs["price"], recs["robot"], recs["flags"] = goal, price, robot, RELEASED if released else 0
        return part.absorb(0, 0, 0, recs)

    assert merge([0, 0, 1], [2.0, 2.0, 0.5], [3, 2, 5])
    assert board.owner.tolist() == [2, 5] and board.price.tolist() == [2.0, 0.5]
    # a lower bid than the current price does not take the goal; nor does a higher robot id at an equal price
    assert not merge([0, 0], [1.5, 2.0], [9, 4])
    assert not merge([0], [2.0], [4]) and board.owner[0] == 2
    # at an equal price and robot, "released" is the greater record
    assert merge([0], [2.0], [2], released=True) and board.released.tolist() == [True, False]
    assert not board.holds(np.array([2]), np.array([0]))[0]


def test_deadlock_penalty_moves_a_robot_off_its_goal():
    goals = np.array([[0.0, 0.0], [0.3, 0.0]])
    positions = np.array([[0.0, 0.05], [0.3, 0.05]])
    part = _solve(positions, goals, 1e-4)
    assert part.agreed == {0: 0, 1: 1}
    part.penalise(0, 0, 1.0)  # C_d on robot 0's goal
    part.settle_alone(positions)
    assert part.agreed == {0: 1, 1: 0}
