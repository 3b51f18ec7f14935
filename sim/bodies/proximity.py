"""The world's robot-robot contact search (sim.bodies.world._ContactWatch, compiled in sim.bodies.contacts),
and each robot's nearest other, on agent.core.grid's grid.

Only +, -, * and sqrt touch the coordinates, (xa - xb)^2 + (ya - yb)^2 with a < b, so the distances equal
numpy's to the bit. Positions must be finite.
"""

from __future__ import annotations

import numpy as np

from agent.core.grid import nearest
from sim.bodies import contacts


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
    done, best, i, j, hits, depth = contacts.close_pairs(xy, r, reach, motion, bound, int(first_row), int(budget))
    if not done:
        return None
    return float(best), int(i), int(j), hits, depth.T


def nearest_other(points: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's nearest other point within ``reach`` (N, 2): its index (-1: none) and distance."""
    xy = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
    ids = np.arange(len(xy), dtype=np.int64)
    other = nearest(xy, ids, xy, ids, reach, 1)[:, 0]
    has = other >= 0
    distance = np.full(len(xy), np.inf)
    distance[has] = np.hypot(*(xy[has] - xy[other[has]]).T)
    return other, distance
