"""Who is near whom on a uniform grid of cells, compiled: every engine's neighbour search (`nearest`,
so a robot's neighbours never depend on its batch); the world's contact detection searches the same
grid (sim/bodies/contacts.pyx). `unheard` tells which of the tracker's bodies a robot has not heard by
their states (agent.neighbour_table.with_bodies).

The ranking, the same everywhere: j is nearer to q than l when (d2(q, j), key[j], j) < (d2(q, l),
key[l], l), d2 = dx * dx + dy * dy with dx = x[j] - qx, dy = y[j] - qy in float64 (no fast-math or
FMA), whatever order the grid meets the points in. Positions must be finite.
"""

# cython: language_level=3

from libc.math cimport INFINITY, fabs, hypot, isfinite, sqrt
from libc.stdint cimport int64_t
from libc.stdlib cimport calloc, free, malloc, qsort

from agent.core.crew cimport most_hands, share_rows
from agent.core.distance cimport against

import numpy as np

cdef enum:
    CELLS_PER_POINT = 16  # a grid has at most this many cells per point (coarser cells past it), or 1024
    PARTS = 3  # nearest's cells are reach / PARTS wide where the points are crowded (see cell_width)
    QUERIES_PER_CHUNK = 32  # queries a thread of the central engine's crew claims at a time


cdef void grid_free(Grid *g) noexcept:
    free(g.cx)
    free(g.cy)
    free(g.start)
    free(g.order)
    free(g.sx)
    free(g.sy)
    g.cx = g.cy = g.start = g.order = NULL
    g.sx = g.sy = NULL


cdef struct Box:
    double x0, x1, y0, y1


cdef Box bounds(const double[:, ::1] points) noexcept:
    """The finite points' bounding box (none: the origin). A point with an infinite or NaN coordinate
    is within no distance of any other, so its cell does not matter (the box's edge)."""
    cdef Box b = Box(INFINITY, -INFINITY, INFINITY, -INFINITY)
    cdef Py_ssize_t i
    for i in range(points.shape[0]):
        if isfinite(points[i, 0]) and isfinite(points[i, 1]):
            b.x0 = min(b.x0, points[i, 0])
            b.x1 = max(b.x1, points[i, 0])
            b.y0 = min(b.y0, points[i, 1])
            b.y1 = max(b.y1, points[i, 1])
    if b.x0 > b.x1:
        return Box(0.0, 0.0, 0.0, 0.0)
    return b


cdef int grid_build(Grid *g, const double[:, ::1] points, double width) except -1:
    """The cells of the (at least one) points, ``width`` wide or wider (a far outlier cannot ask for
    billions of cells)."""
    cdef Py_ssize_t n = points.shape[0], i, c, cells
    cdef Box box = bounds(points)
    cdef double x0 = box.x0, x1 = box.x1, y0 = box.y0, y1 = box.y1
    if not (isfinite(x1 - x0) and isfinite(y1 - y0)):  # no grid of cells spans them
        raise ValueError("nearest: the points lie farther apart than a double holds")
    # a little wider, so two points within a width are never two cells apart by rounding
    cdef double cell = width * (1.0 + 1e-6) + 1e-12
    cdef double cap = max(CELLS_PER_POINT * n, 1024)
    if not cell < 1e300:  # an infinite reach: one cell
        cell = max(x1 - x0, y1 - y0) + 1.0
    while ((x1 - x0) / cell + 1.0) * ((y1 - y0) / cell + 1.0) > cap:
        cell *= 2.0
    g.n, g.x0, g.y0, g.cell, g.per = n, x0, y0, cell, 1.0 / cell
    g.nx = <Py_ssize_t>((x1 - x0) / cell) + 1
    g.ny = <Py_ssize_t>((y1 - y0) / cell) + 1
    cells = g.nx * g.ny
    g.cx = <Py_ssize_t *>malloc(n * sizeof(Py_ssize_t))
    g.cy = <Py_ssize_t *>malloc(n * sizeof(Py_ssize_t))
    g.start = <Py_ssize_t *>malloc((cells + 1) * sizeof(Py_ssize_t))
    g.order = <Py_ssize_t *>malloc(n * sizeof(Py_ssize_t))
    g.sx = <double *>malloc(n * sizeof(double))
    g.sy = <double *>malloc(n * sizeof(double))
    if not (g.cx and g.cy and g.start and g.order and g.sx and g.sy):
        grid_free(g)
        raise MemoryError()
    for c in range(cells + 1):
        g.start[c] = 0
    for i in range(n):
        g.cx[i] = cell_index((points[i, 0] - x0) / cell, 0, g.nx - 1)
        g.cy[i] = cell_index((points[i, 1] - y0) / cell, 0, g.ny - 1)
        g.start[g.cx[i] * g.ny + g.cy[i] + 1] += 1
    for c in range(cells):
        g.start[c + 1] += g.start[c]
    # counting sort, stable: order[start[c] + k] is the k-th lowest index in cell c
    for i in range(n):
        c = g.cx[i] * g.ny + g.cy[i]
        g.order[g.start[c]] = i
        g.start[c] += 1
    for c in range(cells, 0, -1):
        g.start[c] = g.start[c - 1]
    g.start[0] = 0
    for c in range(n):
        i = g.order[c]
        g.sx[c] = points[i, 0]
        g.sy[c] = points[i, 1]
    return 0


cdef inline Py_ssize_t cell_index(double v, Py_ssize_t low, Py_ssize_t high) noexcept nogil:
    """floor(v) clamped to [low, high], clamped as a double first (v may be beyond any int); between,
    the truncation, one less where it rounded a negative v up (cheaper than floor)."""
    if not v >= low:  # NaN too
        return low
    if v >= high + 1.0:
        return high
    cdef Py_ssize_t t = <Py_ssize_t>v
    return t - 1 if t > v else t


cdef inline bint before(double d2, int64_t k, Py_ssize_t j, double d2b, int64_t kb, Py_ssize_t jb) noexcept nogil:
    """(d2, k, j) < (d2b, kb, jb): the ranking of the module's docstring."""
    if d2 != d2b:
        return d2 < d2b
    if k != kb:
        return k < kb
    return j < jb


cdef struct Query:
    double px, py  # the query point
    int64_t own  # its key: not its own neighbour
    double reach2  # reach squared
    bint inclusive  # d2 <= reach2, else d2 < reach2
    Py_ssize_t k, m  # neighbours kept so far, at most m
    double bound  # no point farther (d2) can be kept: reach2, then the m-th's d2
    double *best  # (m,) their d2, nearest first
    int64_t *best_key  # (m,) their keys
    int64_t *chosen  # (m,) their indices (the query's row of the output)


cdef inline void scan(Grid *g, Query *q, const int64_t *key, Py_ssize_t first, Py_ssize_t last) noexcept nogil:
    """The points of cells first..last - 1 into q's m nearest, by (d2, key, index)."""
    cdef Py_ssize_t a, j, p, m = q.m
    cdef int64_t kj
    cdef double dx, dy, d2
    if first >= last:
        return
    for a in range(g.start[first], g.start[last]):
        dx = g.sx[a] - q.px
        dy = g.sy[a] - q.py
        d2 = dx * dx + dy * dy
        if d2 > q.bound:  # most points: farther than the m-th kept (or than reach, until m are)
            continue
        j = g.order[a]
        kj = key[j]
        if kj == q.own:
            continue
        if not (d2 <= q.reach2 if q.inclusive else d2 < q.reach2):
            continue
        if q.k == m and not before(d2, kj, j, q.best[m - 1], q.best_key[m - 1], q.chosen[m - 1]):
            continue
        p = min(q.k, m - 1)  # insert (d2, key, j) in order, dropping the last when full
        while p > 0 and before(d2, kj, j, q.best[p - 1], q.best_key[p - 1], q.chosen[p - 1]):
            q.best[p] = q.best[p - 1]
            q.best_key[p] = q.best_key[p - 1]
            q.chosen[p] = q.chosen[p - 1]
            p -= 1
        q.best[p] = d2
        q.best_key[p] = kj
        q.chosen[p] = j
        if q.k < m:
            q.k += 1
        if q.k == m:
            q.bound = q.best[m - 1]


cdef double cell_width(const double[:, ::1] points, double reach, Py_ssize_t m) noexcept:
    """nearest's cells: reach / PARTS wide where a disc of ``reach`` holds m points or more at the
    mean density (narrow cells pass over the rest), else reach wide (the 3 x 3 cells hold the disc)."""
    cdef Box b = bounds(points)
    if points.shape[0] * 3.141592653589793 * reach * reach >= m * (b.x1 - b.x0 + reach) * (b.y1 - b.y0 + reach):
        return reach / PARTS
    return reach


def nearest(const double[:, ::1] query, const int64_t[::1] query_key, const double[:, ::1] points,
            const int64_t[::1] key, double reach, Py_ssize_t m, bint inclusive=True, int threads=1):
    """(Q, m) int64: each query's up to ``m`` nearest points within ``reach`` (``inclusive``: d2 <=
    reach^2, else <, as RVO2), by (d2, key, index), -1 past the last; never a point of its own key.
    A query reads its 3 x 3 cells first (the disc shrinks to the m-th distance at once), then the
    columns outward, each as one run; ``threads`` share the queries (the same result)."""
    cdef Py_ssize_t q = query.shape[0], n = points.shape[0]
    if query_key.shape[0] != q or key.shape[0] != n or (q and query.shape[1] != 2) or (n and points.shape[1] != 2):
        raise ValueError("nearest: query (Q, 2) with query_key (Q,), points (N, 2) with key (N,)")
    if m < 0:
        raise ValueError(f"nearest: m must not be negative, not {m}")
    out_array = np.full((q, m), -1, dtype=np.int64)
    cdef int64_t[:, ::1] out = out_array
    if q == 0 or n == 0 or m == 0 or not reach > 0.0:
        return out_array
    cdef Grid g
    grid_build(&g, points, cell_width(points, reach, m))  # frees what it took if it raises
    cdef int t
    threads = most_hands(q, QUERIES_PER_CHUNK, threads)
    cdef Query *each = <Query *>calloc(threads, sizeof(Query))  # a thread's own query and its best
    cdef Queries job
    cdef Py_ssize_t spread
    cdef Box box
    cdef double slack, far
    try:
        if each == NULL:
            raise MemoryError()
        for t in range(threads):
            each[t].reach2, each[t].inclusive, each[t].m = reach * reach, inclusive, m
            each[t].best = <double *>malloc(m * sizeof(double))
            each[t].best_key = <int64_t *>malloc(m * sizeof(int64_t))
            if each[t].best == NULL or each[t].best_key == NULL:
                raise MemoryError()
        box = bounds(points)
        far = max(fabs(box.x0), fabs(box.x1), fabs(box.y0), fabs(box.y1))
        box = bounds(query)
        far = max(far, fabs(box.x0), fabs(box.x1), fabs(box.y0), fabs(box.y1))
        # how far rounding may move a point across a cell border: far below a cell, above any ulp
        slack = 1e-9 * (g.cell + far)
        # columns either side of the query's that can hold a point within reach
        spread = cell_index(reach / g.cell + 2.0, 0, g.nx + 1)
        job = Queries(&g, each, &query[0, 0], &query_key[0], &key[0], &out[0, 0], slack, spread)
        with nogil:  # the central engine's auction runs beside
            share_rows(_queries, &job, q, QUERIES_PER_CHUNK, threads)
    finally:
        grid_free(&g)
        for t in range(threads if each != NULL else 0):
            free(each[t].best)
            free(each[t].best_key)
        free(each)
    return out_array


cdef struct Queries:  # nearest's queries, as its crew's hands read them
    Grid *g
    Query *each  # each hand's own
    const double *xy  # (Q, 2)
    const int64_t *own  # (Q,) their keys
    const int64_t *key  # (N,) the points'
    int64_t *out  # (Q, m)
    double slack
    Py_ssize_t spread


cdef void _queries(void *job, int hand, Py_ssize_t start, Py_ssize_t stop) noexcept nogil:
    cdef Queries *j = <Queries *>job
    cdef Py_ssize_t i, m = j.each[hand].m
    for i in range(start, stop):
        _query(j.g, &j.each[hand], j.xy[2 * i], j.xy[2 * i + 1], j.own[i], j.key, j.out + m * i, j.slack, j.spread)


cdef void _query(Grid *g, Query *nb, double px, double py, int64_t own, const int64_t *key, int64_t *chosen,
                 double slack, Py_ssize_t spread) noexcept nogil:
    """nearest's search for one query point: its neighbours into ``chosen``."""
    cdef Py_ssize_t c, s, gx, qx, qy, low, high, missed
    cdef double left, away, half
    qx = cell_index((px - g.x0) * g.per, -1, g.nx)  # outside the grid: the cell just outside
    qy = cell_index((py - g.y0) * g.per, -1, g.ny)
    nb.px, nb.py, nb.own, nb.k, nb.bound, nb.chosen = px, py, own, 0, nb.reach2, chosen
    for gx in range(max(qx - 1, 0), min(qx + 2, g.nx)):
        if qy + 1 >= 0 and qy - 1 < g.ny:
            c = gx * g.ny
            scan(g, nb, key, c + max(qy - 1, 0), c + min(qy + 1, g.ny - 1) + 1)
    missed = 0
    for s in range(2 * spread + 1):
        gx = qx + (s + 1) // 2 if s % 2 else qx - s // 2  # 0, +1, -1, +2, -2, ...
        if s % 2 == 1:
            missed = 0  # a new pair of columns, one either side, each farther than the last
        if gx < 0 or gx >= g.nx:
            missed += 1
            continue
        left = g.x0 + gx * g.cell - slack
        away = max(max(left - px, px - (left + g.cell + 2.0 * slack)), 0.0)  # to the column, across
        if away * away > nb.bound:
            # the disc only shrinks and columns get farther: when neither of a pair reaches it, none beyond does
            missed += 1
            if missed == 2:
                break
            continue
        # along the column: as far as the disc reaches, widened past any rounding of the root
        half = sqrt(max(nb.bound - away * away, 0.0) + 1e-12 * nb.bound) + slack
        low = cell_index((py - half - g.y0) * g.per, -1, g.ny)
        high = cell_index((py + half - g.y0) * g.per, -1, g.ny)
        low, high = max(low, 0), min(high, g.ny - 1)
        c = gx * g.ny
        if qx - 1 <= gx <= qx + 1:  # the cells around the query's are done: the runs below and above them
            scan(g, nb, key, c + low, c + min(high, qy - 2) + 1)
            low = max(low, qy + 2)
        scan(g, nb, key, c + low, c + high + 1)


# ---------------------------------------------------------------- the tracker's bodies against the states heard


cdef struct Keyed:  # a heard state's robot and its row, ordered by (robot, row)
    int64_t robot
    Py_ssize_t row


cdef int _by_robot(const void *a, const void *b) noexcept nogil:
    cdef const Keyed *p = <const Keyed *>a
    cdef const Keyed *q = <const Keyed *>b
    if p.robot != q.robot:
        return -1 if p.robot < q.robot else 1
    return (p.row > q.row) - (p.row < q.row)


def unheard(const int64_t[:] robots, const double[:, :] position, const double[:] stamps, bodies, double stamp,
            double stale_after, double v_max, double radius):
    """agent.neighbour_table.with_bodies' test, (B,) bool: which of the tracker's bodies (Poses records)
    are of a robot with no heard state (rows: ``robots``, ``position``, ``stamps``) newer than
    ``stale_after`` at ``stamp``, or whose state lies farther from its body than it could have driven
    since (``v_max``) and ``radius``. A robot's first row counts."""
    cdef const int64_t[::1] body = np.ascontiguousarray(bodies["robot"], np.int64)
    cdef const double[::1] bx = np.ascontiguousarray(bodies["x"], float)
    cdef const double[::1] by = np.ascontiguousarray(bodies["y"], float)
    cdef Py_ssize_t s = robots.shape[0], b = body.shape[0], i, lo, hi, mid, k
    out = np.ones(b, bool)
    cdef unsigned char[::1] o = out.view(np.uint8)
    cdef double age
    cdef Keyed *rows = <Keyed *>malloc(max(s, 1) * sizeof(Keyed))
    if rows == NULL:
        raise MemoryError()
    cdef bint ordered = True
    for i in range(s):
        rows[i].robot, rows[i].row = robots[i], i
        ordered = ordered and (i == 0 or robots[i - 1] <= robots[i])
    if not ordered:  # the central engine hears every robot in id order
        qsort(rows, s, sizeof(Keyed), _by_robot)
    lo = 0
    for i in range(b):
        # the first row of the body's robot: a tracker's frame comes in id order, so most often a step on
        # from the last body's, else a binary search
        if i == 0 or body[i] < body[i - 1]:
            lo = 0
        hi = lo + 2
        while lo < s and rows[lo].robot < body[i] and lo < hi:
            lo += 1
        if lo < s and rows[lo].robot < body[i]:
            hi = s
            while lo < hi:
                mid = (lo + hi) // 2
                if rows[mid].robot < body[i]:
                    lo = mid + 1
                else:
                    hi = mid
        if lo == s or rows[lo].robot != body[i]:
            continue
        k = rows[lo].row
        age = stamp - stamps[k]
        if age <= stale_after and within(bx[i] - position[k, 0], by[i] - position[k, 1], v_max * max(age, 0.0) + radius):
            o[i] = 0
    free(rows)
    return out


cdef inline bint within(double dx, double dy, double limit) noexcept nogil:
    """hypot(dx, dy) <= limit."""
    cdef int side = against(dx * dx + dy * dy, limit)
    return side < 0 if side else hypot(dx, dy) <= limit
