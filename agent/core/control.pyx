# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""A robot's control step (paper 5.2-5.4), compiled once for every engine (docs/control_step.md).

A robot's result reads its own row alone, so it is the same, bit for bit, alone or in any batch.
Lines are a point and a unit direction, permissible on the left: det(d, v - p) >= 0.
"""

from libc.math cimport INFINITY, atan2, copysign, cos, fabs, hypot, isfinite, sin, sqrt, tan
from libc.stdint cimport int64_t, uint64_t
from libc.stdlib cimport free, malloc
from libc.string cimport memset

from agent.core.distance cimport against
from agent.core.splitmix cimport splitmix64
from agent.core.crew cimport MAX_HANDS, most_hands, share_rows

import math

import numpy as np

cdef double COOPERATING = 0.5  # responsibility c toward a robot running the same ORCA (eq. 12)
cdef double NON_COOPERATING = 1.0  # toward a dynamic obstacle, or a robot whose state is stale
cdef double PERTURBATION = 1e-4  # largest component of the symmetry-breaking perturbation (m/s)
cdef double EPSILON = 1e-5  # two unit directions are parallel below this |det| (as RVO2)
cdef Py_ssize_t ROWS_PER_CHUNK = 16  # rows a thread of the central engine's crew claims at a time
cdef int N_VERTICES = 24  # P_AHV's vertices: N_VERTICES - 1 spread denser ahead, where its boundary turns
# fastest, then pi and the dent's two (vertex_angles)

# radii 1 ppm larger in the safety and obstacle lines: rounding must not turn a closed gap into overlap
cdef double BUFFER = 1.0 + 1e-6
cdef double SHRINK = 4.0  # where infeasible the robot horizon is divided by this, down to dt
cdef double COS_RIGHT = cos(-math.pi / 4)
cdef double SIN_RIGHT = sin(-math.pi / 4)
DEF MAX_VERTICES = 32


cdef struct Lines:  # half-planes, structure of arrays; ``use`` flags the lines a 1-D problem is clipped by
    double *px, *py, *dx, *dy
    unsigned char *use


cdef struct Target:  # the point closest to (tx, ty), or ``directional``: furthest along it; within the disk
    double tx, ty, radius
    bint directional


cdef struct Other:  # a neighbour as the ORCA line sees it: position, velocity, radius, responsibility
    double x, y, vx, vy, radius, c


cdef struct Robot:
    double x, y  # position
    double vx, vy  # optimisation velocity (its last collision-free one)
    double tx, ty  # preferred velocity
    double radius
    double vmax


cdef struct Angle:  # the parts of V_H^max(theta) that depend on the angle only (NH-ORCA's closed forms)
    bint turning
    double t_eff, t_eff_s_half, k, v_s, v_s_sinc, v_s_omc2


cdef struct Config:
    double v_pref, k_a, arrived, v_max, tau, tau_obst, dt, margin, timeout, noise, committed
    bint safety, diffdrive
    double wheel_base, omega_cap, t_orient, error_min, error_max
    int n_vertices
    double cos_a[MAX_VERTICES]
    double sin_a[MAX_VERTICES]
    Angle terms[MAX_VERTICES]


cdef class Settings:
    """What a batch shares: horizons, how late neighbours are grown, P_AHV's shape; ``margin`` is added
    to every radius in the robot lines; ``safety=False``: RVO2's program."""

    cdef Config c

    def __init__(self, params, *, safety=True, margin=None, timeout=None, noise=None, committed=None, horizons=None):
        """From a RobotParams, defaults as an agent steers (holonomic margin: the noise bound; a
        broadcast velocity committed for dt). ``horizons``: other (tau, tau_obst, dt) (RVO2's)."""
        cdef Config c
        c.diffdrive = params.kinematics == "diffdrive"
        c.v_pref, c.k_a, c.v_max = params.v_pref, params.k_a, params.v_max
        # a differential-drive robot cannot close on a point (it turns on the spot for ever): at its goal it stops
        c.arrived = params.goal_tolerance if c.diffdrive else 0.0
        c.tau, c.tau_obst, c.dt = (params.tau, params.tau_obst, params.dt) if horizons is None else horizons
        c.margin = (0.0 if c.diffdrive else params.noise_bound) if margin is None else margin
        c.timeout = params.stale_after if timeout is None else timeout
        c.noise = params.noise_bound if noise is None else noise
        c.committed = c.dt if committed is None else committed
        c.safety = safety
        c.wheel_base, c.t_orient = params.wheel_base, params.t_orient
        c.omega_cap = min(params.omega_max, 2.0 * params.v_max / params.wheel_base)
        c.error_min, c.error_max = params.error_min, params.error_max
        angles = vertex_angles(c.t_orient * c.omega_cap)
        c.n_vertices = len(angles)
        for k, a in enumerate(angles):
            c.cos_a[k], c.sin_a[k] = cos(a), sin(a)
            c.terms[k] = _angle(&c, a)
        self.c = c

    @property
    def omega_cap(self):
        """The largest usable angular speed: omega_max, and no more than keeps a wheel within v_max."""
        return self.c.omega_cap


def vertex_angles(double dent):
    """Angles to the heading of P_AHV's vertices in (-pi, pi], denser ahead; S_AHV's dent (case C,
    ``dent`` = T omega_cap) is one, so every edge is a chord of a convex arc and lies in S_AHV."""
    u = [-1.0 + 2.0 * k / N_VERTICES for k in range(1, N_VERTICES)]
    angles = {math.pi * math.copysign(abs(x) ** 1.5, x) for x in u} | {math.pi}
    if dent < math.pi:
        angles |= {-dent, dent}
    return sorted(angles)


# ---------------------------------------------------------------- preferred velocity (eq. 9)


cdef inline void _perturbation(uint64_t robot, uint64_t seed, uint64_t tick, double magnitude, double *out) noexcept nogil:
    cdef uint64_t key = splitmix64(splitmix64(robot ^ splitmix64(seed)) + tick)
    cdef double a = <double>(key >> 11) * 2.0**-53  # [0, 1)
    cdef double b = <double>(splitmix64(key) >> 11) * 2.0**-53
    out[0] = (2.0 * a - 1.0) * magnitude
    out[1] = (2.0 * b - 1.0) * magnitude


cdef inline void _eq9(double ex, double ey, double v_pref, double k_a, double arrived, double *out) noexcept nogil:
    # speed V_p toward the goal, falling linearly within K_a of it; zero without a goal (NaN) or within
    # ``arrived`` of it
    cdef double dist = sqrt(ex * ex + ey * ey)
    cdef double gain
    if isfinite(dist) and dist > arrived:
        gain = v_pref / dist if dist > k_a else v_pref / k_a
        out[0], out[1] = ex * gain, ey * gain
    else:
        out[0], out[1] = 0.0, 0.0


def preferred_velocity(position, goal, double v_pref, double k_a):
    """Paper eq. 9 for points (..., 2) toward goals (..., 2) (NaN: no goal, zero)."""
    p = np.ascontiguousarray(position, dtype=float)
    g = np.ascontiguousarray(np.broadcast_to(np.asarray(goal, dtype=float), p.shape))
    cdef const double[:, ::1] pv = p.reshape(-1, 2)
    cdef const double[:, ::1] gv = g.reshape(-1, 2)
    out = np.empty((pv.shape[0], 2))
    cdef double[:, ::1] ov = out
    cdef Py_ssize_t i
    for i in range(pv.shape[0]):
        _eq9(gv[i, 0] - pv[i, 0], gv[i, 1] - pv[i, 1], v_pref, k_a, 0.0, &ov[i, 0])
    return out.reshape(p.shape)


def perturbation(robot_ids, seed, tick=0, double magnitude=PERTURBATION):
    """The tiny vectors (B,2) added to non-zero preferred velocities to break symmetric standoffs: a
    function of (robot id, seed, tick) only, so every process agrees."""
    ids = np.ascontiguousarray(np.asarray(robot_ids).reshape(-1).astype(np.uint64, copy=False))
    cdef const uint64_t[::1] iv = ids
    cdef uint64_t s = seed % 2**64, t = tick % 2**64
    out = np.empty((len(ids), 2))
    cdef double[:, ::1] ov = out
    cdef Py_ssize_t i
    for i in range(iv.shape[0]):
        _perturbation(iv[i], s, t, magnitude, &ov[i, 0])
    return out


def preferred_velocities(Settings settings, robot_ids, position, velocity, goal, given, seed, tick, cap=None):
    """A batch's preferred velocities (B,2): eq. 9, or the finite rows of ``given``; within ``cap``;
    turned 45 degrees right where the robot barely moves (a standoff becomes a roundabout); perturbed. A robot
    starting from rest turns too, which sets a symmetric start circling before it can jam: without it, 6
    e-pucks swapping across a circle jammed at its centre and had not arrived after 60 s
    (tests/e2e/test_clocks_events_engines.py)."""
    cdef const double[:, ::1] p = np.ascontiguousarray(position, dtype=float)
    cdef const double[:, ::1] v = np.ascontiguousarray(velocity, dtype=float)
    cdef const double[:, ::1] g = np.ascontiguousarray(goal, dtype=float)
    b = p.shape[0]
    cdef const double[:, ::1] w = np.full((b, 2), np.nan) if given is None else np.ascontiguousarray(given, dtype=float)
    cdef const uint64_t[::1] ids = np.ascontiguousarray(np.asarray(robot_ids).reshape(-1).astype(np.uint64))
    cdef const double[::1] c = _per_robot(np.nan if cap is None else cap, b)
    cdef uint64_t seed_word = seed % 2**64, tick_word = tick % 2**64
    out = np.empty((b, 2))
    cdef double[:, ::1] o = out
    cdef double want, x, y
    cdef double d[2]
    cdef Py_ssize_t i
    cdef Config *s = &settings.c
    for i in range(b):
        _eq9(g[i, 0] - p[i, 0], g[i, 1] - p[i, 1], s.v_pref, s.k_a, s.arrived, &o[i, 0])
        if isfinite(w[i, 0]) and isfinite(w[i, 1]):
            o[i, 0], o[i, 1] = w[i, 0], w[i, 1]
        x, y = o[i, 0], o[i, 1]
        want = sqrt(x * x + y * y)
        if want > c[i]:  # NaN: no cap
            x, y = x * (c[i] / want), y * (c[i] / want)
            want = sqrt(x * x + y * y)
        if want > 0.5 * s.v_pref and sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]) < 0.25 * want:
            x, y = COS_RIGHT * x - SIN_RIGHT * y, SIN_RIGHT * x + COS_RIGHT * y
        if x != 0.0 or y != 0.0:
            _perturbation(ids[i], seed_word, tick_word, PERTURBATION, d)
            x, y = x + d[0], y + d[1]
        o[i, 0], o[i, 1] = x, y
    return out


# ---------------------------------------------------------------- the 2-D linear program (eq. 13-14)


cdef inline bint _violates(Lines *L, int i, double x, double y, double by) noexcept nogil:
    # (x, y) lies more than ``by`` on line i's forbidden side
    return L.dx[i] * (L.py[i] - y) - L.dy[i] * (L.px[i] - x) > by


cdef bint _on_line(Lines *L, int i, int n, bint all_lines, Target *g, double *out) noexcept nogil:
    """The optimum on line i within the disk and lines j < n (with ``use`` unless ``all_lines``);
    False if there is none (``out`` unread then: the search stops at the first line that empties i)."""
    cdef double pix = L.px[i], piy = L.py[i], dix = L.dx[i], diy = L.dy[i]
    cdef double dot = pix * dix + piy * diy
    cdef double disc = dot * dot + g.radius * g.radius - (pix * pix + piy * piy)
    if not disc >= 0.0:
        return False
    cdef double sq = sqrt(disc if disc > 0.0 else 0.0)
    cdef double t_left = -dot - sq, t_right = -dot + sq, den, num, t, t_best
    cdef int j
    for j in range(n):
        if not all_lines and not L.use[j]:
            continue
        den = dix * L.dy[j] - diy * L.dx[j]
        num = L.dx[j] * (piy - L.py[j]) - L.dy[j] * (pix - L.px[j])
        if fabs(den) <= EPSILON:  # parallel: line j empties line i if i lies on its forbidden side
            if num < 0.0:
                return False
            continue
        t = num / den
        if den > 0.0:
            t_right = t if t < t_right else t_right
        else:
            t_left = t if t > t_left else t_left
        if t_left > t_right:
            return False
    if not t_left <= t_right:
        return False
    if g.directional:
        t_best = t_right if g.tx * dix + g.ty * diy > 0.0 else t_left
    else:
        t_best = dix * (g.tx - pix) + diy * (g.ty - piy)
        t_best = t_left if t_best < t_left else t_best
        t_best = t_right if t_best > t_right else t_best
    out[0], out[1] = pix + t_best * dix, piy + t_best * diy
    return True


cdef inline void _disk_optimum(Target *g, double *out) noexcept nogil:  # over the speed disk alone
    cdef double n2 = g.tx * g.tx + g.ty * g.ty, scale
    if g.directional:
        out[0], out[1] = g.tx * g.radius, g.ty * g.radius
    elif n2 > g.radius * g.radius:
        scale = g.radius / sqrt(n2)
        out[0], out[1] = g.tx * scale, g.ty * scale
    else:
        out[0], out[1] = g.tx, g.ty


cdef bint _optimise(Lines *L, int n, bint all_lines, Target *g, double *out) noexcept nogil:
    """RVO2's linearProgram2 over lines 0..n-1 (with ``use`` unless ``all_lines``), incrementally;
    False at the first line that cannot be met (``out``: the optimum over those before)."""
    cdef double at[2]
    cdef int i
    _disk_optimum(g, out)
    for i in range(n):
        if (all_lines or L.use[i]) and _violates(L, i, out[0], out[1], 0.0):
            if not _on_line(L, i, i, all_lines, g, at):
                return False
            out[0], out[1] = at[0], at[1]
    return True


cdef bint _optimise_few(Lines *L, int n, Target *g, double *out) noexcept nogil:
    """The optimum over lines 0..n-1 with ``use`` and the disk as the best 1-D optimum on the lines the
    disk's optimum violates (ties to the first): the shrinking horizon's (it moves crowds on sooner)."""
    cdef double at[2]
    cdef double best_cost = INFINITY, cost, ex, ey, cx, cy, near
    cdef bint violated = False, good = False
    cdef int c
    _disk_optimum(g, out)
    cx, cy = out[0], out[1]
    for c in range(n):
        if not L.use[c] or not _violates(L, c, cx, cy, 0.0):
            continue
        violated = True
        if good and not g.directional:
            # a line farther from the target than the best so far (less a slack for rounding) cannot beat it
            near = fabs(L.dx[c] * (g.ty - L.py[c]) - L.dy[c] * (g.tx - L.px[c])) - 1e-9 * (
                fabs(L.px[c]) + fabs(L.py[c]) + fabs(g.tx) + fabs(g.ty) + g.radius)
            if near > 0.0 and near * near > best_cost:
                continue
        if not _on_line(L, c, n, False, g, at):
            continue
        if g.directional:
            cost = -(g.tx * at[0] + g.ty * at[1])
        else:
            ex, ey = at[0] - g.tx, at[1] - g.ty
            cost = ex * ex + ey * ey
        if cost < best_cost:
            out[0], out[1], best_cost, good = at[0], at[1], cost, True
    if not violated:
        return True
    if not good:
        out[0], out[1] = cx, cy
    return good


cdef void _least_violation(Lines *L, Lines *Q, int n, int n_hard, Target *g, double *out) noexcept nogil:
    """RVO2's linearProgram3: keep the first n_hard lines (all soft if they leave nothing), minimise
    the largest violation of the others. ``Q``: scratch for the bisectors; L.use marks the hard lines."""
    cdef int i, j
    cdef double distance = 0.0, pix, piy, dix, diy, den, t, ex, ey, norm
    cdef double at[2]
    cdef bint par
    cdef Target into
    for i in range(n):
        L.use[i] = i < n_hard
    if not _optimise(L, n, False, g, out):  # the hard lines leave nothing: all soft, from the disk's optimum
        _disk_optimum(g, out)
        for i in range(n):
            L.use[i] = False
    for i in range(n):
        if L.use[i] or not _violates(L, i, out[0], out[1], distance):
            continue
        pix, piy, dix, diy = L.px[i], L.py[i], L.dx[i], L.dy[i]
        for j in range(i):  # the hard lines, and the bisectors with the earlier soft lines
            if L.use[j]:
                Q.px[j], Q.py[j], Q.dx[j], Q.dy[j], Q.use[j] = L.px[j], L.py[j], L.dx[j], L.dy[j], True
                continue
            den = dix * L.dy[j] - diy * L.dx[j]
            par = fabs(den) <= EPSILON
            Q.use[j] = not (par and dix * L.dx[j] + diy * L.dy[j] > 0.0)  # same direction: i dominates
            if par:
                Q.px[j], Q.py[j] = 0.5 * (pix + L.px[j]), 0.5 * (piy + L.py[j])
            else:
                t = (L.dx[j] * (piy - L.py[j]) - L.dy[j] * (pix - L.px[j])) / den
                Q.px[j], Q.py[j] = pix + t * dix, piy + t * diy
            ex, ey = L.dx[j] - dix, L.dy[j] - diy
            norm = sqrt(ex * ex + ey * ey)
            norm = norm if norm > 0.0 else 1.0
            Q.dx[j], Q.dy[j] = ex / norm, ey / norm
        into = Target(-diy, dix, g.radius, True)  # line i's left normal: into its half-plane
        if _optimise(Q, i, False, &into, at):
            out[0], out[1] = at[0], at[1]
        distance = dix * (piy - out[1]) - diy * (pix - out[0])


# ---------------------------------------------------------------- ORCA lines (eq. 10-12)


cdef struct Pair:  # what an ORCA line takes from the pair whatever the horizon, and its legs' lines
    double rpx, rpy, rvx, rvy, dist2, big_r, big_r2, vx, vy, c
    bint apart
    bint made[2]  # leg[0]: the left leg's line, leg[1]: the right's
    double leg[2][4]


cdef inline void _pair(Robot *me, Other *o, Pair *p) noexcept nogil:
    p.rpx, p.rpy, p.rvx, p.rvy = o.x - me.x, o.y - me.y, me.vx - o.vx, me.vy - o.vy
    p.dist2 = p.rpx * p.rpx + p.rpy * p.rpy
    p.big_r = me.radius + o.radius
    p.big_r2 = p.big_r * p.big_r
    p.apart = p.dist2 > p.big_r2
    p.vx, p.vy, p.c = me.vx, me.vy, o.c
    p.made[0] = p.made[1] = False


cdef inline void _pair_line(Pair *p, double inv_tau, double inv_dt, double *line) noexcept nogil:
    """The ORCA half-plane (eq. 10-12) through v_opt + c u, u the smallest change leaving the velocity
    obstacle of horizon tau (an overlapping pair: dt, to separate within a period); as 1/tau, 1/dt."""
    cdef double rpx = p.rpx, rpy = p.rpy, rvx = p.rvx, rvy = p.rvy
    cdef double inv_h = inv_tau if p.apart else inv_dt
    cdef double wx = rvx - inv_h * rpx, wy = rvy - inv_h * rpy
    cdef double w2 = wx * wx + wy * wy, dot1 = wx * rpx + wy * rpy
    cdef double wl, ux, uy, scale, leg, inv_d2, ldx, ldy, dot2
    cdef int side
    if not p.apart or (dot1 < 0.0 and dot1 * dot1 > p.big_r2 * w2):  # the cut-off circle
        wl = sqrt(w2)
        if wl == 0.0:
            ux, uy = 1.0, 0.0
        else:
            ux, uy = wx / wl, wy / wl
        scale = p.big_r * inv_h - wl
        line[0], line[1], line[2], line[3] = p.vx + p.c * (scale * ux), p.vy + p.c * (scale * uy), uy, -ux
        return
    side = 0 if rpx * wy - rpy * wx > 0.0 else 1
    if p.made[side]:
        line[0], line[1], line[2], line[3] = p.leg[side][0], p.leg[side][1], p.leg[side][2], p.leg[side][3]
        return
    leg = sqrt(p.dist2 - p.big_r2 if p.dist2 > p.big_r2 else 0.0)  # a leg of the cone
    if side:
        leg = -leg
    inv_d2 = 1.0 / (p.dist2 if p.dist2 > 0.0 else 1.0)
    ldx = (rpx * leg - rpy * p.big_r) * inv_d2
    ldy = (rpy * leg + rpx * p.big_r) * inv_d2
    dot2 = rvx * ldx + rvy * ldy
    line[0], line[1] = p.vx + p.c * (dot2 * ldx - rvx), p.vy + p.c * (dot2 * ldy - rvy)
    line[2], line[3] = ldx, ldy
    p.leg[side][0], p.leg[side][1], p.leg[side][2], p.leg[side][3] = line[0], line[1], line[2], line[3]
    p.made[side] = True


cdef inline void _orca_line(Robot *me, Other *o, double tau, double dt, double *line) noexcept nogil:
    cdef Pair p
    memset(&p, 0, sizeof(Pair))  # the legs are made here, never read: this tells the compiler so
    _pair(me, o, &p)
    _pair_line(&p, 1.0 / tau, 1.0 / dt, line)


cdef inline double _obstacle_line(Robot *me, double radius, const double *seg, double tau_obst,
                                  double *line) noexcept nogil:
    """Keep ``radius`` from the edge for tau_obst: v.n >= -(d - r)/tau_obst, n and d from the edge's
    nearest point (overlapping: only away). Returns (d - r)/tau_obst (0 if overlapping)."""
    cdef double ax = seg[0], ay = seg[1], ex = seg[2] - seg[0], ey = seg[3] - seg[1]
    cdef double len2 = ex * ex + ey * ey
    cdef double t = ((me.x - ax) * ex + (me.y - ay) * ey) / (len2 if len2 > 0.0 else 1.0)
    t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
    cdef double nx = me.x - (ax + t * ex), ny = me.y - (ay + t * ey)
    cdef double d = sqrt(nx * nx + ny * ny), el, offset
    if d == 0.0:  # centre on the edge: the free side is on its right
        el = sqrt(len2 if len2 > 0.0 else 1.0)
        nx, ny = ey / el, -ex / el
    else:
        nx, ny = nx / d, ny / d
    offset = d - radius
    offset = (offset if offset > 0.0 else 0.0) / tau_obst
    line[0], line[1], line[2], line[3] = -nx * offset, -ny * offset, ny, -nx
    return offset


cdef inline bint _needed(double *line, double vmax) noexcept nogil:
    # a line the whole speed disk satisfies changes nothing (min over the disk: -vmax - det(d, p))
    return line[2] * line[1] - line[3] * line[0] > -vmax


cdef inline int _push(Lines *L, int n, double *line, double vmax) noexcept nogil:
    if _needed(line, vmax):
        L.px[n], L.py[n], L.dx[n], L.dy[n] = line[0], line[1], line[2], line[3]
        return n + 1
    return n


# ---------------------------------------------------------------- one robot


cdef struct Scratch:  # one robot's neighbours as prepared, and its lines: reused robot after robot
    int m
    int used  # slots up to the last valid one (the rest are padding, skipped)
    double *nx, *ny, *nvx, *nvy
    double *nr  # radius as grown (body, noise, growth; NH-ORCA: and the neighbour's error)
    double *ng  # growth: how far it may have strayed since its state
    double *nc  # responsibility
    double *nlead  # s further along its velocity to where it most likely is
    unsigned char *nok
    Pair *pairs  # toward each neighbour, for its robot lines at every horizon
    Lines L
    Lines Q


cdef class Work:
    """Owns a Scratch for M neighbours and up to ``size`` lines."""

    cdef Scratch s
    cdef double *block
    cdef unsigned char *flags
    cdef Pair *pairs

    def __cinit__(self, int m, int size):
        self.block = <double *>malloc(sizeof(double) * (8 * m + 8 * size + 1))
        self.flags = <unsigned char *>malloc(m + 2 * size + 1)
        self.pairs = <Pair *>malloc(sizeof(Pair) * (m + 1))
        if self.block == NULL or self.flags == NULL or self.pairs == NULL:
            raise MemoryError()
        self.s.pairs = self.pairs
        cdef double *b = self.block
        self.s.m = self.s.used = m
        self.s.nx, self.s.ny, self.s.nvx, self.s.nvy = b, b + m, b + 2 * m, b + 3 * m
        self.s.nr, self.s.ng, self.s.nc, self.s.nlead = b + 4 * m, b + 5 * m, b + 6 * m, b + 7 * m
        self.s.nok = self.flags
        b = b + 8 * m
        self.s.L = Lines(b, b + size, b + 2 * size, b + 3 * size, self.flags + m)
        b = b + 4 * size
        self.s.Q = Lines(b, b + size, b + 2 * size, b + 3 * size, self.flags + m + size)

    def __dealloc__(self):
        free(self.block)
        free(self.flags)
        free(self.pairs)


cdef class Heard:
    """What a batch heard: a table of states (S, 7: x, y, vx, vy, radius, age, cooperative) as broadcast,
    and each robot's rows of it (B, M), nearest first, -1 where none."""

    cdef Py_ssize_t b, m
    cdef const int64_t[:, ::1] index
    cdef const double[:, ::1] table

    def __init__(self, states):
        """From agent.core.step.NeighbourStates (or anything with its index and table)."""
        index = np.ascontiguousarray(states.index, dtype=np.int64)
        table = np.ascontiguousarray(states.table, dtype=float)
        if index.ndim != 2 or table.ndim != 2 or table.shape[1] != 7:
            raise ValueError("neighbour states: index (B,M) into a table (S,7)")
        if index.size and index.max() >= len(table):
            raise IndexError(f"neighbour states: row {index.max()} past the table's {len(table)}")
        self.index, self.table = index, table
        self.b, self.m = index.shape[0], index.shape[1]

    @property
    def batch(self):
        return self.b if self.m else -1


cdef class Obstacles:
    """Obstacle edges (S,2,2) as the core reads them: n x (ax, ay, bx, by), shared by the batch."""

    cdef int n
    cdef const double[::1] xy
    cdef double[::1] box  # n x (x low, x high, y low, y high): each edge's bounding box

    def __init__(self, segments=None):
        self.xy = np.zeros(0) if segments is None else np.ascontiguousarray(segments, dtype=float).reshape(-1)
        if len(self.xy) % 4:
            raise ValueError("obstacle segments must be an (S,2,2) array")
        self.n = len(self.xy) // 4
        self.box = np.empty(4 * self.n + 1)
        cdef const double *e
        cdef int k
        for k in range(self.n):
            e = &self.xy[4 * k]
            self.box[4 * k], self.box[4 * k + 1] = min(e[0], e[2]), max(e[0], e[2])
            self.box[4 * k + 2], self.box[4 * k + 3] = min(e[1], e[3]), max(e[1], e[3])


cdef void _prepare(Config *s, Heard h, Py_ssize_t i, Scratch *w, double vmax) noexcept nogil:
    """Neighbours now from states ``age`` old: extrapolated by min(age, committed), grown by noise +
    h vmax for the rest h (``lead`` h: it most likely kept going); stale ones not extrapolated, grown
    twice as much, avoided alone (c = 1). Invalid where none or not finite."""
    cdef Py_ssize_t k, j
    cdef double x, y, u, v, r, age, horizon, shift
    cdef bint ok, stale, cooperative
    w.used = w.m
    while w.used > 0 and h.index[i, w.used - 1] < 0:
        w.used -= 1
    for k in range(w.used):
        j = h.index[i, k]
        x, y, u, v, r, age, cooperative = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, True
        if j >= 0:
            x, y, u, v = h.table[j, 0], h.table[j, 1], h.table[j, 2], h.table[j, 3]
            r, age, cooperative = h.table[j, 4], h.table[j, 5], h.table[j, 6] != 0.0
        age = age if age > 0.0 else 0.0
        ok = j >= 0 and isfinite(x) and isfinite(y) and isfinite(u) and isfinite(v) and isfinite(r) and isfinite(age)
        stale = age > s.timeout
        horizon = (s.timeout if stale else age) - s.committed
        horizon = horizon if horizon > 0.0 else 0.0
        shift = 0.0 if stale else age - horizon
        if not ok:
            x, y, u, v, r, horizon = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        w.nx[k], w.ny[k] = x + shift * u, y + shift * v
        w.nvx[k], w.nvy[k] = u, v
        w.ng[k] = horizon * (2.0 if stale else 1.0) * vmax
        w.nr[k] = r + s.noise + w.ng[k]
        w.nlead[k] = horizon if not stale else 0.0
        w.nc[k] = COOPERATING if cooperative and not stale else NON_COOPERATING
        w.nok[k] = ok


cdef inline double _touch(Config *s, double radius, double other, double age, double vmax) noexcept nogil:
    """How near to a robot of ``radius`` a neighbour heard ``age`` ago may have been heard and touch it by
    the end of the step: since, it may have gone anywhere at vmax, and both move for a step more."""
    return radius + other + s.noise + (age + 2.0 * s.dt) * vmax


cdef bint _unsure(Config *s, Heard h, Py_ssize_t i, Scratch *w, Robot *me) noexcept nogil:
    """Whether a neighbour stale (not heard for longer than the timeout) may touch us within the step.
    Steering around a guess no longer keeps clear then, so the robot stops (docs/faults.md)."""
    cdef Py_ssize_t k
    cdef double ex, ey, age, reach
    for k in range(w.used):
        if not w.nok[k]:
            continue
        age = h.table[h.index[i, k], 5]
        if not age > s.timeout:
            continue
        ex, ey = w.nx[k] - me.x, w.ny[k] - me.y
        reach = _touch(s, me.radius, h.table[h.index[i, k], 4], age, me.vmax)
        if ex * ex + ey * ey < reach * reach:
            return True
    return False


def touch_reach(Settings settings, double radius, other, age):
    """Elementwise: within what distance of where a neighbour (radius ``other``) was heard ``age`` s ago
    it may touch a robot of ``radius`` by the end of the step (where the robot stands for a stale one)."""
    o, a = np.broadcast_arrays(np.asarray(other, dtype=float), np.asarray(age, dtype=float))
    out = np.empty(o.shape)
    for k, (x, y) in enumerate(zip(o.reshape(-1).tolist(), a.reshape(-1).tolist())):
        out.reshape(-1)[k] = _touch(&settings.c, radius, x, y, settings.c.v_max)
    return out


cdef int _hard_lines(Config *s, Scratch *w, Robot *me, Obstacles edges, Lines *extra, int n_extra) noexcept nogil:
    """The lines every fallback keeps: obstacle edges, ``extra`` (P_AHV), the safety lines (horizon dt, our
    velocity zero; a cooperating neighbour at rest, and only one within 2 dt v_max; a dynamic obstacle or a stale
    robot at its velocity; neighbours grown only up to our surface, else no common solution). Returns how many."""
    cdef Lines *L = &w.L
    cdef double line[4]
    cdef double own = me.radius * BUFFER, r_obst = (me.radius + s.margin) * BUFFER
    cdef double ex, ey, dist, limit, gap
    cdef int n = 0, k
    cdef Robot still = me[0]
    cdef Other o
    # an edge gets a line only within r_obst + vmax tau_obst: one whose box lies well beyond is passed over
    cdef double reach = (r_obst + me.vmax * s.tau_obst) * (1.0 + 1e-6) + 1e-9, bx, by
    cdef const double *box
    for k in range(edges.n):
        box = &edges.box[4 * k]
        bx = max(max(box[0] - me.x, me.x - box[1]), 0.0)
        by = max(max(box[2] - me.y, me.y - box[3]), 0.0)
        if bx * bx + by * by > reach * reach:
            continue
        if _obstacle_line(me, r_obst, &edges.xy[4 * k], s.tau_obst, line) < me.vmax:
            n = _push(L, n, line, me.vmax)
    for k in range(n_extra):
        line[0], line[1], line[2], line[3] = extra.px[k], extra.py[k], extra.dx[k], extra.dy[k]
        n = _push(L, n, line, me.vmax)
    if not s.safety:
        return n
    still.vx, still.vy, still.radius = 0.0, 0.0, own
    for k in range(w.used):
        if not w.nok[k]:
            continue
        ex, ey = w.nx[k] - me.x, w.ny[k] - me.y
        dist = sqrt(ex * ex + ey * ey)
        o = Other(w.nx[k], w.ny[k], w.nvx[k], w.nvy[k], w.nr[k] * BUFFER, w.nc[k])
        limit = dist * (1.0 - 1e-9) - own
        o.radius = min(o.radius, max(limit, o.radius - w.ng[k] * BUFFER))
        gap = dist - (own + o.radius)
        if o.c < 1.0:  # a cooperating robot: only one that could touch us within dt, at rest
            if not gap < 2.0 * s.dt * me.vmax:
                continue
            o.vx, o.vy = 0.0, 0.0
        _orca_line(&still, &o, s.dt, s.dt, line)
        n = _push(L, n, line, me.vmax)
    return n


cdef int _robot_lines(Config *s, Scratch *w, Robot *me, double horizon, int start, bint again) noexcept nogil:
    """The ORCA lines at ``horizon`` after the hard ones: late neighbours where they most likely are,
    not grown (the safety lines cover that). ``again``: same robot, another horizon. Returns the count.
    A dynamic obstacle's line keeps the full horizon: it will not make way, so a horizon shrunk past it
    plans to meet it (a robot in a crowd drove back into a mover's path)."""
    cdef Robot grown = me[0]
    cdef double line[4]
    cdef double lead, left, inv_tau = 1.0 / horizon, inv_dt = 1.0 / s.dt, inv_full = 1.0 / s.tau
    cdef int n = start, k
    cdef Other o
    grown.radius = me.radius + s.margin
    for k in range(w.used):
        if not w.nok[k]:
            continue
        if not again:
            lead = w.nlead[k] if s.safety else 0.0
            left = w.ng[k] if s.safety else 0.0
            o = Other(w.nx[k] + lead * w.nvx[k], w.ny[k] + lead * w.nvy[k], w.nvx[k], w.nvy[k],
                      w.nr[k] - left + s.margin, w.nc[k])
            _pair(&grown, &o, &w.pairs[k])
        _pair_line(&w.pairs[k], inv_full if w.nc[k] == NON_COOPERATING else inv_tau, inv_dt, line)
        n = _push(&w.L, n, line, me.vmax)
    return n


cdef bint _orca(Config *s, Scratch *w, Robot *me, Obstacles edges, Lines *extra, int n_extra, bint full_only,
                double *out) noexcept nogil:
    """Eq. 14 for one robot. Infeasible (True: a fallback): the horizon shrinks to dt (paper 5.3), then
    least violation keeping the hard lines, as RVO2 does, where the paper stops the robot for the tick: the
    hard lines already rule out a contact within dt. ``full_only``: stop after the full horizon."""
    cdef Target g = Target(me.tx, me.ty, me.vmax, False)
    cdef int n_hard = _hard_lines(s, w, me, edges, extra, n_extra)
    cdef int n = _robot_lines(s, w, me, s.tau, n_hard, False)
    cdef double horizon = s.tau
    cdef int k
    if _optimise(&w.L, n, True, &g, out):
        return False
    if full_only:
        return True
    while s.safety and horizon > s.dt:
        horizon = max(horizon / SHRINK, s.dt)
        n = _robot_lines(s, w, me, horizon, n_hard, True)
        for k in range(n):
            w.L.use[k] = True
        if _optimise_few(&w.L, n, &g, out):
            return True
    _least_violation(&w.L, &w.Q, n, n_hard, &g, out)
    return True


# ---------------------------------------------------------------- NH-ORCA (paper 5.4)


cdef Angle _angle(Config *s, double theta) noexcept nogil:
    cdef Angle t
    cdef double a = fabs(theta), a_safe, s_half, omc
    t.t_eff = a / s.omega_cap if a > s.t_orient * s.omega_cap else s.t_orient
    t.v_s = max(s.v_max - (a / t.t_eff) * (0.5 * s.wheel_base), 0.0)
    t.turning = a > 1e-8
    a_safe = a if t.turning else 1.0
    s_half = sin(0.5 * a_safe)
    t.k = 0.5 * a_safe * cos(0.5 * a_safe) / s_half if t.turning else 1.0
    t.t_eff_s_half = t.t_eff * s_half
    t.v_s_sinc = t.v_s * (sin(a_safe) / a_safe if t.turning else 1.0)
    omc = t.v_s * ((1.0 - cos(a_safe)) / a_safe if t.turning else 0.0)
    t.v_s_omc2 = omc * omc
    return t


cdef double _speed_bound(Angle *t, double error, double v_max) noexcept nogil:
    """V_H^max within ``error``: case A E / (T |sin(th/2)|); B (saturated at v_s) the larger root of
    E(v_s)^2 = E^2; C (|th|/T beyond omega_cap) T = |th|/omega_cap; at most v_max."""
    cdef double v_a = error / t.t_eff_s_half if t.turning else INFINITY
    cdef double q, root, v
    if v_a * t.k > t.v_s:
        q = error / t.t_eff
        root = q * q - t.v_s_omc2
        v = t.v_s_sinc + sqrt(root if root > 0.0 else 0.0)
    else:
        v = v_a
    return v if v < v_max else v_max


cdef int _polygon(Config *s, double c, double si, double error, double mirror, Lines *P) noexcept nogil:
    """P_AHV's edges as lines, counter-clockwise (``mirror`` -1: driving backwards); returns how many."""
    cdef double vx[MAX_VERTICES]
    cdef double vy[MAX_VERTICES]
    cdef double r, lx, ly, ex, ey, norm
    cdef int k, nxt, n = 0
    for k in range(s.n_vertices):
        r = _speed_bound(&s.terms[k], error, s.v_max)
        lx, ly = r * s.cos_a[k], r * s.sin_a[k]
        vx[k], vy[k] = mirror * (c * lx - si * ly), mirror * (si * lx + c * ly)
    for k in range(s.n_vertices):
        nxt = (k + 1) % s.n_vertices
        ex, ey = vx[nxt] - vx[k], vy[nxt] - vy[k]
        norm = sqrt(ex * ex + ey * ey)
        if norm > 0.0:
            P.px[n], P.py[n], P.dx[n], P.dy[n] = vx[k], vy[k], ex / norm, ey / norm
            n += 1
    return n


cdef double _tracking_error(Config *s, Scratch *w, Robot *me) noexcept nogil:
    """E: half the free gap to the nearest neighbour, in [error_min, error_max]; each neighbour grows
    by its own bound from our side (both do, so the inflated disks stay apart)."""
    cdef double error = s.error_max, ex, ey, half
    cdef int k
    for k in range(w.used):
        ex, ey = w.nx[k] - me.x, w.ny[k] - me.y
        half = 0.5 * (sqrt(ex * ex + ey * ey) - (me.radius + w.nr[k]))
        half = s.error_min if half < s.error_min else (s.error_max if half > s.error_max else half)
        if w.nok[k] and half < error:
            error = half
        w.nr[k] += half
    return error


cdef inline double _min_error_speed(double v_h, double theta) noexcept nogil:
    cdef double half = 0.5 * fabs(theta)
    return v_h * (half / tan(half)) if half > 1e-8 else v_h


cdef void _controls(Config *s, double vx, double vy, double c, double si, bint reverse, double *out) noexcept nogil:
    """(v, omega) tracking a holonomic velocity: omega = sign(th) min(|th|/T, omega_cap), v = v*_E
    within v_max - |omega| l_w/2 (``reverse``: from the reversed heading, v negated)."""
    cdef double hx = -c if reverse else c, hy = -si if reverse else si
    cdef double speed = sqrt(vx * vx + vy * vy)
    cdef double theta = atan2(hx * vy - hy * vx, hx * vx + hy * vy) if speed > 0.0 else 0.0
    cdef double omega = copysign(min(fabs(theta) / s.t_orient, s.omega_cap), theta)
    cdef double v = max(0.0, min(_min_error_speed(speed, theta), s.v_max - fabs(omega) * (0.5 * s.wheel_base)))
    out[0], out[1] = (-v if reverse else v), omega


cdef struct Result:
    double vx, vy  # v_cf, the collision-free holonomic velocity (broadcast, next tick's v_opt)
    double c0, c1  # the command: v_cf, or the wheel speeds (left, right)
    double error  # NH-ORCA's tracking error E
    bint fallback  # infeasible at the full horizon
    bint reverse  # NH-ORCA: the mirrored polygon, driving backwards


cdef Result _nh_orca(Config *s, Scratch *w, Robot *me, double heading, Obstacles edges) noexcept nogil:
    """NH-ORCA: radii grown by the tracking error, P_AHV hard; infeasible: the mirrored polygon at the
    full horizon, else the forward fallback."""
    cdef Result r
    cdef Lines P = Lines(w.Q.px, w.Q.py, w.Q.dx, w.Q.dy, w.Q.use)  # the polygon, copied into L first
    cdef double c = cos(heading), si = sin(heading)
    cdef double forward[2]
    cdef double back[2]
    cdef double u[2]
    cdef int n
    r.error = _tracking_error(s, w, me)
    r.reverse = False
    me.radius += r.error
    n = _polygon(s, c, si, r.error, 1.0, &P)
    r.fallback = _orca(s, w, me, edges, &P, n, False, forward)
    if r.fallback:
        n = _polygon(s, c, si, r.error, -1.0, &P)
        if not _orca(s, w, me, edges, &P, n, True, back):
            forward[0], forward[1], r.reverse = back[0], back[1], True
    r.vx, r.vy = forward[0], forward[1]
    _controls(s, r.vx, r.vy, c, si, r.reverse, u)
    r.c0, r.c1 = u[0] - u[1] * (0.5 * s.wheel_base), u[0] + u[1] * (0.5 * s.wheel_base)
    return r


# ---------------------------------------------------------------- batches


cdef class Batch:
    """A batch's rows: position, v_opt, preferred velocity (B,2); heading, radius, vmax and ``cap``
    (B, or scalar; cap, unlike vmax, leaves what it assumes of neighbours' speeds as it is)."""

    cdef Py_ssize_t b
    cdef const double[::1] position, velocity, pref, heading, radius, vmax, cap

    def __init__(self, position, velocity, pref, heading=None, radius=None, vmax=None, cap=None):
        self.position, self.velocity, self.pref = [np.ascontiguousarray(x, dtype=float).reshape(-1) for x in (position, velocity, pref)]
        self.b = self.position.shape[0] // 2
        if self.velocity.shape[0] != 2 * self.b or self.pref.shape[0] != 2 * self.b:
            raise ValueError("position, velocity and preferred velocity must be (B,2) arrays of one B")
        self.heading, self.radius = [_per_robot(0.0 if x is None else x, self.b) for x in (heading, radius)]
        self.vmax, self.cap = [_per_robot(np.nan if x is None else x, self.b) for x in (vmax, cap)]


cdef _per_robot(value, Py_ssize_t b):
    a = np.asarray(value, dtype=float)
    if a.ndim == 1 and a.shape[0] == b:
        return np.ascontiguousarray(a)  # already one per robot (a central engine's radii: no copy)
    return np.full(b, float(a)) if a.ndim == 0 else np.ascontiguousarray(np.broadcast_to(a.reshape(-1), (b,)))


cdef inline Robot _robot(Batch rows, Py_ssize_t i, Config *s) noexcept nogil:
    cdef double vmax = rows.vmax[i] if isfinite(rows.vmax[i]) else s.v_max
    return Robot(rows.position[2 * i], rows.position[2 * i + 1], rows.velocity[2 * i], rows.velocity[2 * i + 1],
                 rows.pref[2 * i], rows.pref[2 * i + 1], rows.radius[i], vmax)


cdef void _step_one(Config *s, Batch robots, Heard nb, Obstacles obstacles, Scratch *w, Py_ssize_t i,
                    double *o) noexcept nogil:
    """Row i of step: o = (v_cf, command, fallback, reverse, tracking error)."""
    cdef Robot me = _robot(robots, i, s)
    cdef Result r
    _prepare(s, nb, i, w, me.vmax)
    if s.safety and _unsure(s, nb, i, w, &me):
        o[0], o[1], o[2], o[3], o[4], o[5], o[6] = 0.0, 0.0, 0.0, 0.0, False, False, 0.0
        return
    if robots.cap[i] < me.vmax:  # NaN: no cap
        me.vmax = robots.cap[i]
    if s.diffdrive:
        r = _nh_orca(s, w, &me, robots.heading[i], obstacles)
    else:
        r.fallback = _orca(s, w, &me, obstacles, NULL, 0, False, &r.vx)
        r.c0, r.c1, r.error, r.reverse = r.vx, r.vy, 0.0, False
    o[0], o[1], o[2], o[3], o[4], o[5], o[6] = r.vx, r.vy, r.c0, r.c1, r.fallback, r.reverse, r.error


cdef struct StepJob:  # step's batch, as its crew's hands read it
    Config *s
    void *robots  # Batch
    void *heard  # Heard
    void *obstacles  # Obstacles
    Scratch *scratch[MAX_HANDS]  # each hand's own
    double *out  # (B, 7)


cdef void _step_rows(void *job, int hand, Py_ssize_t start, Py_ssize_t stop) noexcept nogil:
    cdef StepJob *j = <StepJob *>job
    cdef Py_ssize_t i
    for i in range(start, stop):
        _step_one(j.s, <Batch>j.robots, <Heard>j.heard, <Obstacles>j.obstacles, j.scratch[hand], i, j.out + 7 * i)


def step(Settings settings, Batch robots, heard, segments=None, int threads=1):
    """One control step from what each robot heard (NeighbourStates (B,M) or Heard) and the edges
    (S,2,2): (v_cf, command (v_cf or wheel speeds), fallback, reverse, tracking error). Without the
    GIL; ``threads`` share the rows (the same bits)."""
    cdef Heard nb = heard if isinstance(heard, Heard) else Heard(heard)
    cdef Obstacles obstacles = segments if isinstance(segments, Obstacles) else Obstacles(segments)
    cdef Py_ssize_t b = robots.b
    if nb.batch not in (b, -1):
        raise ValueError(f"{nb.batch} rows of neighbour states for {b} robots")
    threads = most_hands(b, ROWS_PER_CHUNK, threads)
    works = [Work(nb.m, obstacles.n + MAX_VERTICES + 2 * nb.m) for _ in range(threads)]
    out = np.zeros((b, 7))
    cdef double[:, ::1] o = out
    cdef StepJob job
    cdef int hand
    job.s, job.robots, job.heard, job.obstacles = &settings.c, <void *>robots, <void *>nb, <void *>obstacles
    job.out = &o[0, 0] if b else NULL
    for hand in range(threads):
        job.scratch[hand] = &(<Work>works[hand]).s
    with nogil:
        share_rows(_step_rows, &job, b, ROWS_PER_CHUNK, threads)
    return out[:, 0:2].copy(), out[:, 2:4].copy(), out[:, 4] != 0, out[:, 5] != 0, out[:, 6].copy()


def blocked(params, to_goal, pref_velocity, velocity):
    """Paper 5.5.5, (B,) bool: near its goal ``to_goal`` (NaN: none) but not on it (penalised there it
    would leave a formed image), v_cf far from v_pref, and no headway (unlike a slowed crowd)."""
    cdef const double[:, ::1] g = np.ascontiguousarray(to_goal, dtype=float).reshape(-1, 2)
    cdef const double[:, ::1] p = np.ascontiguousarray(pref_velocity, dtype=float).reshape(-1, 2)
    cdef const double[:, ::1] v = np.ascontiguousarray(velocity, dtype=float).reshape(-1, 2)
    cdef double tolerance = params.goal_tolerance, near = params.deadlock_near, speed = params.deadlock_speed
    cdef double d, gap, headway
    cdef Py_ssize_t i, b = g.shape[0]
    if p.shape[0] != b or v.shape[0] != b:
        raise ValueError("to_goal, pref_velocity and velocity must be (B,2) arrays of one B")
    out = np.zeros(b, bool)
    cdef unsigned char[::1] o = out.view(np.uint8)
    for i in range(b):
        d = g[i, 0] * g[i, 0] + g[i, 1] * g[i, 1]  # most robots are far from their goal or on it
        if against(d, near) > 0 or against(d, tolerance) < 0:
            continue
        d = hypot(g[i, 0], g[i, 1])
        if not (isfinite(d) and d > tolerance and d <= near):
            continue
        gap = hypot(p[i, 0] - v[i, 0], p[i, 1] - v[i, 1])
        headway = (v[i, 0] * g[i, 0] + v[i, 1] * g[i, 1]) / d
        o[i] = gap > speed and headway < speed
    return out


def step_known(Settings settings, Batch robots, index, segments=None, out=None):
    """RVO2's step: neighbours are the batch's rows ``index`` (B,M) (-1: none), known perfectly.
    Returns (v_cf, fallback); v_cf into ``out`` if given (not the batch's velocities)."""
    cdef const int64_t[:, ::1] idx = np.ascontiguousarray(index, dtype=np.int64).reshape(robots.b, -1)
    cdef Obstacles obstacles = segments if isinstance(segments, Obstacles) else Obstacles(segments)
    cdef Py_ssize_t b = robots.b, i, j
    cdef int m = idx.shape[1], k
    if out is None:
        out = np.empty((b, 2))
    cdef double[:, ::1] o = out
    if o.shape[0] != b or o.shape[1] != 2:
        raise ValueError(f"step_known: out must be ({b}, 2), not {out.shape}")
    if b and &o[0, 0] == &robots.velocity[0]:
        raise ValueError("step_known: out must not be the batch's velocities (its neighbours read them)")
    cdef Work work = Work(m, obstacles.n + 2 * m)
    fallback = np.zeros(b, bool)
    cdef unsigned char[::1] fb = fallback.view(np.uint8)
    cdef Config *s = &settings.c
    cdef Scratch *w = &work.s
    cdef Robot me
    with nogil:
        for i in range(b):
            me = _robot(robots, i, s)
            w.used = m
            while w.used > 0 and idx[i, w.used - 1] < 0:
                w.used -= 1
            for k in range(w.used):
                j = idx[i, k]
                w.nok[k] = j >= 0
                j = j if j >= 0 else 0
                w.nx[k], w.ny[k] = robots.position[2 * j], robots.position[2 * j + 1]
                w.nvx[k], w.nvy[k] = robots.velocity[2 * j], robots.velocity[2 * j + 1]
                w.nr[k], w.ng[k], w.nc[k], w.nlead[k] = robots.radius[j], 0.0, COOPERATING, 0.0
            fb[i] = _orca(s, w, &me, obstacles, NULL, 0, False, &o[i, 0])
    return out, fallback


# ---------------------------------------------------------------- the parts, for tests and figures


def prepare_neighbours(Settings settings, heard, vmax=None):
    """What ``step`` assumes of the neighbours heard: (position, velocity, radius grown, growth,
    responsibility, lead, valid)."""
    cdef Heard nb = heard if isinstance(heard, Heard) else Heard(heard)
    cdef Py_ssize_t b = max(nb.batch, 0), i
    cdef int m = nb.m, k
    cdef Work work = Work(m, 1)
    cdef Scratch *w = &work.s
    out = np.empty((b, m, 9))
    cdef double[:, :, ::1] o = out
    for i in range(b):
        _prepare(&settings.c, nb, i, w, settings.c.v_max if vmax is None else vmax)
        for k in range(w.used, m):  # padding: as an invalid slot
            w.nx[k] = w.ny[k] = w.nvx[k] = w.nvy[k] = w.ng[k] = w.nlead[k] = 0.0
            w.nr[k], w.nc[k], w.nok[k] = settings.c.noise, COOPERATING, False
        for k in range(m):
            o[i, k, 0], o[i, k, 1], o[i, k, 2], o[i, k, 3] = w.nx[k], w.ny[k], w.nvx[k], w.nvy[k]
            o[i, k, 4], o[i, k, 5], o[i, k, 6], o[i, k, 7], o[i, k, 8] = w.nr[k], w.ng[k], w.nc[k], w.nlead[k], w.nok[k]
    return out[..., 0:2], out[..., 2:4], out[..., 4], out[..., 5], out[..., 6], out[..., 7], out[..., 8] != 0


def orca_line(robot, neighbour, double tau, double dt):
    """The ORCA line (px, py, dx, dy) of a robot (x, y, vx, vy, r) toward a neighbour (..., r, c)."""
    cdef Robot me = Robot(robot[0], robot[1], robot[2], robot[3], 0.0, 0.0, robot[4], INFINITY)
    cdef Other o = Other(neighbour[0], neighbour[1], neighbour[2], neighbour[3], neighbour[4], neighbour[5])
    cdef double line[4]
    _orca_line(&me, &o, tau, dt, line)
    return (line[0], line[1], line[2], line[3])


def obstacle_line(position, double radius, segment, double tau_obst):
    """The line (px, py, dx, dy) keeping a robot ``radius`` from an edge for tau_obst."""
    cdef Robot me = Robot(position[0], position[1], 0.0, 0.0, 0.0, 0.0, radius, INFINITY)
    cdef const double[::1] seg = np.ascontiguousarray(segment, dtype=float).reshape(4)
    cdef double line[4]
    _obstacle_line(&me, radius, &seg[0], tau_obst, line)
    return (line[0], line[1], line[2], line[3])


def linear_program(lines, double vmax, target, int n_hard=0):
    """Eq. 14 over lines (L,4) and the speed disk: (velocity, fallback); infeasible: least violation
    keeping the first ``n_hard``."""
    cdef const double[:, ::1] ln = np.ascontiguousarray(lines, dtype=float).reshape(-1, 4)
    cdef int n = ln.shape[0], k
    cdef Work work = Work(0, n + 1)
    cdef Scratch *w = &work.s
    for k in range(n):
        w.L.px[k], w.L.py[k], w.L.dx[k], w.L.dy[k] = ln[k, 0], ln[k, 1], ln[k, 2], ln[k, 3]
    cdef Target g = Target(target[0], target[1], vmax, False)
    cdef double out[2]
    if _optimise(&w.L, n, True, &g, out):
        return np.array([out[0], out[1]]), False
    _least_violation(&w.L, &w.Q, n, min(n_hard, n), &g, out)
    return np.array([out[0], out[1]]), True


def max_trackable_speed(Settings settings, theta, error):
    """V_H^max(theta) within ``error`` (the boundary of S_AHV), elementwise."""
    th, er = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(error, dtype=float))
    out = np.empty(th.shape)
    cdef Angle a
    for k, (x, e) in enumerate(zip(th.reshape(-1), er.reshape(-1))):
        a = _angle(&settings.c, x)
        out.reshape(-1)[k] = _speed_bound(&a, e, settings.c.v_max)
    return out


def min_error_speed(double v_h, double theta):
    """v*_E = v_H (th/2) cot(th/2): the speed that minimises the tracking error (v_H at 0)."""
    return _min_error_speed(v_h, theta)


def tracking_error(Settings settings, robot, neighbours):
    """NH-ORCA's E of a robot (x, y, r) among neighbours (M,3), and each neighbour's bound (M,)."""
    table = np.ascontiguousarray(neighbours, dtype=float).reshape(-1, 3)
    cdef int m = table.shape[0], k
    cdef Work work = Work(m, 1)
    cdef Scratch *w = &work.s
    cdef Robot me = Robot(robot[0], robot[1], 0.0, 0.0, 0.0, 0.0, robot[2], settings.c.v_max)
    for k in range(m):
        w.nx[k], w.ny[k], w.nr[k], w.nok[k] = table[k, 0], table[k, 1], table[k, 2], True
    error = _tracking_error(&settings.c, w, &me)
    return error, np.array([w.nr[k] - table[k, 2] for k in range(m)])


def ahv_polygon(Settings settings, double heading, double error, bint mirrored=False):
    """P_AHV's edges as lines (K,4), counter-clockwise."""
    cdef Work work = Work(0, MAX_VERTICES)
    cdef Lines *P = &work.s.L
    cdef int n = _polygon(&settings.c, cos(heading), sin(heading), error, -1.0 if mirrored else 1.0, P), k
    return np.array([[P.px[k], P.py[k], P.dx[k], P.dy[k]] for k in range(n)])


def controls(Settings settings, velocity, double heading, bint reverse=False):
    """(v, omega) of a differential-drive robot tracking the holonomic ``velocity`` (2,)."""
    cdef double out[2]
    _controls(&settings.c, velocity[0], velocity[1], cos(heading), sin(heading), reverse, out)
    return out[0], out[1]
