"""The world's robot-robot contact search (sim.bodies.world._ContactWatch) on agent.core.grid's grid.

Only +, -, * and sqrt touch the coordinates, (xa - xb)^2 + (ya - yb)^2 with a < b, so the distances equal
numpy's to the bit. Positions must be finite.
"""

from __future__ import annotations

import numpy as np

from agent.core import grid


def close_pairs(
    traj: np.ndarray,
    radius: np.ndarray,
    reach: float,
    motion: float,
    first_row: int,
    *,
    bound: float = np.inf,
    budget: int = -1,
) -> tuple[float, int, int, np.ndarray, np.ndarray] | None:
    """Robot-robot clearance and overlaps over the states traj (rows, N, 2) of discs of radius (N,).

    Looks at every pair within ``reach`` in traj[0]; ``motion`` bounds any disc's distance from traj[0].
    Returns (clearance, i, j, pairs, depth): the smallest clearance over those pairs (+inf if none) and a
    pair that has it (-1, -1 if none); the pairs (H, 2), i < j, that overlap in a row from ``first_row`` on,
    and their depths r_i + r_j - d (rows - first_row, H). ``bound``: a known row-0 clearance of a pair
    within reach, to skip pairs that can beat neither it nor overlap. None if more than ``budget`` pairs
    would be looked at (negative: no limit).
    """
    budget = np.iinfo(np.int64).max if budget < 0 else budget
    xy, r = np.ascontiguousarray(traj, dtype=float), np.ascontiguousarray(radius, dtype=float)
    done, best, i, j, hits, depth = grid.close_pairs(xy, r, reach, motion, bound, int(first_row), int(budget))
    if not done:
        return None
    return float(best), int(i), int(j), hits, depth.T
