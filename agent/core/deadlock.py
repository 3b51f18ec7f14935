"""Deadlock detection (paper 5.5.5), over a batch of robots: pure, no clock; here, the count of blocked iterations.

A robot is *blocked* (agent.core.control.blocked, compiled) when it is near its goal but not on it, its
collision-free velocity differs from its preferred one by more than a threshold, and it makes no headway toward
the goal. N_d blocked iterations in a row are a deadlock: the runtime adds C_d to the robot's cost of that goal
(agent.core.bidder), which triggers a reassignment. A robot on its goal is never blocked (yielding there is ORCA's
shared responsibility; penalising it would pull it off a formed image), and the headway condition tells a deadlock
from a crowd, whose slowed robots reassigned would keep the image from forming.
"""

from __future__ import annotations

import numpy as np


def count_blocked(counts: np.ndarray, now_blocked: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive blocked iterations per robot; returns (new counts, deadlocked now). A declared
    deadlock restarts the count, so a robot still stuck is penalised again N_d iterations later."""
    counts = np.where(now_blocked, counts + 1, 0)
    deadlocked = counts >= iterations
    return np.where(deadlocked, 0, counts), deadlocked
