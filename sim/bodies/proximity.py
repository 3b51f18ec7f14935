"""The world's robot-robot detection (sim.bodies.world._ContactWatch.detect) on agent.core.grid's grid.

Every pair whose centres are within ``reach`` in the first state is found on a grid of cells that wide
(such a pair lies in the 3 x 3 cells around either one's cell), then checked in every state. Only +, -, *
and sqrt touch the coordinates, (xa - xb)^2 + (ya - yb)^2 with a < b, so the distances equal numpy's to
the bit. Positions must be finite.
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

    Looks at every pair whose centres are within ``reach`` in traj[0] (and maybe some farther ones);
    ``motion`` bounds how far any disc is from its place in traj[0] in any row. Returns
    (clearance, i, j, pairs, depth): the smallest clearance sqrt(min over rows of d^2) - r_i - r_j
    over those pairs (+inf if none) and a pair that has it (-1, -1 if none); the pairs (H, 2),
    i < j, that overlap (d < r_i + r_j) in a row from ``first_row`` on, and their depths
    r_i + r_j - d (rows - first_row, H). ``bound``: the row-0 clearance of a pair within reach, if
    known; the rows of a pair are skipped when it can neither overlap nor come closer than that (or
    than the smallest clearance found so far). None if more than ``budget`` pairs would be looked at
    (negative: no limit).
    """
    budget = np.iinfo(np.int64).max if budget < 0 else budget
    done, best, i, j, hits, depth = grid.close_pairs(
        np.ascontiguousarray(traj, dtype=float),
        np.ascontiguousarray(radius, dtype=float),
        float(reach),
        float(motion),
        float(bound),
        int(first_row),
        int(budget),
    )
    if not done:
        return None
    return float(best), int(i), int(j), hits, depth.T
