"""The 2-D linear program of ORCA (paper eq. 13-14), vectorised over a batch of robots.

A constraint line is a point ``p`` and a unit direction ``d``; the permissible half-plane is to the
LEFT of ``d`` (RVO2's convention): ``det(d, v - p) >= 0``. A velocity violates a line by
``det(d, p - v)`` when that is positive.

Two problems are solved:

* the optimum (eq. 14): the velocity in the speed disk and in every half-plane closest to the preferred
  velocity, or (``directional``) the one furthest along a unit direction;
* the fallback when that is infeasible (RVO2's "linearProgram3" semantics): the leading ``n_hard``
  lines (obstacles, kinematic polygon) stay hard and the largest violation of the remaining (robot)
  lines is minimised, solved as RVO2 does, one 2-D program per soft line over projected lines.

Instead of the incremental (randomised) algorithm, the optimum is taken among candidates: the
unconstrained optimum if feasible, else the best point of each line's feasible segment (the optimum of a
convex problem lies on the boundary). Results equal the incremental algorithm's where the optimum is
unique, and it vectorises over lines as well as robots.

Determinism: only elementwise + - * / sqrt and comparisons, and min/max/argmin along the line axis are
used, never a reduction across robots, so a robot's result is bit-identical whether it is solved alone
or in a batch (padded lines being invalid).
"""
from __future__ import annotations

import numpy as np

# Two unit directions are treated as parallel below this |det| (RVO2 uses the same tolerance).
EPSILON = 1e-5

__all__ = ["EPSILON", "linear_program", "least_violation", "optimise"]


def _candidates(px, py, dx, dy, valid, radius, tx, ty, directional, violated):
    """Best point on the feasible segment of each line violated by the disk's optimum.

    The optimum of a convex problem whose unconstrained optimum c0 is infeasible lies on a line that
    c0 violates (moving from any other feasible point toward c0 would improve it), so only those
    lines are candidates (axis 1, padded); every valid line clips them (axis 2). Arrays are (k, L);
    radius, tx, ty are (k,). Returns (x, y, feasible), each (k,).
    """
    n_cand = int(violated.sum(axis=1).max())
    order = (np.arange(len(px))[:, None], np.argsort(~violated, axis=1, kind="stable")[:, :n_cand])
    cpx, cpy, cdx, cdy, ok = px[order], py[order], dx[order], dy[order], violated[order]
    r2 = (radius * radius)[:, None]
    # segment of candidate line i inside the speed disk: p + t d, t in [t_left, t_right]
    dot = cpx * cdx + cpy * cdy
    disc = dot * dot + r2 - (cpx * cpx + cpy * cpy)
    ok &= disc >= 0.0
    sq = np.sqrt(np.maximum(disc, 0.0))
    t_left = -dot - sq
    t_right = -dot + sq
    # clip by every valid line j (axis 2)
    dxi, dyi = cdx[:, :, None], cdy[:, :, None]
    dxj, dyj = dx[:, None, :], dy[:, None, :]
    den = dxi * dyj - dyi * dxj  # det(d_i, d_j)
    num = dxj * (cpy[:, :, None] - py[:, None, :]) - dyj * (cpx[:, :, None] - px[:, None, :])
    vj = valid[:, None, :]
    par = np.abs(den) <= EPSILON
    # a parallel line with line i on its forbidden side empties line i (line i itself: num = 0)
    ok &= ~(vj & par & (num < 0.0)).any(axis=2)
    t = num / np.where(par, 1.0, den)
    use = vj & ~par
    t_right = np.minimum(t_right, np.where(use & (den > 0.0), t, np.inf).min(axis=2))
    t_left = np.maximum(t_left, np.where(use & (den < 0.0), t, -np.inf).max(axis=2))
    ok &= t_left <= t_right
    txc, tyc = tx[:, None], ty[:, None]
    if directional:
        t_best = np.where(txc * cdx + tyc * cdy > 0.0, t_right, t_left)
    else:
        t_best = np.minimum(np.maximum(cdx * (txc - cpx) + cdy * (tyc - cpy), t_left), t_right)
    x = cpx + t_best * cdx
    y = cpy + t_best * cdy
    if directional:
        cost = -(txc * x + tyc * y)
    else:
        ex, ey = x - txc, y - tyc
        cost = ex * ex + ey * ey
    cost = np.where(ok, cost, np.inf)
    best = (np.arange(len(x)), np.argmin(cost, axis=1))
    return x[best], y[best], ok.any(axis=1)


def optimise(point: np.ndarray, direction: np.ndarray, valid: np.ndarray, radius: np.ndarray,
             target: np.ndarray, directional: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Optimum over the speed disk D(0, radius) and the valid half-planes.

    ``target`` (B,2) is the velocity to get closest to, or with ``directional`` a unit direction to
    go furthest along. Returns (velocity (B,2), feasible (B,)); where infeasible the velocity is the
    disk's optimum, which violates some line.
    """
    px, py = point[..., 0], point[..., 1]
    dx, dy = direction[..., 0], direction[..., 1]
    radius = np.asarray(radius, dtype=float)
    tx, ty = target[:, 0], target[:, 1]
    if directional:
        cx, cy = tx * radius, ty * radius
    else:
        n2 = tx * tx + ty * ty
        outside = n2 > radius * radius
        scale = np.where(outside, radius / np.sqrt(np.where(outside, n2, 1.0)), 1.0)
        cx, cy = tx * scale, ty * scale
    violated = valid & (dx * (py - cy[:, None]) - dy * (px - cx[:, None]) > 0.0)
    rows = np.nonzero(violated.any(axis=1))[0]
    feasible = np.ones(len(cx), dtype=bool)
    if rows.size:
        x, y, ok = _candidates(px[rows], py[rows], dx[rows], dy[rows], valid[rows], radius[rows],
                               tx[rows], ty[rows], directional, violated[rows])
        cx, cy = cx.copy(), cy.copy()
        cx[rows] = np.where(ok, x, cx[rows])
        cy[rows] = np.where(ok, y, cy[rows])
        feasible[rows] = ok
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
        pix, piy = px[rows, i:i + 1], py[rows, i:i + 1]
        dix, diy = dx[rows, i:i + 1], dy[rows, i:i + 1]
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
        res, ok = optimise(np.stack([qx, qy], -1), np.stack([bx, by], -1), use, radius[rows], target,
                           directional=True)
        vx[rows] = np.where(ok, res[:, 0], vx[rows])
        vy[rows] = np.where(ok, res[:, 1], vy[rows])
        distance[rows] = dix[:, 0] * (piy[:, 0] - vy[rows]) - diy[:, 0] * (pix[:, 0] - vx[rows])
    return vx, vy


def least_violation(point: np.ndarray, direction: np.ndarray, valid: np.ndarray, max_speed,
                    pref_velocity: np.ndarray, n_hard=0) -> np.ndarray:
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
    hard = np.arange(n) < np.broadcast_to(np.asarray(n_hard), (b,))[:, None]
    start, ok = optimise(point, direction, valid & hard, radius, np.asarray(pref_velocity, dtype=float))
    hard &= ok[:, None]
    vx, vy = _least_violation(point[..., 0], point[..., 1], direction[..., 0], direction[..., 1],
                              valid, hard, radius, start[:, 0], start[:, 1])
    return np.stack([vx, vy], axis=-1)


def linear_program(point: np.ndarray, direction: np.ndarray, valid: np.ndarray, max_speed,
                   pref_velocity: np.ndarray, n_hard=0) -> tuple[np.ndarray, np.ndarray]:
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
        velocity[rows] = least_violation(point[rows], direction[rows], valid[rows], radius[rows],
                                         pref_velocity[rows], n_hard)
    return velocity, fallback
