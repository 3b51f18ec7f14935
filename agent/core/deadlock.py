"""Deadlock detection (paper 5.5.5), over a batch of robots: pure, no clock.

A robot is *blocked* in an iteration when it is near its goal but not on it, and its collision-free
velocity differs from its preferred velocity by more than a threshold: others stand in its way. N_d
blocked iterations in a row are a deadlock; the runtime then adds C_d to the robot's cost of that goal
(agent.core.bidder), which triggers a reassignment. A robot already on its goal is never blocked:
yielding to a passing neighbour there is ORCA's shared responsibility, not a deadlock, and penalising
it would pull a robot off a formed image.
"""
from __future__ import annotations

import numpy as np

from .params import RobotParams


def blocked(params: RobotParams, distance_to_goal: np.ndarray, pref_velocity: np.ndarray,
            velocity: np.ndarray) -> np.ndarray:
    """(B,) bool: near the goal (not on it) with v_cf far from v_pref. NaN distance: no goal."""
    d = np.asarray(distance_to_goal, float)
    near = np.isfinite(d) & (d > params.goal_tolerance) & (d <= params.deadlock_near)
    gap = np.hypot(*(np.asarray(pref_velocity) - np.asarray(velocity)).T)
    return near & (gap > params.deadlock_speed)


def count_blocked(counts: np.ndarray, now_blocked: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive blocked iterations per robot; returns (new counts, deadlocked now). A declared
    deadlock restarts the count, so a robot still stuck is penalised again N_d iterations later."""
    counts = np.where(now_blocked, counts + 1, 0)
    deadlocked = counts >= iterations
    return np.where(deadlocked, 0, counts), deadlocked
