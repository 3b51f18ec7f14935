"""Who is near whom, on a uniform grid of cells as wide as the distance asked about, compiled with
numba: every pair within that distance lies in the 3 x 3 cells around either one's cell.

- `grid_cells`: the grid itself (each point's cell, the points sorted by cell), shared by the
  searches here and in sim.proximity.
- `nearest_within`: each robot's nearest neighbours within reach, as RVO2's k-d tree finds them: the
  same neighbours as scipy's kd-tree, ties in distance by index (tests/test_proximity.py), without
  the tree's build and the bookkeeping around it. The RVO2-shaped engine uses it (agent.core.rvo).

Agent processes do not import this module (numba is slow to start); the central engines import it
where they step. sim.proximity compiles `grid_cells` into its own functions: numba's cache keys on
that file, so after changing this one touch sim/proximity.py too.

Positions must be finite.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["grid_cells", "nearest_within"]

CELLS_PER_ROBOT = 16  # the grid's cell count is capped at this many per robot (coarser cells past it)
RINGS = 4  # nearest_within's cells are reach / RINGS wide


@njit(cache=True)
def grid_cells(x: np.ndarray, y: np.ndarray, width: float) -> tuple:
    """Cells of the points, at least ``width`` wide (wider where there would be too many): per point
    its cell (cx, cy); the grid's size (nx, ny); cell starts and the points sorted by cell (the
    points of cell c = gx * ny + gy are order[start[c]:start[c + 1]]); the grid's origin (x0, y0)
    and cell size."""
    n = x.size
    x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
    # a little wider, so two points within a width are never two cells apart by rounding
    cell = width * (1.0 + 1e-6) + 1e-12
    cap = max(CELLS_PER_ROBOT * n, 1024)
    while ((x1 - x0) / cell + 1.0) * ((y1 - y0) / cell + 1.0) > cap:
        cell *= 2.0
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        cx[i] = min(int((x[i] - x0) / cell), nx - 1)
        cy[i] = min(int((y[i] - y0) / cell), ny - 1)
        start[cx[i] * ny + cy[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cx[i] * ny + cy[i]
        order[fill[c]] = i
        fill[c] += 1
    return cx, cy, nx, ny, start, order, x0, y0, cell


@njit(cache=True, nogil=True)
def nearest_within(position: np.ndarray, reach: float, m: int) -> np.ndarray:
    """(N, m) indices of each robot's m nearest other robots strictly within ``reach`` (distance
    sqrt(dx^2 + dy^2)), nearest first (equal distances: the lower index first), -1 past the last.

    Cells are reach / RINGS wide; each robot looks at the rings of cells around its own, nearest
    ring first, and stops when it has m neighbours all nearer than the next ring can be (in a crowd
    the m nearest are much nearer than reach, as RVO2's k-d tree shrinks its range)."""
    n = position.shape[0]
    out = np.full((n, m), -1, np.int64)
    if n == 0 or m == 0:
        return out
    x, y = position[:, 0].copy(), position[:, 1].copy()
    cx, cy, nx, ny, start, order, _, _, cell = grid_cells(x, y, reach / RINGS)
    rings = int(reach / cell) + 1  # a point r rings away is at least (r - 1) cells away
    # how far rounding may move a point across a cell border: far below a cell, above any ulp
    slack = 1e-9 * (cell + max(np.abs(x).max(), np.abs(y).max()))
    best_d = np.empty(m)
    for i in range(n):
        k = 0  # neighbours kept so far, sorted by (distance, index)
        for r in range(rings + 1):
            if k == m and (r - 1) * cell - slack > best_d[m - 1]:
                break
            for gx in range(max(cx[i] - r, 0), min(cx[i] + r + 1, nx)):
                edge = gx == cx[i] - r or gx == cx[i] + r
                step = 1 if edge else 2 * r  # inside the ring's columns only its top and bottom cells
                for gy in range(cy[i] - r, cy[i] + r + 1, max(step, 1)):
                    if gy < 0 or gy >= ny:
                        continue
                    c = gx * ny + gy
                    for a in range(start[c], start[c + 1]):
                        j = order[a]
                        if j == i:
                            continue
                        dx, dy = x[j] - x[i], y[j] - y[i]
                        d = np.sqrt(dx * dx + dy * dy)
                        if not d < reach or (
                            k == m and (d > best_d[m - 1] or (d == best_d[m - 1] and j > out[i, m - 1]))
                        ):
                            continue
                        p = min(k, m - 1)  # insert (d, j) in order, dropping the last when full
                        while p > 0 and (best_d[p - 1] > d or (best_d[p - 1] == d and out[i, p - 1] > j)):
                            best_d[p] = best_d[p - 1]
                            out[i, p] = out[i, p - 1]
                            p -= 1
                        best_d[p] = d
                        out[i, p] = j
                        k = min(k + 1, m)
    return out
