"""Holonomic ORCA (paper 5.2-5.3, eq. 9-14) over a batch of robots.

Arrays carry a leading robot axis B; neighbours a second axis M (padded, with a ``valid`` mask);
obstacle edges are shared by the batch. Lines follow `agent.core.lp`: point + unit direction,
permissible side on the left.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from agent.core.lp import (
    Line,
    NumpyDecides,
    least_violation,
    linear_program,
    np_maximum,
    np_minimum,
    optimise,
    optimise_few,
    optimise_few_one,
    optimise_one,
    plain,
)

__all__ = [
    "Lines",
    "preferred_velocity",
    "orca_lines",
    "obstacle_lines",
    "polygon_segments",
    "arena_segments",
    "concat_lines",
    "compact_lines",
    "drop_redundant",
    "safety_lines",
    "orca_velocity",
]


# radii 1 ppm larger in the safety and obstacle lines: gaps may close completely, rounding must not
# turn that into an overlap
_BUFFER = 1.0 + 1e-6
# where infeasible, the horizon is divided by this until feasible (paper 5.3), down to dt; the
# completion hardly depends on the factor
_SHRINK = 4.0


class Lines(NamedTuple):
    """Half-planes of a batch: point (B,L,2), unit direction (B,L,2), valid (B,L)."""

    point: np.ndarray
    direction: np.ndarray
    valid: np.ndarray


def preferred_velocity(position: ArrayLike, goal: ArrayLike, v_pref: ArrayLike, k_a: ArrayLike) -> np.ndarray:
    """Paper eq. 9: speed V_p toward the goal, falling linearly within K_a of it; zero without a goal (NaN)."""
    position = np.asarray(position, dtype=float)
    goal = np.asarray(goal, dtype=float)
    ex = goal[..., 0] - position[..., 0]
    ey = goal[..., 1] - position[..., 1]
    dist = np.sqrt(ex * ex + ey * ey)
    has = np.isfinite(dist) & (dist > 0.0)
    safe = np.where(has, dist, 1.0)
    # V_p min(1, d/K_a) / d, written so that within K_a it is V_p / K_a exactly (no division by d)
    gain = np.where(safe > k_a, v_pref / safe, v_pref / np.asarray(k_a, dtype=float))
    gain = np.where(has, gain, 0.0)
    return np.stack([np.where(has, ex, 0.0) * gain, np.where(has, ey, 0.0) * gain], axis=-1)


def orca_lines(
    position: ArrayLike,
    velocity: ArrayLike,
    radius: ArrayLike,
    nbr_position: np.ndarray,
    nbr_velocity: np.ndarray,
    nbr_radius: np.ndarray,
    nbr_responsibility: ArrayLike,
    nbr_valid: ArrayLike,
    tau: float,
    dt: float,
) -> Lines:
    """ORCA half-plane of each robot with respect to each neighbour (eq. 10-12).

    The optimisation velocities are the current velocities. u is the smallest change of the relative
    velocity that leaves the velocity obstacle VO^tau (truncated cone, eq. 10); the line passes through
    v_opt + c u with c the responsibility (0.5 toward cooperating robots, 1 toward dynamic obstacles),
    normal to the VO boundary. Overlapping pairs use the cut-off circle of horizon ``dt``: they separate
    within one control period. Shapes: (B,2), (B,2), (B,), (B,M,2), (B,M,2), (B,M), (B,M), (B,M).
    """
    p = np.asarray(position, dtype=float)[:, None, :]
    v = np.asarray(velocity, dtype=float)[:, None, :]
    rpx = nbr_position[..., 0] - p[..., 0]
    rpy = nbr_position[..., 1] - p[..., 1]
    rvx = v[..., 0] - nbr_velocity[..., 0]
    rvy = v[..., 1] - nbr_velocity[..., 1]
    dist2 = rpx * rpx + rpy * rpy
    big_r = np.asarray(radius, dtype=float)[:, None] + nbr_radius
    big_r2 = big_r * big_r
    apart = dist2 > big_r2
    # cut-off circle centre: relative position / horizon (tau if apart, dt if overlapping)
    inv_h = np.where(apart, 1.0 / tau, 1.0 / dt)
    wx = rvx - inv_h * rpx
    wy = rvy - inv_h * rpy
    w2 = wx * wx + wy * wy
    dot1 = wx * rpx + wy * rpy
    on_circle = ~apart | ((dot1 < 0.0) & (dot1 * dot1 > big_r2 * w2))
    # circle: u points from the relative velocity to the nearest point of the cut-off circle
    wl = np.sqrt(w2)
    degenerate = wl == 0.0  # only when overlapping with relative velocity exactly rel_p/dt
    wl_safe = np.where(degenerate, 1.0, wl)
    ux_c = np.where(degenerate, 1.0, wx / wl_safe)
    uy_c = np.where(degenerate, 0.0, wy / wl_safe)
    circ_dx, circ_dy = uy_c, -ux_c
    scale = big_r * inv_h - wl
    circ_ux, circ_uy = scale * ux_c, scale * uy_c
    # legs: project the relative velocity on the nearer leg of the cone
    leg = np.sqrt(np.maximum(dist2 - big_r2, 0.0))
    leg = np.where(rpx * wy - rpy * wx > 0.0, leg, -leg)  # left leg, or right leg
    inv_d2 = 1.0 / np.where(dist2 > 0.0, dist2, 1.0)
    ldx = (rpx * leg - rpy * big_r) * inv_d2
    ldy = (rpy * leg + rpx * big_r) * inv_d2
    dot2 = rvx * ldx + rvy * ldy
    leg_ux = dot2 * ldx - rvx
    leg_uy = dot2 * ldy - rvy
    dx = np.where(on_circle, circ_dx, ldx)
    dy = np.where(on_circle, circ_dy, ldy)
    ux = np.where(on_circle, circ_ux, leg_ux)
    uy = np.where(on_circle, circ_uy, leg_uy)
    c = nbr_responsibility
    point = np.stack([v[..., 0] + c * ux, v[..., 1] + c * uy], axis=-1)
    return Lines(point, np.stack([dx, dy], axis=-1), np.asarray(nbr_valid, dtype=bool).copy())


def polygon_segments(vertices: ArrayLike) -> np.ndarray:
    """Edges (S,2,2) of a closed polygon: counter-clockwise for an obstacle, clockwise for an enclosing
    wall (RVO2's convention; the free side is then on the right of every edge)."""
    vert = np.asarray(vertices, dtype=float)
    return np.stack([vert, np.roll(vert, -1, axis=0)], axis=1)


def arena_segments(xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    """Walls enclosing the rectangle [xmin,xmax] x [ymin,ymax] (clockwise)."""
    return polygon_segments([(xmin, ymin), (xmin, ymax), (xmax, ymax), (xmax, ymin)])


def obstacle_lines(
    position: ArrayLike, radius: ArrayLike, max_speed: ArrayLike, segments: ArrayLike, tau_obst: float
) -> Lines:
    """Half-planes keeping each robot at least its radius from each obstacle edge for tau_obst.

    Each edge is a segment; q is its point closest to the robot, n the unit vector from q to the robot
    and d their distance. The segment lies in {x: (x - q).n <= 0} (q is a projection onto a convex set),
    so a robot whose centre stays in {(x - q).n >= r} clears it: with velocity v for time tau_obst that
    holds iff v.n >= -(d - r)/tau_obst. An overlapping robot may only move away (v.n >= 0). Edges whose
    line the speed disk already satisfies are marked invalid. Shapes: (B,2), (B,), (B,) or scalar,
    (S,2,2) -> (B,S) lines.
    """
    p = np.asarray(position, dtype=float)
    b = p.shape[0]
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    if seg.shape[0] == 0:
        return Lines(np.zeros((b, 0, 2)), np.zeros((b, 0, 2)), np.zeros((b, 0), dtype=bool))
    ax, ay = seg[None, :, 0, 0], seg[None, :, 0, 1]
    ex, ey = seg[None, :, 1, 0] - ax, seg[None, :, 1, 1] - ay
    px, py = p[:, 0:1], p[:, 1:2]
    len2 = ex * ex + ey * ey
    t = np.clip(((px - ax) * ex + (py - ay) * ey) / np.where(len2 > 0.0, len2, 1.0), 0.0, 1.0)
    nx = px - (ax + t * ex)
    ny = py - (ay + t * ey)
    d = np.sqrt(nx * nx + ny * ny)
    on = d == 0.0
    # centre exactly on the edge: the free side is on the edge's right
    el = np.sqrt(np.where(len2 > 0.0, len2, 1.0))
    nx = np.where(on, ey / el, nx / np.where(on, 1.0, d))
    ny = np.where(on, -ex / el, ny / np.where(on, 1.0, d))
    r = np.asarray(radius, dtype=float).reshape(-1, 1) * _BUFFER  # rounding must not touch
    offset = np.maximum(d - r, 0.0) / tau_obst
    point = np.stack([-nx * offset, -ny * offset], axis=-1)
    direction = np.stack([ny, -nx], axis=-1)
    vmax = np.broadcast_to(np.asarray(max_speed, dtype=float), (b,))[:, None]
    valid = offset < vmax
    return Lines(point, direction, valid)


def concat_lines(*parts: Lines) -> Lines:
    """Lines of several groups side by side (hard groups first)."""
    return Lines(
        np.concatenate([x.point for x in parts], axis=1),
        np.concatenate([x.direction for x in parts], axis=1),
        np.concatenate([x.valid for x in parts], axis=1),
    )


def compact_lines(lines: Lines) -> Lines:
    """Move each robot's valid lines to the front in their order and drop all-invalid columns
    (fewer lines for the program; per-robot results are unchanged)."""
    valid = lines.valid
    if valid.shape[1] == 0:
        return lines
    n = int(valid.sum(axis=1).max()) if valid.size else 0
    if n == valid.shape[1] and valid.all():
        return lines
    order = (np.arange(valid.shape[0])[:, None], np.argsort(~valid, axis=1, kind="stable")[:, :n])
    return Lines(lines.point[order], lines.direction[order], valid[order])


def drop_redundant(lines: Lines, max_speed: np.ndarray) -> Lines:
    """Invalidate lines that the whole speed disk satisfies, then compact (results are unchanged)."""
    p, d = lines.point, lines.direction
    # min over the disk of det(d, v - p) is -R - det(d, p)
    needed = d[..., 0] * p[..., 1] - d[..., 1] * p[..., 0] > -max_speed[:, None]
    return compact_lines(Lines(p, d, lines.valid & needed))


def safety_lines(
    position: ArrayLike,
    radius: ArrayLike,
    max_speed: np.ndarray,
    nbr_position: np.ndarray,
    nbr_velocity: np.ndarray,
    nbr_radius: np.ndarray,
    nbr_responsibility: np.ndarray,
    nbr_valid: ArrayLike,
    dt: float,
    nbr_growth: ArrayLike | None = None,
) -> Lines:
    """ORCA half-planes of horizon ``dt`` around zero optimisation velocities (cooperating neighbours).

    Reciprocal and always jointly satisfiable by cooperating robots (v = 0 is in every one): if both
    robots of a pair keep theirs, they do not overlap within the next control period. Toward a
    cooperating neighbour this reads v.p_hat <= gap / (2 dt), so only neighbours closer than
    2 dt max_speed are kept. Dynamic obstacles (responsibility >= 1) keep their velocity.
    """
    p = np.asarray(position, dtype=float)
    b = p.shape[0]
    ex = nbr_position[..., 0] - p[:, None, 0]
    ey = nbr_position[..., 1] - p[:, None, 1]
    dist = np.sqrt(ex * ex + ey * ey)
    own = np.asarray(radius, dtype=float)[:, None] * _BUFFER
    nbr_radius = nbr_radius * _BUFFER
    if nbr_growth is not None:
        # A neighbour heard late has its radius grown by how far it may have strayed
        # (``nbr_growth``, prepare_neighbours). Grown over us, its line would say "leave its possible
        # positions within dt"; several such lines at once have no common solution, and the
        # least-violation answer then breaks the lines of the neighbours we know well (contacts under
        # loss). Grown only up to our surface it says "do not approach it", which v = 0 keeps.
        certain = nbr_radius - np.asarray(nbr_growth, dtype=float) * _BUFFER
        nbr_radius = np.minimum(nbr_radius, np.maximum(dist * (1.0 - 1e-9) - own, certain))
    gap = dist - (own + nbr_radius)
    keep = np.asarray(nbr_responsibility) >= 1.0
    needed = np.asarray(nbr_valid, dtype=bool) & (keep | (gap < 2.0 * dt * max_speed[:, None]))
    n = int(needed.sum(axis=1).max()) if needed.size else 0
    order = (np.arange(b)[:, None], np.argsort(~needed, axis=1, kind="stable")[:, :n])
    return orca_lines(
        p,
        np.zeros((b, 2)),
        own[:, 0],
        nbr_position[order],
        np.where(keep[order][..., None], nbr_velocity[order], 0.0),
        nbr_radius[order],
        nbr_responsibility[order],
        needed[order],
        dt,
        dt,
    )


def orca_velocity(
    position: ArrayLike,
    velocity: ArrayLike,
    pref_velocity: ArrayLike,
    radius: ArrayLike,
    max_speed: ArrayLike,
    nbr_position: ArrayLike,
    nbr_velocity: ArrayLike,
    nbr_radius: ArrayLike,
    nbr_responsibility: ArrayLike,
    nbr_valid: ArrayLike,
    obstacle_segments: np.ndarray | None = None,
    *,
    tau: float,
    tau_obst: float,
    dt: float,
    extra_hard_lines: Lines | None = None,
    safety: bool = True,
    margin: float = 0.0,
    nbr_growth: ArrayLike | None = None,
    nbr_lead: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Collision-free velocity of eq. 14 for a batch of holonomic robots.

    Shapes: position, velocity (the optimisation velocity: the current one), pref_velocity (B,2);
    radius, max_speed (B,) or scalars; neighbours (B,M,...) sorted nearest first (the fallback takes
    them in order), invalid entries padded; obstacle_segments (S,2,2) shared by the batch.
    ``extra_hard_lines`` (e.g. a kinematic polygon) are kept hard with the obstacle lines.
    ``margin`` is added to every radius (own and neighbours') in the ORCA lines of the robots (not
    in the safety lines): crowds keep a little slack, the fallback may squeeze into it.
    ``nbr_growth`` (B,M): the part of each neighbour's radius that is how far it may have strayed
    since its state (`prepare_neighbours`); the safety lines grow it only up to our surface, the
    robot lines not at all (with ``safety``: the safety lines alone keep us off its possible places).
    ``nbr_lead`` (B,M): with ``safety``, the robot lines take each neighbour this many seconds further
    along its velocity, where it most likely is (`prepare_neighbours`).

    With ``safety`` (the default):

    * the `safety_lines` (no overlap within dt, true radii) are hard, like the obstacle lines;
    * where the program is infeasible the robots' horizon is divided by 4 until it is feasible, down
      to dt (paper 5.3);
    * below that, the largest violation of the robot lines of horizon dt is minimised keeping the
      hard lines (RVO2's fallback). The robot never stops dead, which jams crowds.

    Without it the result is RVO2's (no safety lines, least violation at the full horizon).
    Returns (new velocity (B,2), fallback (B,) bool: infeasible at the full horizon).
    """
    position = np.asarray(position, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    pref_velocity = np.asarray(pref_velocity, dtype=float)
    b = position.shape[0]
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (b,))
    max_speed = np.broadcast_to(np.asarray(max_speed, dtype=float), (b,))
    nbr = (
        np.asarray(nbr_position, dtype=float),
        np.asarray(nbr_velocity, dtype=float),
        np.asarray(nbr_radius, dtype=float),
        np.asarray(nbr_responsibility, dtype=float),
        np.asarray(nbr_valid, dtype=bool),
    )
    if b == 1 and safety:
        try:
            one = _orca_velocity_one(
                position,
                velocity,
                pref_velocity,
                radius,
                max_speed,
                nbr,
                obstacle_segments,
                extra_hard_lines,
                None if nbr_growth is None else np.asarray(nbr_growth, dtype=float),
                None if nbr_lead is None else np.asarray(nbr_lead, dtype=float),
                float(tau),
                float(tau_obst),
                float(dt),
                float(margin),
            )
            if one is not None:
                return one
        except NumpyDecides:
            pass
    hard = []
    if obstacle_segments is not None and len(obstacle_segments):
        # Static obstacles do not move and do not help: the margin (e.g. the tracking-noise bound)
        # keeps a noisy own position off them.
        hard.append(obstacle_lines(position, radius + margin, max_speed, obstacle_segments, tau_obst))
    if extra_hard_lines is not None:
        hard.append(extra_hard_lines)
    if safety:
        hard.append(safety_lines(position, radius, max_speed, *nbr, dt, nbr_growth))
    hard_lines = drop_redundant(concat_lines(*hard), max_speed) if hard else None
    # The robot lines take a neighbour heard late where it most likely is, its body not grown: the
    # hard safety lines above keep us off every place it may have strayed to, and the long
    # horizon's cone over those places would make crowds heard late jam where they pass on time.
    likely, certain = nbr[0], nbr[2]
    if safety and nbr_lead is not None:
        likely = nbr[0] + np.asarray(nbr_lead, dtype=float)[..., None] * nbr[1]
    if safety and nbr_growth is not None:
        certain = nbr[2] - np.asarray(nbr_growth, dtype=float)
    grown = (likely, nbr[1], certain + margin, *nbr[3:])

    def program(rows, horizon):
        robots = orca_lines(
            position[rows], velocity[rows], radius[rows] + margin, *(x[rows] for x in grown), horizon, dt
        )
        robots = drop_redundant(robots, max_speed[rows])
        if hard_lines is None:
            return robots, 0
        return concat_lines(Lines(*(x[rows] for x in hard_lines)), robots), hard_lines.valid.shape[1]

    lines, n_hard = program(slice(None), tau)
    if not safety:
        return linear_program(lines.point, lines.direction, lines.valid, max_speed, pref_velocity, n_hard=n_hard)
    new_velocity, feasible = optimise(lines.point, lines.direction, lines.valid, max_speed, pref_velocity)
    rows = np.nonzero(~feasible)[0]
    lines = Lines(*(x[rows] for x in lines))
    horizon = tau
    while rows.size and horizon > dt:
        horizon = max(horizon / _SHRINK, dt)
        lines, n_hard = program(rows, horizon)
        v, ok = optimise_few(lines.point, lines.direction, lines.valid, max_speed[rows], pref_velocity[rows])
        new_velocity[rows[ok]] = v[ok]
        rows = rows[~ok]
        lines = Lines(*(x[~ok] for x in lines))
    if rows.size:
        new_velocity[rows] = least_violation(
            lines.point, lines.direction, lines.valid, max_speed[rows], pref_velocity[rows], n_hard
        )
    return new_velocity, ~feasible


# A batch of one robot (an agent process): orca_velocity with safety lines on Python floats, the
# same operations in the same order as the numpy code above (numpy's per-call overhead dominates
# on arrays of one). Lines are tuples (px, py, dx, dy); only valid ones are kept, in the numpy
# code's order (they are all an LP of one robot looks at).


def _orca_line(
    px: float,
    py: float,
    vx: float,
    vy: float,
    r: float,
    qx: float,
    qy: float,
    nvx: float,
    nvy: float,
    nr: float,
    c: float,
    inv_tau: float,
    inv_dt: float,
) -> Line:
    """`orca_lines` of one robot toward one neighbour (position q, velocity nv, radius nr)."""
    rpx = qx - px
    rpy = qy - py
    rvx = vx - nvx
    rvy = vy - nvy
    dist2 = rpx * rpx + rpy * rpy
    big_r = r + nr
    big_r2 = big_r * big_r
    apart = dist2 > big_r2
    inv_h = inv_tau if apart else inv_dt
    wx = rvx - inv_h * rpx
    wy = rvy - inv_h * rpy
    w2 = wx * wx + wy * wy
    dot1 = wx * rpx + wy * rpy
    if not apart or (dot1 < 0.0 and dot1 * dot1 > big_r2 * w2):
        wl = math.sqrt(w2)
        ux_c, uy_c = (1.0, 0.0) if wl == 0.0 else (wx / wl, wy / wl)
        dx, dy = uy_c, -ux_c
        scale = big_r * inv_h - wl
        ux, uy = scale * ux_c, scale * uy_c
    else:
        leg = math.sqrt(dist2 - big_r2)  # apart: positive
        if not rpx * wy - rpy * wx > 0.0:
            leg = -leg
        inv_d2 = 1.0 / (dist2 if dist2 > 0.0 else 1.0)
        dx = (rpx * leg - rpy * big_r) * inv_d2
        dy = (rpy * leg + rpx * big_r) * inv_d2
        dot2 = rvx * dx + rvy * dy
        ux = dot2 * dx - rvx
        uy = dot2 * dy - rvy
    return vx + c * ux, vy + c * uy, dx, dy


def _obstacle_lines_one(px: float, py: float, r: float, vmax: float, segments: list, tau_obst: float) -> list[Line]:
    """`obstacle_lines` of one robot: its valid lines, edge by edge."""
    r = r * _BUFFER
    out = []
    for (ax, ay), (bx, by) in segments:
        ex, ey = bx - ax, by - ay
        len2 = ex * ex + ey * ey
        t = ((px - ax) * ex + (py - ay) * ey) / (len2 if len2 > 0.0 else 1.0)
        if t == 0.0 and (ax == 0.0 or ay == 0.0):
            raise NumpyDecides  # np.clip keeps +0 or -0, which would show in ax + t ex
        t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
        nx = px - (ax + t * ex)
        ny = py - (ay + t * ey)
        d = math.sqrt(nx * nx + ny * ny)
        if d == 0.0:
            el = math.sqrt(len2 if len2 > 0.0 else 1.0)
            nx, ny = ey / el, -ex / el
        else:
            nx, ny = nx / d, ny / d
        gap = d - r
        offset = (gap if gap > 0.0 else 0.0) / tau_obst  # d - r is never -0
        if offset < vmax:
            out.append((-nx * offset, -ny * offset, ny, -nx))
    return out


def _orca_velocity_one(
    position, velocity, pref_velocity, radius, max_speed, nbr, segments, extra, growth, lead, tau, tau_obst, dt, margin
):
    """orca_velocity (with safety) of a batch of one robot from its arrays; None where the Python
    floats might not be numpy's (inputs not finite or huge)."""
    (px, py), (vx, vy), (tx, ty) = position[0].tolist(), velocity[0].tolist(), pref_velocity[0].tolist()
    r, vmax = float(radius[0]), float(max_speed[0])
    valid = nbr[4][0].tolist()
    grow = [0.0] * len(valid) if growth is None else growth[0].tolist()
    leads = [0.0] * len(valid) if lead is None else lead[0].tolist()
    nbrs = [
        (q, w, nr, c, g, a)
        for q, w, nr, c, g, a, ok in zip(
            nbr[0][0].tolist(), nbr[1][0].tolist(), nbr[2][0].tolist(), nbr[3][0].tolist(), grow, leads, valid
        )
        if ok
    ]
    seg = segments_one(segments)
    extra_lines = []
    if extra is not None:
        ep, ed = extra.point[0].tolist(), extra.direction[0].tolist()
        extra_lines = [(*p, *d) for p, d, ok in zip(ep, ed, extra.valid[0].tolist()) if ok]
    flat = [x for q, w, nr, c, g, a in nbrs for x in (*q, *w, nr, c, g, a)]
    if not plain([px, py, vx, vy, tx, ty, r, vmax, tau, tau_obst, dt, margin], flat, seg_values(seg)):
        return None
    if not plain([x for line in extra_lines for x in line]):
        return None
    x, y, fallback = orca_velocity_one(
        px, py, vx, vy, tx, ty, r, vmax, nbrs, seg, extra_lines, growth is not None, tau, tau_obst, dt, margin
    )
    return np.array([[x, y]]), np.array([fallback])


def segments_one(segments: np.ndarray | None) -> list:
    """Obstacle edges as nested lists ((ax, ay), (bx, by)) for `orca_velocity_one`."""
    return [] if segments is None else np.asarray(segments, dtype=float).reshape(-1, 2, 2).tolist()


def seg_values(seg: list) -> list[float]:
    return [x for s in seg for p in s for x in p]


def orca_velocity_one(
    px: float,
    py: float,
    vx: float,
    vy: float,
    tx: float,
    ty: float,
    r: float,
    vmax: float,
    nbrs: list[tuple],
    seg: list,
    extra_lines: list[Line],
    grown: bool,
    tau: float,
    tau_obst: float,
    dt: float,
    margin: float,
) -> tuple[float, float, bool]:
    """orca_velocity with safety lines for one robot on Python floats (finite, at most
    lp._PLAIN_LIMIT): the same operations in the same order. ``nbrs``: the valid neighbours as
    ((x, y), (vx, vy), radius, responsibility, growth, lead); ``grown``: whether growths were given.
    Returns (x, y, fallback); raises NumpyDecides where numpy's bits could differ."""
    hard = _obstacle_lines_one(px, py, r + margin, vmax, seg, tau_obst) if seg else []
    hard += extra_lines
    own = r * _BUFFER
    inv_dt = 1.0 / dt
    reach = 2.0 * dt * vmax
    for (qx, qy), (wx, wy), nr, c, g, _ in nbrs:
        ex = qx - px
        ey = qy - py
        dist = math.sqrt(ex * ex + ey * ey)
        nr = nr * _BUFFER
        if grown:
            certain = nr - g * _BUFFER
            nr = np_minimum(nr, np_maximum(dist * (1.0 - 1e-9) - own, certain))
        keep = c >= 1.0
        if keep or dist - (own + nr) < reach:
            if not keep:
                wx = wy = 0.0
            hard.append(_orca_line(px, py, 0.0, 0.0, own, qx, qy, wx, wy, nr, c, inv_dt, inv_dt))
    hard = [line for line in hard if line[2] * line[1] - line[3] * line[0] > -vmax]  # drop_redundant
    r_grown = r + margin

    def program(horizon: float) -> list[Line]:
        inv_h = 1.0 / horizon
        lines = list(hard)
        for (qx, qy), (wx, wy), nr, c, g, a in nbrs:
            qx, qy = qx + a * wx, qy + a * wy
            line = _orca_line(px, py, vx, vy, r_grown, qx, qy, wx, wy, nr - g + margin, c, inv_h, inv_dt)
            if line[2] * line[1] - line[3] * line[0] > -vmax:
                lines.append(line)
        return lines

    lines = program(tau)
    x, y, feasible = optimise_one(lines, vmax, tx, ty, False)
    if feasible:
        return x, y, False
    horizon = tau
    while horizon > dt:
        horizon = max(horizon / _SHRINK, dt)
        lines = program(horizon)
        x, y, ok = optimise_few_one(lines, vmax, tx, ty, False)
        if ok:
            return x, y, True
    arr = np.array(lines, dtype=float).reshape(1, -1, 4)
    every = np.ones(arr.shape[:2], dtype=bool)
    v = least_violation(arr[..., :2], arr[..., 2:], every, np.array([vmax]), np.array([[tx, ty]]), len(hard))
    return float(v[0, 0]), float(v[0, 1]), True
