"""The world's robot-robot contact detection (sim.bodies.proximity), compiled, on the grid of the
robots' neighbour search (agent.core.grid)."""

# cython: language_level=3

from libc.math cimport sqrt
from libc.stdint cimport int64_t
from libc.stdlib cimport free, malloc

from agent.core.grid cimport Grid, grid_build, grid_free

import numpy as np


def close_pairs(const double[:, :, ::1] traj, const double[::1] radius, double reach, double motion, double bound,
                Py_ssize_t first_row, int64_t budget):
    """Discs of radius (N,) over states traj (rows, N, 2): the pairs within ``reach`` in traj[0],
    checked in every row. Returns (done, clearance, i, j, pairs, depth): the smallest clearance and a
    pair with it (-1, -1: none), the pairs (H, 2) that overlap from ``first_row`` on and their depths.
    A pair's rows are skipped when, its discs within ``motion`` of traj[0], it can neither overlap nor
    come closer than ``bound``; done is False (the rest empty) past ``budget`` pairs."""
    cdef Py_ssize_t rows = traj.shape[0], n = traj.shape[1] if traj.shape[0] else 0
    if radius.shape[0] != n or (rows and traj.shape[2] != 2) or not 0 <= first_row <= rows:
        raise ValueError("close_pairs: traj (rows, N, 2), radius (N,), 0 <= first_row <= rows")
    cdef Py_ssize_t width = rows - first_row, cap = 64, hits = 0
    pairs_array = np.empty((cap, 2), dtype=np.int64)
    depth_array = np.empty((cap, width))
    cdef int64_t[:, ::1] pairs = pairs_array
    cdef double[:, ::1] depth = depth_array
    cdef double best = np.inf
    cdef Py_ssize_t best_i = -1, best_j = -1
    if rows == 0 or n == 0:
        return True, best, best_i, best_j, pairs_array[:0], depth_array[:0]
    cdef Grid g
    grid_build(&g, traj[0], reach)  # frees what it took if it raises
    cdef double *d2 = <double *>malloc(rows * sizeof(double))
    cdef Py_ssize_t i, j, a, ax, ay, c, row
    cdef int64_t scanned = 0
    cdef double dx, dy, s, s2, low, gap, clear
    cdef double reach2 = reach * reach
    cdef double slack = 2.0 * motion + 1e-9  # no row brings a pair closer than its row-0 distance less this
    cdef bint hit
    try:
        if d2 == NULL:
            raise MemoryError()
        for i in range(n):
            for ax in range(max(g.cx[i] - 1, 0), min(g.cx[i] + 2, g.nx)):
                for ay in range(max(g.cy[i] - 1, 0), min(g.cy[i] + 2, g.ny)):
                    c = ax * g.ny + ay
                    for a in range(g.start[c], g.start[c + 1]):
                        j = g.order[a]
                        if j <= i:
                            continue
                        scanned += 1
                        if scanned > budget:
                            return False, best, best_i, best_j, pairs_array[:0], depth_array[:0]
                        dx = traj[0, i, 0] - traj[0, j, 0]
                        dy = traj[0, i, 1] - traj[0, j, 1]
                        d2[0] = dx * dx + dy * dy
                        if d2[0] > reach2:
                            continue
                        s = radius[i] + radius[j]
                        gap = sqrt(d2[0]) - s - slack
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
                        clear = sqrt(low) - s
                        if clear < best:
                            best, best_i, best_j = clear, i, j
                        if hit:
                            if hits == cap:  # grow the outputs
                                cap *= 2
                                pairs_array = np.concatenate([pairs_array, np.empty_like(pairs_array)])
                                depth_array = np.concatenate([depth_array, np.empty_like(depth_array)])
                                pairs = pairs_array
                                depth = depth_array
                            pairs[hits, 0] = i
                            pairs[hits, 1] = j
                            for row in range(first_row, rows):
                                depth[hits, row - first_row] = s - sqrt(d2[row])
                            hits += 1
    finally:
        grid_free(&g)
        free(d2)
    return True, best, best_i, best_j, pairs_array[:hits], depth_array[:hits]
