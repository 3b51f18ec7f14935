"""Deadlock detection (paper 5.5.5): near the goal but not on it, v_cf far from v_pref for N_d iterations."""

from __future__ import annotations

import numpy as np

from agent.core.deadlock import blocked, count_blocked
from agent.core.params import RobotParams

P = RobotParams()


def test_blocked_only_near_the_goal_and_not_on_it() -> None:
    pref = np.array([[0.1, 0.0]] * 4)
    stuck = np.zeros((4, 2))
    to_goal = np.array([[0.005, 0.0], [0.1, 0.0], [1.0, 0.0], [np.nan, np.nan]])  # on it, near, far, no goal
    assert blocked(P, to_goal, pref, stuck).tolist() == [False, True, False, False]
    assert not blocked(P, to_goal, pref, pref).any()  # moving as it prefers: not blocked


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


def test_the_compiled_blocked_test_blocks_the_same_robots() -> None:
    """The central engine's compiled twin (agent.core.deadlock_kernel) against the numpy test, on
    robots near and far, on and off their goals, with and without a goal, at the thresholds."""
    from agent.core.deadlock_kernel import blocked_core

    rng = np.random.default_rng(7)
    n = 4000
    position = rng.uniform(-1, 1, (n, 2))
    goal = position + rng.uniform(-0.4, 0.4, (n, 2)) * rng.choice([0.0, 0.01, 1.0], (n, 1))
    has_goal = rng.random(n) < 0.8
    velocity = rng.uniform(-0.1, 0.1, (n, 2)) * rng.choice([0.0, 1.0], (n, 1))
    pref = velocity + rng.choice([0.0, P.deadlock_speed, 0.2], (n, 1)) * rng.choice([-1.0, 1.0], (n, 2))
    to_goal = np.where(has_goal[:, None], goal - position, np.nan)
    expected = blocked(P, to_goal, pref, velocity)
    got = blocked_core(position, goal, has_goal, pref, velocity, P.goal_tolerance, P.deadlock_near, P.deadlock_speed)
    assert 100 < expected.sum() < n - 100  # both answers are common
    assert got.tolist() == expected.tolist()
