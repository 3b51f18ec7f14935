"""Deadlock detection (paper 5.5.5): near the goal but not on it, v_cf far from v_pref for N_d iterations."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from agent.core.control import blocked
from agent.core.params import RobotParams
from agent.core.policy import count_blocked

P = RobotParams()


def test_blocked_only_near_the_goal_and_not_on_it() -> None:
    pref = np.array([[0.1, 0.0]] * 4)
    stuck = np.zeros((4, 2))
    to_goal = np.array([[0.005, 0.0], [0.1, 0.0], [1.0, 0.0], [np.nan, np.nan]])  # on it, near, far, no goal
    assert blocked(P, to_goal, pref, stuck).tolist() == [False, True, False, False]
    assert not blocked(P, to_goal, pref, pref).any()  # moving as it prefers: not blocked


def test_a_robot_a_few_ulps_either_side_of_the_goal_tolerance_or_the_near_bound_is_judged_by_its_distance() -> None:
    """Near its goal means goal_tolerance < hypot <= deadlock_near, as math.hypot has it, however close to either
    bound, and for bounds too small to square (blocked reads squares first where they decide it)."""
    rng = np.random.default_rng(5)
    for tolerance, near in ((P.goal_tolerance, P.deadlock_near), (1e-170, 1e-160)):
        params = dataclasses.replace(P, goal_tolerance=tolerance, deadlock_near=near)
        lengths = [r * (1.0 + s) for r in (tolerance, near) for s in (-1e-10, -2e-16, 0.0, 2e-16, 1e-10)]
        angles = rng.uniform(0, 2 * math.pi, len(lengths))
        to_goal = np.column_stack([np.multiply(lengths, np.cos(angles)), np.multiply(lengths, np.sin(angles))])
        expected = [tolerance < math.hypot(x, y) <= near for x, y in to_goal.tolist()]
        pref, stuck = np.tile([1.0, 0.0], (len(lengths), 1)), np.zeros((len(lengths), 2))
        assert blocked(params, to_goal, pref, stuck).tolist() == expected
        assert 0 < sum(expected) < len(expected)


def test_a_robot_slowed_by_a_crowd_but_making_headway_is_not_blocked() -> None:
    pref = np.array([[0.4, 0.0], [0.4, 0.0]])
    to_goal = np.array([[0.2, 0.0], [0.2, 0.0]])
    slowed = np.array([[0.1, 0.05], [0.0, 0.1]])  # toward the goal at 10 cm/s; sideways, no headway
    assert blocked(P, to_goal, pref, slowed).tolist() == [False, True]


def test_deadlock_after_n_d_blocked_iterations_then_the_count_restarts() -> None:
    counts = np.zeros(2, int)
    declared = []
    for k in range(2 * P.deadlock_iterations):
        counts, dead = count_blocked(counts, np.array([True, k % 2 == 0]), P.deadlock_iterations)
        declared.append(dead.copy())
    declared = np.array(declared)
    assert np.flatnonzero(declared[:, 0]).tolist() == [P.deadlock_iterations - 1, 2 * P.deadlock_iterations - 1]
    assert not declared[:, 1].any()  # blocked every other iteration only: never N_d in a row
