"""The auction's latency compensation (agent.runtime.bid_position): a robot on its way bids from
where it will be when the instance's agreement is adopted."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.runtime import bid_position


def test_a_robot_bids_from_ahead_on_its_way_to_the_goal():
    p = bid_position(np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.4, 0.0]), lead=1.5)
    assert p == pytest.approx([0.6, 0.0])


def test_never_past_the_goal_and_not_without_speed():
    goal = np.array([1.0, 1.0])
    assert bid_position(np.zeros(2), goal, np.array([0.5, 0.5]), lead=10.0) == pytest.approx(goal)
    assert bid_position(np.zeros(2), goal, np.zeros(2), lead=2.0) == pytest.approx([0.0, 0.0])  # blocked
    assert bid_position(goal, goal, np.array([0.1, 0.0]), lead=2.0) == pytest.approx(goal)  # on the goal
    assert bid_position(np.zeros(2), goal, np.array([0.5, 0.5]), lead=0.0) == pytest.approx([0.0, 0.0])


def test_a_robot_that_just_got_another_goal_is_led_toward_it_at_its_speed():
    """The next block freezes right after an agreement, while a robot sent elsewhere still moves as
    it did for its last goal: it will turn, so it bids from ahead on the way to the new one (bidding
    from where it stood sent robots back and forth every block)."""
    goal = np.array([1.0, 0.0])
    ahead = bid_position(np.zeros(2), goal, np.array([-0.3, 0.4]), lead=1.0)  # speed 0.5, moving away
    assert ahead == pytest.approx([0.5, 0.0])


def test_the_optimal_assignment_stands_for_robots_partway_to_their_goals():
    """Why leading is safe: with squared distances, robots that have all covered the same fraction of
    their straight way to optimally assigned goals keep that assignment optimal (seeded instances)."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        start, goals = rng.uniform(-2, 2, (30, 2)), rng.uniform(-2, 2, (30, 2))
        rows, cols = linear_sum_assignment(((start[:, None] - goals[None]) ** 2).sum(-1))
        s = rng.uniform(0.0, 1.0)
        partway = start + s * (goals[cols] - start)
        cost = ((partway[:, None] - goals[None]) ** 2).sum(-1)
        r2, c2 = linear_sum_assignment(cost)
        assert cost[rows, cols].sum() == pytest.approx(cost[r2, c2].sum(), abs=1e-9)
