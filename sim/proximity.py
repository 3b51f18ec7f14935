"""Who is near whom, on a uniform grid of cells as wide as the distance asked about, compiled with
numba: every pair within that distance lies in the 3 x 3 cells around either one's cell.

The grid is agent.core.neighbour_grid's (`grid_cells`), which the searches here share.

- `nearest_heard_compiled`: each robot's nearest neighbours among the states it heard (the in-process
  link's search, sim.link): each grid column near a robot is read as one run of points, over the
  cells the disc of reach covers there.
- `close_pairs`: the world's robot-robot detection (sim.world.World._detect): every pair whose
  centres are within ``reach`` in the first state is found on the grid, then checked in every
  state. It returns the smallest clearance over the pairs checked and the pairs that overlap, with
  their depths (a kd-tree costs its build every step, even with no pair in reach). Only +, -, *
  and sqrt touch the coordinates, in the order the numpy code used ((xa - xb)^2 + (ya - yb)^2 with
  a < b, then sqrt), so the distances are the same to the bit (numba does not fuse multiply-adds
  without fastmath).

Positions must be finite.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from agent.core.neighbour_grid import grid_cells
from agent.core.step import NeighbourStates
from agent.neighbour_table import Heard

__all__ = ["close_pairs", "nearest_heard_compiled"]

COLUMN_PARTS = 2  # nearest_heard_compiled's cells are reach / COLUMN_PARTS wide


@njit(cache=True, nogil=True)
def _close_pairs(
    traj: np.ndarray,
    radius: np.ndarray,
    reach: float,
    motion: float,
    bound: float,
    first_row: int,
    budget: int,
) -> tuple:
    """close_pairs, compiled: (done, clearance, i, j, pairs, depth (H, rows - first_row))."""
    rows, n = traj.shape[0], traj.shape[1]
    x, y = traj[0, :, 0].copy(), traj[0, :, 1].copy()
    cx, cy, nx, ny, start, order, _, _, _ = grid_cells(x, y, reach)
    reach2 = reach * reach
    slack = 2.0 * motion + 1e-9  # no row brings a pair closer than its row-0 distance less this
    best, best_i, best_j = np.inf, -1, -1
    cap = 64
    hits = np.empty((cap, 2), dtype=np.int64)
    depth = np.empty((cap, rows - first_row))
    n_hits = 0
    d2 = np.empty(rows)
    scanned = 0
    for i in range(n):
        for ax in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for ay in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = ax * ny + ay
                for k in range(start[c], start[c + 1]):
                    j = order[k]
                    if j <= i:
                        continue
                    scanned += 1
                    if scanned > budget:
                        return False, best, best_i, best_j, hits[:0], depth[:0]
                    dx = x[i] - x[j]
                    dy = y[i] - y[j]
                    d2[0] = dx * dx + dy * dy
                    if d2[0] > reach2:
                        continue
                    s = radius[i] + radius[j]
                    # the rows can neither overlap nor beat the smallest clearance known: skip them
                    gap = np.sqrt(d2[0]) - s - slack
                    if gap > 0.0 and gap > min(best, bound):
                        continue
                    s2 = s * s
                    low = d2[0]
                    hit = first_row == 0 and d2[0] < s2
                    for row in range(1, rows):
                        dx = traj[row, i, 0] - traj[row, j, 0]
                        dy = traj[row, i, 1] - traj[row, j, 1]
                        d2[row] = dx * dx + dy * dy
                        low = min(low, d2[row])
                        hit = hit or (row >= first_row and d2[row] < s2)
                    clear = np.sqrt(low) - s
                    if clear < best:
                        best, best_i, best_j = clear, i, j
                    if hit:
                        if n_hits == cap:  # grow the outputs
                            cap *= 2
                            more = np.empty((cap, 2), dtype=np.int64)
                            more[:n_hits] = hits
                            hits = more
                            deeper = np.empty((cap, rows - first_row))
                            deeper[:n_hits] = depth
                            depth = deeper
                        hits[n_hits, 0] = i
                        hits[n_hits, 1] = j
                        for row in range(first_row, rows):
                            depth[n_hits, row - first_row] = s - np.sqrt(d2[row])
                        n_hits += 1
    return True, best, best_i, best_j, hits[:n_hits], depth[:n_hits]


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
    done, best, i, j, hits, depth = _close_pairs(
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


@njit(cache=True, nogil=True)
def _nearest_heard(qx, qy, qid, x, y, ids, vel, rad, stamp, coop, now: float, reach: float, m: int) -> tuple:
    """Each query point's m nearest heard states within ``reach`` (d^2 <= reach^2), not its own id,
    nearest first, equal distances by index, as padded neighbour arrays (a padded slot: zeros,
    radius 1, not valid): positions, velocities (Q, m, 2), radii, ages, valid, cooperative (Q, m).

    Cells are reach / COLUMN_PARTS wide. A column's cells are consecutive in the grid's order, so
    each column near the query is read as one run of points: the cells its part of the disc of
    reach covers (the query's own column first, then outward; once m are found, the disc shrinks
    to the m-th distance). The m nearest by (distance, index) do not depend on the order in which
    points are met, so these are the neighbours of any exhaustive search."""
    q, n = qx.size, x.size
    position, velocity = np.zeros((q, m, 2)), np.zeros((q, m, 2))
    radius, age = np.ones((q, m)), np.zeros((q, m))
    valid, cooperative = np.zeros((q, m), np.bool_), np.ones((q, m), np.bool_)
    if q == 0 or n == 0 or m == 0:
        return position, velocity, radius, age, valid, cooperative
    _, _, nx, ny, start, order, x0, y0, cell = grid_cells(x, y, reach / COLUMN_PARTS)
    # how far rounding may move a point across a cell border: far below a cell, above any ulp
    slack = 1e-9 * (cell + max(np.abs(x).max(), np.abs(y).max(), np.abs(qx).max(), np.abs(qy).max()))
    reach2 = reach * reach
    spread = int(reach / cell) + 2  # columns either side of the query's that can hold a point within reach
    best, chosen = np.empty(m), np.empty(m, np.int64)
    for i in range(q):
        px, py = qx[i], qy[i]
        column = int(np.floor((px - x0) / cell))
        k = 0
        bound = reach2  # no point farther than this (squared) is kept
        for s in range(2 * spread + 1):
            gx = column + (s + 1) // 2 if s % 2 else column - s // 2  # 0, +1, -1, +2, -2, ...
            if gx < 0 or gx >= nx:
                continue
            left = x0 + gx * cell - slack
            away = max(left - px, px - (left + cell + 2.0 * slack), 0.0)  # to the column, across
            if away * away > bound:
                continue
            # along the column: as far as the disc reaches, widened past any rounding of the square root
            half = np.sqrt(max(bound - away * away, 0.0) + 1e-12 * bound) + slack
            low = max(int(np.floor((py - half - y0) / cell)), 0)
            high = min(int(np.floor((py + half - y0) / cell)), ny - 1)
            if low > high:
                continue
            for a in range(start[gx * ny + low], start[gx * ny + high + 1]):
                j = order[a]
                if ids[j] == qid[i]:
                    continue
                dx, dy = x[j] - px, y[j] - py
                d2 = dx * dx + dy * dy
                if not d2 <= reach2 or (k == m and (d2 > best[m - 1] or (d2 == best[m - 1] and j > chosen[m - 1]))):
                    continue
                p = min(k, m - 1)  # insert (d2, j) in order, dropping the last when full
                while p > 0 and (best[p - 1] > d2 or (best[p - 1] == d2 and chosen[p - 1] > j)):
                    best[p] = best[p - 1]
                    chosen[p] = chosen[p - 1]
                    p -= 1
                best[p] = d2
                chosen[p] = j
                k = min(k + 1, m)
                if k == m:
                    bound = best[m - 1]
        for c in range(k):
            j = chosen[c]
            position[i, c, 0], position[i, c, 1] = x[j], y[j]
            velocity[i, c, 0], velocity[i, c, 1] = vel[j, 0], vel[j, 1]
            radius[i, c], age[i, c] = rad[j], now - stamp[j]
            valid[i, c], cooperative[i, c] = True, coop[j]
    return position, velocity, radius, age, valid, cooperative


def nearest_heard_compiled(
    robot_ids: np.ndarray, positions: np.ndarray, stamp: float, heard: Heard, reach: float, m: int
) -> NeighbourStates:
    """agent.neighbour_table.nearest_heard on the grid, compiled: the same neighbours in the same order
    (the same squared distances, ties by id), for the central engine's thousand robots a tick."""
    ids = np.ascontiguousarray(heard.ids, dtype=np.int64)
    if len(ids) > 1 and not (ids[1:] > ids[:-1]).all():  # by id, as nearest_heard ranks ties
        order = np.argsort(ids, kind="stable")
        heard = Heard(
            ids[order],
            heard.position[order],
            heard.velocity[order],
            heard.radius[order],
            heard.stamp[order],
            heard.cooperative[order],
        )
        ids = heard.ids
    f64 = np.ascontiguousarray
    pos = f64(heard.position, dtype=float)
    p = f64(positions, dtype=float).reshape(-1, 2)
    return NeighbourStates(
        *_nearest_heard(
            p[:, 0].copy(),
            p[:, 1].copy(),
            f64(robot_ids, dtype=np.int64),
            pos[:, 0].copy(),
            pos[:, 1].copy(),
            ids,
            f64(heard.velocity, dtype=float),
            f64(heard.radius, dtype=float),
            f64(heard.stamp, dtype=float),
            f64(heard.cooperative, dtype=np.bool_),
            float(stamp),
            float(reach),
            int(m),
        )
    )
