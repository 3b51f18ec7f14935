"""The 2-D linear program of ORCA (paper eq. 13-14), vectorised over a batch of robots.

A constraint line is a point ``p`` and a unit direction ``d``; the permissible half-plane is to the
LEFT of ``d`` (RVO2's convention): ``det(d, v - p) >= 0``. A velocity violates a line by
``det(d, p - v)`` when that is positive.

Two problems are solved, with RVO2's algorithms and semantics:

* the optimum (eq. 14, `optimise`): the velocity in the speed disk and in every half-plane closest to
  the preferred velocity, or (``directional``) the one furthest along a unit direction. Incremental:
  lines are added in order; where the current optimum violates a line, the new optimum lies on it
  (a 1-D problem on that line, clipped by the earlier lines and the disk);
* the fallback when that is infeasible (`least_violation`, RVO2's "linearProgram3"): the leading
  ``n_hard`` lines (obstacles, kinematic polygon, safety) stay hard and the largest violation of the
  remaining (robot) lines is minimised, one directional 2-D program per soft line.

Vectorised across robots with numpy, looping in Python over the line index only.
Determinism: only elementwise + - * / sqrt and comparisons, and min/max/any along the line axis, never
a reduction across robots, so a robot's result is bit-identical whether it is solved alone or in a
batch (padded lines being invalid).

A batch of one robot (an agent process) takes plain-Python twins of `optimise` and `optimise_few`
(numpy's per-call overhead dominates on arrays of one): the same IEEE double operations in the same
order on Python floats. Where the twins could disagree with numpy they hand over to it: inputs not
finite or huge (no overflow, hence no NaN, can then occur), and a minimum or maximum between +0 and
-0 (which one numpy keeps is its own choice) where the sign could show in the result.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

# Two unit directions are treated as parallel below this |det| (RVO2 uses the same tolerance).
EPSILON = 1e-5

__all__ = ["EPSILON", "linear_program", "least_violation", "optimise", "optimise_few"]


def _on_line(pix, piy, dix, diy, px, py, dx, dy, valid, radius, tx, ty, directional, axis=0):
    """The 1-D problem on lines i clipped by the disk and the lines j, along ``axis`` of the j
    arrays; the i arrays have length 1 on that axis, and so have the results.

    Returns (x, y, ok); not ok where the disk and the lines leave nothing of line i.
    """
    dot = pix * dix + piy * diy
    disc = dot * dot + radius * radius - (pix * pix + piy * piy)
    ok = disc >= 0.0
    sq = np.sqrt(np.maximum(disc, 0.0))
    t_left = -dot - sq
    t_right = -dot + sq
    if px.shape[axis]:
        den = dix * dy - diy * dx  # det(d_i, d_j)
        num = dx * (piy - py) - dy * (pix - px)
        par = np.abs(den) <= EPSILON
        # a parallel line with line i on its forbidden side empties line i
        ok = ok & ~(valid & par & (num < 0.0)).any(axis=axis, keepdims=True)
        t = num / np.where(par, 1.0, den)
        use = valid & ~par
        t_right = np.minimum(t_right, np.where(use & (den > 0.0), t, np.inf).min(axis=axis, keepdims=True))
        t_left = np.maximum(t_left, np.where(use & (den < 0.0), t, -np.inf).max(axis=axis, keepdims=True))
        ok &= t_left <= t_right
    if directional:
        t_best = np.where(tx * dix + ty * diy > 0.0, t_right, t_left)
    else:
        t_best = np.minimum(np.maximum(dix * (tx - pix) + diy * (ty - piy), t_left), t_right)
    return pix + t_best * dix, piy + t_best * diy, ok


class NumpyDecides(Exception):
    """A plain-Python twin met a case where it might not give numpy's bits: run the numpy code."""


# Inputs of a plain-Python twin are at most this large: every intermediate then stays finite.
_PLAIN_LIMIT = 1e50


def plain(*values: list[float]) -> bool:
    """All values finite and at most _PLAIN_LIMIT in magnitude (NaN fails the comparison)."""
    return all(all(map(_PLAIN_LIMIT.__gt__, map(abs, v))) for v in values)


def _zeros_differ(a: float, b: float) -> bool:
    """a and b are +0 and -0: equal, but which one numpy's min or max keeps is numpy's choice."""
    return a == 0.0 and b == 0.0 and math.copysign(1.0, a) != math.copysign(1.0, b)


def np_maximum(a: float, b: float) -> float:
    """np.maximum of two finite Python floats (NumpyDecides on a +0/-0 tie)."""
    if a > b:
        return a
    if a < b or not _zeros_differ(a, b):
        return b
    raise NumpyDecides


def np_minimum(a: float, b: float) -> float:
    """np.minimum of two finite Python floats (NumpyDecides on a +0/-0 tie)."""
    if a < b:
        return a
    if a > b or not _zeros_differ(a, b):
        return b
    raise NumpyDecides


Line = tuple[float, float, float, float]  # one robot's line on Python floats: (px, py, dx, dy)


def _on_line_one(
    pix: float,
    piy: float,
    dix: float,
    diy: float,
    lines: list[Line],
    radius: float,
    tx: float,
    ty: float,
    directional: bool,
) -> tuple[float, float, bool]:
    """`_on_line` for one robot on Python floats: line i clipped by the disk and ``lines`` (the valid
    lines j, tuples (px, py, dx, dy)). Where it is not ok the point is not used and not computed."""
    dot = pix * dix + piy * diy
    disc = dot * dot + radius * radius - (pix * pix + piy * piy)
    if disc < 0.0:
        return 0.0, 0.0, False
    sq = math.sqrt(disc)  # disc is +0 or more: a sum of squares minus one, never -0
    t_left = -dot - sq
    t_right = -dot + sq
    # Folding the disk's ends in first gives the values of numpy's min/max over the lines then
    # against the ends. Only the sign of a zero can differ (numpy keeps +0 or -0 on a tie), and it
    # only shows in the point if the line's point has a zero coordinate.
    for px, py, dx, dy in lines:
        den = dix * dy - diy * dx
        num = dx * (piy - py) - dy * (pix - px)
        if -EPSILON <= den <= EPSILON:  # |den| <= EPSILON
            if num < 0.0:
                return 0.0, 0.0, False
            continue
        t = num / den
        if den > 0.0:
            if t < t_right:
                t_right = t
                if t_right < t_left:
                    return 0.0, 0.0, False
        elif t > t_left:
            t_left = t
            if t_right < t_left:
                return 0.0, 0.0, False
    if directional:
        t_best = t_right if tx * dix + ty * diy > 0.0 else t_left
    else:
        t_best = dix * (tx - pix) + diy * (ty - piy)
        if t_best <= t_left:
            t_best = t_left
        if t_best >= t_right:
            t_best = t_right
    if t_best == 0.0 and (pix == 0.0 or piy == 0.0):
        raise NumpyDecides
    return pix + t_best * dix, piy + t_best * diy, True


def _disk_optimum_one(tx: float, ty: float, radius: float, directional: bool) -> tuple[float, float]:
    """`_disk_optimum` on Python floats."""
    if directional:
        return tx * radius, ty * radius
    n2 = tx * tx + ty * ty
    scale = radius / math.sqrt(n2) if n2 > radius * radius else 1.0
    return tx * scale, ty * scale


class _One(NamedTuple):
    """One robot's program on Python floats: its valid lines, speed-disk radius and target."""

    lines: list[Line]
    radius: float
    tx: float
    ty: float


def _lines_one(
    point: np.ndarray, direction: np.ndarray, valid: np.ndarray, radius: np.ndarray, target: np.ndarray
) -> _One | None:
    """One robot's valid lines as tuples (px, py, dx, dy), its radius and target (tx, ty) as Python
    floats; None where the plain-Python twins may not be used."""
    if point.dtype != np.float64 or direction.dtype != np.float64:
        return None
    p = point.reshape(-1).tolist()
    d = direction.reshape(-1).tolist()
    r = float(radius.reshape(-1)[0])
    tx, ty = target.reshape(-1).tolist()
    if not plain(p, d, [r, tx, ty]):
        return None
    lines = [line for line, ok in zip(zip(p[0::2], p[1::2], d[0::2], d[1::2]), valid.reshape(-1).tolist()) if ok]
    return _One(lines, r, tx, ty)


def _solve_one(solve, point, direction, valid, radius, target, directional):
    """A batch of one robot by its plain-Python twin ``solve``, as the batch's arrays; None where the
    numpy code must decide (see `_lines_one` and NumpyDecides)."""
    single = _lines_one(point, direction, valid, np.asarray(radius), target)
    if single is None:
        return None
    try:
        x, y, ok = solve(single.lines, single.radius, single.tx, single.ty, directional)
    except NumpyDecides:
        return None
    return np.array([[x, y]]), np.array([ok])


def optimise_one(
    lines: list[Line], radius: float, tx: float, ty: float, directional: bool
) -> tuple[float, float, bool]:
    """`optimise` for one robot on Python floats: (x, y, feasible)."""
    rx, ry = _disk_optimum_one(tx, ty, radius, directional)
    for i, (px, py, dx, dy) in enumerate(lines):
        if dx * (py - ry) - dy * (px - rx) > 0.0:
            x, y, ok = _on_line_one(px, py, dx, dy, lines[:i], radius, tx, ty, directional)
            if not ok:
                return rx, ry, False  # a robot stops at its first unsatisfiable line
            rx, ry = x, y
    return rx, ry, True


def optimise_few_one(
    lines: list[Line], radius: float, tx: float, ty: float, directional: bool
) -> tuple[float, float, bool]:
    """`optimise_few` for one robot on Python floats: (x, y, feasible). Candidates in line order,
    each clipped by every line (itself included); ties go to the first, as argmin's."""
    cx, cy = _disk_optimum_one(tx, ty, radius, directional)
    violated, best_cost, best = False, math.inf, None
    for px, py, dx, dy in lines:
        if not dx * (py - cy) - dy * (px - cx) > 0.0:
            continue
        violated = True
        x, y, ok = _on_line_one(px, py, dx, dy, lines, radius, tx, ty, directional)
        if not ok:
            continue
        if directional:
            cost = -(tx * x + ty * y)
        else:
            ex, ey = x - tx, y - ty
            cost = ex * ex + ey * ey
        if best is None or cost < best_cost:
            best_cost, best = cost, (x, y)
    if not violated:
        return cx, cy, True
    if best is None:
        return cx, cy, False
    return best[0], best[1], True


def _disk_optimum(
    tx: np.ndarray, ty: np.ndarray, radius: np.ndarray, directional: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The optimum over the speed disk alone: the target clipped to the disk, or with
    ``directional`` the disk's furthest point along the unit direction."""
    if directional:
        return tx * radius, ty * radius
    n2 = tx * tx + ty * ty
    outside = n2 > radius * radius
    scale = np.where(outside, radius / np.sqrt(np.where(outside, n2, 1.0)), 1.0)
    return tx * scale, ty * scale


def optimise(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    radius: np.ndarray,
    target: np.ndarray,
    directional: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Optimum over the speed disk D(0, radius) and the valid half-planes (RVO2's linearProgram2).

    ``target`` (B,2) is the velocity to get closest to, or with ``directional`` a unit direction to
    go furthest along. Returns (velocity (B,2), feasible (B,)); where infeasible the velocity is
    the optimum over the lines before the first one that could not be met.
    """
    if len(target) == 1:
        solved = _solve_one(optimise_one, point, direction, valid, radius, target, directional)
        if solved is not None:
            return solved
    # line-major copies (L, B): the loop over lines reads contiguous rows
    px, py = np.ascontiguousarray(point[..., 0].T), np.ascontiguousarray(point[..., 1].T)
    dx, dy = np.ascontiguousarray(direction[..., 0].T), np.ascontiguousarray(direction[..., 1].T)
    valid = np.asarray(valid, dtype=bool).T
    radius = np.asarray(radius, dtype=float)
    tx, ty = target[:, 0], target[:, 1]
    rx, ry = _disk_optimum(tx, ty, radius, directional)
    feasible = np.ones(len(rx), dtype=bool)
    for i in range(valid.shape[0]):
        viol = valid[i] & feasible & (dx[i] * (py[i] - ry) - dy[i] * (px[i] - rx) > 0.0)
        rows = np.nonzero(viol)[0]
        if rows.size == 0:
            continue
        one = slice(i, i + 1)
        x, y, ok = _on_line(
            px[one, rows],
            py[one, rows],
            dx[one, rows],
            dy[one, rows],
            px[:i, rows],
            py[:i, rows],
            dx[:i, rows],
            dy[:i, rows],
            valid[:i, rows],
            radius[rows],
            tx[rows],
            ty[rows],
            directional,
        )
        x, y, ok = x[0], y[0], ok[0]
        rx[rows] = np.where(ok, x, rx[rows])
        ry[rows] = np.where(ok, y, ry[rows])
        feasible[rows[~ok]] = False  # a robot stops at its first unsatisfiable line
    return np.stack([rx, ry], axis=-1), feasible


def optimise_few(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    radius: np.ndarray,
    target: np.ndarray,
    directional: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """`optimise` without a loop over lines, for few robots (fewer, larger numpy operations).

    The optimum is on a line that the disk's optimum c0 violates (from any other feasible point,
    moving toward c0 would improve it): each such line's 1-D optimum, clipped by the disk and every
    valid line at once (arrays (k, candidates, L)), is a candidate; the best one wins. Same optimum
    as `optimise` up to rounding; a call site must always use the same one (determinism).
    """
    if len(target) == 1:
        solved = _solve_one(optimise_few_one, point, direction, valid, radius, target, directional)
        if solved is not None:
            return solved
    px, py = point[..., 0], point[..., 1]
    dx, dy = direction[..., 0], direction[..., 1]
    radius = np.asarray(radius, dtype=float)
    tx, ty = target[:, 0], target[:, 1]
    cx, cy = _disk_optimum(tx, ty, radius, directional)
    violated = valid & (dx * (py - cy[:, None]) - dy * (px - cx[:, None]) > 0.0)
    feasible = np.ones(len(cx), dtype=bool)
    rows = np.nonzero(violated.any(axis=1))[0]
    if rows.size == 0:
        return np.stack([cx, cy], axis=-1), feasible
    px, py, dx, dy, valid, violated = (a[rows] for a in (px, py, dx, dy, valid, violated))
    k = len(rows)
    n_cand = int(violated.sum(axis=1).max())
    pick = (np.arange(k)[:, None], np.argsort(~violated, axis=1, kind="stable")[:, :n_cand])
    cpx, cpy, cdx, cdy = (a[pick][..., None] for a in (px, py, dx, dy))  # (k, candidates, 1)
    x, y, ok = _on_line(
        cpx,
        cpy,
        cdx,
        cdy,
        px[:, None, :],
        py[:, None, :],
        dx[:, None, :],
        dy[:, None, :],
        valid[:, None, :],
        radius[rows, None, None],
        tx[rows, None, None],
        ty[rows, None, None],
        directional,
        axis=2,
    )
    x, y, ok = x[..., 0], y[..., 0], ok[..., 0] & violated[pick]
    if directional:
        cost = -(tx[rows, None] * x + ty[rows, None] * y)
    else:
        ex, ey = x - tx[rows, None], y - ty[rows, None]
        cost = ex * ex + ey * ey
    best = (np.arange(k), np.argmin(np.where(ok, cost, np.inf), axis=1))
    cx, cy = cx.copy(), cy.copy()
    good = ok.any(axis=1)
    cx[rows] = np.where(good, x[best], cx[rows])
    cy[rows] = np.where(good, y[best], cy[rows])
    feasible[rows] = good
    return np.stack([cx, cy], axis=-1), feasible


def _least_violation(px, py, dx, dy, valid, hard, radius, vx, vy):
    """Minimise the largest violation of the soft lines keeping the hard ones (RVO2 linearProgram3).

    Starts from (vx, vy), which satisfies the hard lines; soft lines are taken in their given order
    and the hard lines lead.
    Each violated soft line i gives a 2-D program over the hard lines and the bisectors between line i
    and the earlier soft lines (where both are violated equally), maximising distance into line i.
    """
    k, n = px.shape
    vx, vy = vx.copy(), vy.copy()
    distance = np.zeros(k)
    soft = valid & ~hard
    for i in range(n):
        viol = dx[:, i] * (py[:, i] - vy) - dy[:, i] * (px[:, i] - vx)
        rows = np.nonzero(soft[:, i] & (viol > distance))[0]
        if rows.size == 0:
            continue
        # hard lines lead, so lines before i are the hard ones and the earlier soft ones
        pjx, pjy, djx, djy = px[rows, :i], py[rows, :i], dx[rows, :i], dy[rows, :i]
        pix, piy = px[rows, i : i + 1], py[rows, i : i + 1]
        dix, diy = dx[rows, i : i + 1], dy[rows, i : i + 1]
        den = dix * djy - diy * djx
        par = np.abs(den) <= EPSILON
        same = par & (dix * djx + diy * djy > 0.0)  # same direction: line i dominates, skip
        t = (djx * (piy - pjy) - djy * (pix - pjx)) / np.where(par, 1.0, den)
        qx = np.where(par, 0.5 * (pix + pjx), pix + t * dix)
        qy = np.where(par, 0.5 * (piy + pjy), piy + t * diy)
        bx, by = djx - dix, djy - diy
        bn = np.sqrt(bx * bx + by * by)
        bn = np.where(bn > 0.0, bn, 1.0)
        h = hard[rows, :i]
        use = h | (soft[rows, :i] & ~same)
        qx = np.where(h, pjx, qx)
        qy = np.where(h, pjy, qy)
        bx = np.where(h, djx, bx / bn)
        by = np.where(h, djy, by / bn)
        target = np.stack([-diy[:, 0], dix[:, 0]], axis=-1)  # left normal: into line i's half-plane
        res, ok = optimise_few(
            np.stack([qx, qy], -1), np.stack([bx, by], -1), use, radius[rows], target, directional=True
        )
        vx[rows] = np.where(ok, res[:, 0], vx[rows])
        vy[rows] = np.where(ok, res[:, 1], vy[rows])
        distance[rows] = dix[:, 0] * (piy[:, 0] - vy[rows]) - diy[:, 0] * (pix[:, 0] - vx[rows])
    return vx, vy


def least_violation(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    max_speed: ArrayLike,
    pref_velocity: np.ndarray,
    n_hard: ArrayLike = 0,
) -> np.ndarray:
    """The fallback alone: keep the leading ``n_hard`` lines (int or (B,)) hard, minimise the largest
    violation of the others (RVO2's linearProgram3), starting from the optimum over the hard lines.

    If the hard lines and the disk are infeasible by themselves, every line is soft for that robot
    (the least-violation point always exists). Returns the velocity (B,2).
    """
    point = np.asarray(point, dtype=float)
    direction = np.asarray(direction, dtype=float)
    valid = np.asarray(valid, dtype=bool)
    b, n = valid.shape
    radius = np.broadcast_to(np.asarray(max_speed, dtype=float), (b,))
    # Padding and dropped lines inside the hard block keep their geometry: only valid ones are hard
    # (else a robot's result would depend on the batch it is solved in).
    hard = valid & (np.arange(n) < np.broadcast_to(np.asarray(n_hard), (b,))[:, None])
    start, ok = optimise_few(point, direction, hard, radius, np.asarray(pref_velocity, dtype=float))
    hard &= ok[:, None]
    vx, vy = _least_violation(
        point[..., 0],
        point[..., 1],
        direction[..., 0],
        direction[..., 1],
        valid,
        hard,
        radius,
        start[:, 0],
        start[:, 1],
    )
    return np.stack([vx, vy], axis=-1)


def linear_program(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    max_speed: ArrayLike,
    pref_velocity: np.ndarray,
    n_hard: ArrayLike = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """New velocity of eq. 14 for a batch, with RVO2's fallback where it is infeasible.

    point, direction: (B, L, 2) lines (unit directions, permissible side on the left);
    valid: (B, L) bool; max_speed: scalar or (B,) speed-disk radius; pref_velocity: (B, 2);
    n_hard: int or (B,) ints, how many leading lines are hard in the fallback (obstacle and kinematic
    lines). Returns (velocity (B, 2), fallback (B,) bool: where the program was infeasible and
    `least_violation` gave the velocity).
    """
    point = np.asarray(point, dtype=float)
    direction = np.asarray(direction, dtype=float)
    valid = np.asarray(valid, dtype=bool)
    pref_velocity = np.asarray(pref_velocity, dtype=float)
    b = valid.shape[0]
    radius = np.broadcast_to(np.asarray(max_speed, dtype=float), (b,))
    velocity, feasible = optimise(point, direction, valid, radius, pref_velocity)
    fallback = ~feasible
    rows = np.nonzero(fallback)[0]
    if rows.size:
        n_hard = np.broadcast_to(np.asarray(n_hard), (b,))[rows]
        velocity[rows] = least_violation(
            point[rows], direction[rows], valid[rows], radius[rows], pref_velocity[rows], n_hard
        )
    return velocity, fallback
