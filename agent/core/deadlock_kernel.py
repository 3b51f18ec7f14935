"""Deadlock detection's blocked test (agent.core.deadlock.blocked) compiled with numba, one robot at a
time: the central engine's fast path (agent.core.policy.act with ``compiled``); agent processes
keep the numpy code and never load numba.

Why: the numpy test is a dozen whole-batch array operations, each a pass over a thousand robots
that allocates; per robot it is a handful of float operations. The same operations in the same
order (numpy's hypot is the C library's, as numba's; a two-element sum is one addition), so the
same robots are blocked, to the bit (tests/test_deadlock.py).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def blocked_core(position, goal, has_goal, pref_velocity, velocity, tolerance, near_goal, speed):
    """(B,) bool: deadlock.blocked with to_goal = goal - position where ``has_goal``, else none."""
    b = len(position)
    out = np.zeros(b, np.bool_)
    for i in range(b):
        if not has_goal[i]:
            continue  # to_goal NaN: never near
        tx, ty = goal[i, 0] - position[i, 0], goal[i, 1] - position[i, 1]
        d = np.hypot(tx, ty)
        if not (np.isfinite(d) and d > tolerance and d <= near_goal):
            continue
        vx, vy = velocity[i, 0], velocity[i, 1]
        gap = np.hypot(pref_velocity[i, 0] - vx, pref_velocity[i, 1] - vy)
        headway = (vx * tx + vy * ty) / d
        out[i] = gap > speed and headway < speed
    return out
