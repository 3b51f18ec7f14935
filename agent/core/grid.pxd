"""The grid of agent/core/grid.pyx, for compiled modules that search it too (sim/bodies/contacts.pyx)."""

from libc.stdint cimport int64_t


cdef struct Grid:
    Py_ssize_t n  # points
    Py_ssize_t nx, ny  # columns, rows: cell c = gx * ny + gy
    double x0, y0, cell  # origin and cell size
    double per  # 1 / cell: cells per metre
    Py_ssize_t *cx, *cy  # (n,) each point's column and row
    Py_ssize_t *start  # (nx * ny + 1,) the points of cell c are order[start[c]:start[c + 1]]
    Py_ssize_t *order  # (n,) the points, sorted by cell (by index within a cell)
    double *sx, *sy  # (n,) order's points' x and y


cdef int grid_build(Grid *g, const double[:, ::1] points, double width) except -1
cdef void grid_free(Grid *g) noexcept
