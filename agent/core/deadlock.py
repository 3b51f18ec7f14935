"""Deadlock detection (paper 5.5.5), over a batch of robots: pure, no clock. Whether a robot is
blocked in an iteration is part of its compiled arithmetic (agent.core.control.blocked); here, the count.

A robot is *blocked* in an iteration when it is near its goal but not on it, its collision-free
velocity differs from its preferred velocity by more than a threshold, and it makes no headway
toward the goal (its collision-free velocity's component toward the goal is below that threshold):
others stand in its way. N_d blocked iterations in a row are a deadlock; the runtime then adds C_d to the robot's cost of that goal
(agent.core.bidder), which triggers a reassignment. A robot already on its goal is never blocked:
yielding to a passing neighbour there is ORCA's shared responsibility, not a deadlock, and penalising
it would pull a robot off a formed image. The headway condition tells a deadlock from a crowd:
robots slowed (not stopped) near their goals are not blocked, and reassigning them would keep a
crowded image from forming.
"""

from __future__ import annotations

import numpy as np


def count_blocked(counts: np.ndarray, now_blocked: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive blocked iterations per robot; returns (new counts, deadlocked now). A declared
    deadlock restarts the count, so a robot still stuck is penalised again N_d iterations later."""
    counts = np.where(now_blocked, counts + 1, 0)
    deadlocked = counts >= iterations
    return np.where(deadlocked, 0, counts), deadlocked
