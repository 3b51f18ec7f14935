"""The holonomic control core of a batch (what `control_step` does after the preferred velocity:
`prepare_neighbours`, then `orca_velocity` with its safety lines, shrinking horizon and fallback),
one robot at a time, compiled with numba.

Why: the numpy core is vectorised over the batch but loops over lines and neighbours in Python,
so a large batch spends most of its step in array bookkeeping; per robot, the same arithmetic in
the same order takes a fraction of that. The central engines (sim.central's `control_core`,
agent.core.rvo's `central_core`) use this; agent processes keep the numpy core and never load numba.

Per robot nothing allocates (`control_core` makes the scratch), so the per-robot functions are compiled
without numba's runtime (``_nrt=False``), which would count references to every array at every
call, and the small scalar helpers are inlined.

Same results, bit for bit: every line, bound and optimum is computed with the float operations of
agent.core.neighbours, agent.core.orca and agent.core.lp in the same order, taking each robot's
valid lines in the order the numpy core keeps them (hard lines first: obstacle edges, then safety
lines; then the robot lines, nearest neighbour first). tests/test_orca_kernel.py checks it against
the numpy core on random crowds, including infeasible ones.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# As agent.core.orca and agent.core.lp (numba's cache keys on this file only: an imported constant
# that changed there would stay stale in the cache).
BUFFER = 1.0 + 1e-6  # orca._BUFFER: radii 1 ppm larger in the safety and obstacle lines
SHRINK = 4.0  # orca._SHRINK: the horizon divisor where infeasible
EPSILON = 1e-5  # lp.EPSILON: two unit directions are parallel below this |det|
COOPERATING, NON_COOPERATING = 0.5, 1.0  # neighbours.COOPERATING / NON_COOPERATING
COS_RIGHT, SIN_RIGHT = np.cos(-np.pi / 4), np.sin(-np.pi / 4)  # step._COS, step._SIN: 45 degrees clockwise
PERTURBATION = 1e-4  # neighbours.perturb_preferred_velocity's magnitude


@njit(cache=True)
def _splitmix64(x):
    """neighbours.splitmix64 for one uint64 (wrapping arithmetic, as numpy's)."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def preferred_core(position, goal, preferred, velocity, robot_id, v_pref, k_a, seed_key, tick):
    """What control_step does before the control core, per robot, in the numpy code's float
    operations: eq. 9 toward the goal (orca.preferred_velocity), rows of ``preferred`` that are
    finite instead, 45 degrees to the right when blocked (step.keep_right_when_blocked), and the
    tiny perturbation of a non-zero preferred velocity (neighbours.perturb_preferred_velocity, with
    seed_key = splitmix64(seed) and robot_id as uint64)."""
    b = len(position)
    out = np.empty((b, 2))
    for i in range(b):
        ex, ey = goal[i, 0] - position[i, 0], goal[i, 1] - position[i, 1]
        dist = np.sqrt(ex * ex + ey * ey)
        has = np.isfinite(dist) and dist > 0.0
        safe = dist if has else 1.0
        gain = (v_pref / safe if safe > k_a else v_pref / k_a) if has else 0.0
        px, py = (ex if has else 0.0) * gain, (ey if has else 0.0) * gain
        if np.isfinite(preferred[i, 0]) and np.isfinite(preferred[i, 1]):
            px, py = preferred[i, 0], preferred[i, 1]
        want = np.hypot(px, py)
        if want > 0.5 * v_pref and np.hypot(velocity[i, 0], velocity[i, 1]) < 0.25 * want:
            px, py = COS_RIGHT * px - SIN_RIGHT * py, SIN_RIGHT * px + COS_RIGHT * py
        if px != 0 or py != 0:
            key = _splitmix64(_splitmix64(robot_id[i] ^ seed_key) + tick)
            a = np.float64(key >> np.uint64(11)) * 2.0**-53
            c = np.float64(_splitmix64(key) >> np.uint64(11)) * 2.0**-53
            px, py = px + (2.0 * a - 1.0) * PERTURBATION, py + (2.0 * c - 1.0) * PERTURBATION
        out[i, 0], out[i, 1] = px, py
    return out


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _on_line(pix, piy, dix, diy, px, py, dx, dy, use, n, radius, tx, ty, directional):
    """lp._on_line for one line i, clipped by the disk and the lines j < n with use[j]."""
    dot = pix * dix + piy * diy
    disc = dot * dot + radius * radius - (pix * pix + piy * piy)
    ok = disc >= 0.0
    sq = math.sqrt(max(disc, 0.0))
    t_left = -dot - sq
    t_right = -dot + sq
    right, left = np.inf, -np.inf
    for j in range(n):
        if not use[j]:
            continue
        den = dix * dy[j] - diy * dx[j]
        num = dx[j] * (piy - py[j]) - dy[j] * (pix - px[j])
        if abs(den) <= EPSILON:  # parallel: line j empties line i if i lies on its forbidden side
            if num < 0.0:
                ok = False
            continue
        t = num / den
        if den > 0.0:
            right = min(right, t)
        else:
            left = max(left, t)
    t_right = min(t_right, right)
    t_left = max(t_left, left)
    ok = ok and t_left <= t_right
    if directional:
        t_best = t_right if tx * dix + ty * diy > 0.0 else t_left
    else:
        t_best = min(max(dix * (tx - pix) + diy * (ty - piy), t_left), t_right)
    return pix + t_best * dix, piy + t_best * diy, ok


@njit(cache=True, inline="always")
def _disk_optimum(tx, ty, radius, directional):
    if directional:
        return tx * radius, ty * radius
    n2 = tx * tx + ty * ty
    if n2 > radius * radius:
        scale = radius / math.sqrt(n2)
        return tx * scale, ty * scale
    return tx * 1.0, ty * 1.0


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _optimise(px, py, dx, dy, n, radius, tx, ty, every):
    """lp.optimise (RVO2's linearProgram2) over lines 0..n-1 (``every``: n or more True flags):
    (x, y, feasible)."""
    rx, ry = _disk_optimum(tx, ty, radius, False)
    for i in range(n):
        if dx[i] * (py[i] - ry) - dy[i] * (px[i] - rx) > 0.0:
            x, y, ok = _on_line(px[i], py[i], dx[i], dy[i], px, py, dx, dy, every, i, radius, tx, ty, False)
            if not ok:
                return rx, ry, False  # a robot stops at its first unsatisfiable line
            rx, ry = x, y
    return rx, ry, True


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _optimise_few(px, py, dx, dy, use, n, radius, tx, ty, directional):
    """lp.optimise_few over the lines 0..n-1 with use[j]: the best 1-D optimum of the lines that the
    disk's optimum violates, each clipped by every line (itself included); ties to the first."""
    cx, cy = _disk_optimum(tx, ty, radius, directional)
    violated, good = False, False
    best_x, best_y, best_cost = cx, cy, np.inf
    for c in range(n):
        if not use[c] or not dx[c] * (py[c] - cy) - dy[c] * (px[c] - cx) > 0.0:
            continue
        violated = True
        x, y, ok = _on_line(px[c], py[c], dx[c], dy[c], px, py, dx, dy, use, n, radius, tx, ty, directional)
        if not ok:
            continue
        if directional:
            cost = -(tx * x + ty * y)
        else:
            ex, ey = x - tx, y - ty
            cost = ex * ex + ey * ey
        if cost < best_cost:
            best_x, best_y, best_cost, good = x, y, cost, True
    if not violated:
        return cx, cy, True
    if good:
        return best_x, best_y, True
    return cx, cy, False


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _least_violation(px, py, dx, dy, n, n_hard, radius, tx, ty, bisectors, flags):
    """lp.least_violation (RVO2's linearProgram3): the first n_hard lines stay hard (all soft if they
    leave nothing of the disk), the largest violation of the others is minimised. Scratch: the
    lines of each 1-D problem (bisectors (4, n) and flags (2, n): hard, used)."""
    qx, qy, bx, by = bisectors[0], bisectors[1], bisectors[2], bisectors[3]
    hard, use = flags[0], flags[1]
    for i in range(n):
        hard[i] = i < n_hard
    vx, vy, ok = _optimise_few(px, py, dx, dy, hard, n, radius, tx, ty, False)
    if not ok:
        for i in range(n):
            hard[i] = False
    distance = 0.0
    for i in range(n):
        if hard[i] or not dx[i] * (py[i] - vy) - dy[i] * (px[i] - vx) > distance:
            continue
        pix, piy, dix, diy = px[i], py[i], dx[i], dy[i]
        for j in range(i):  # the hard lines, and the bisectors with the earlier soft lines
            pjx, pjy, djx, djy = px[j], py[j], dx[j], dy[j]
            if hard[j]:
                qx[j], qy[j], bx[j], by[j], use[j] = pjx, pjy, djx, djy, True
                continue
            den = dix * djy - diy * djx
            par = abs(den) <= EPSILON
            use[j] = not (par and dix * djx + diy * djy > 0.0)  # same direction: line i dominates
            if par:
                qx[j], qy[j] = 0.5 * (pix + pjx), 0.5 * (piy + pjy)
            else:
                t = (djx * (piy - pjy) - djy * (pix - pjx)) / den
                qx[j], qy[j] = pix + t * dix, piy + t * diy
            ex, ey = djx - dix, djy - diy
            norm = math.sqrt(ex * ex + ey * ey)
            norm = norm if norm > 0.0 else 1.0
            bx[j], by[j] = ex / norm, ey / norm
        x, y, ok = _optimise_few(qx, qy, bx, by, use, i, radius, -diy, dix, True)
        if ok:
            vx, vy = x, y
        distance = dix * (piy - vy) - diy * (pix - vx)
    return vx, vy


@njit(cache=True, inline="always")
def _orca_line(px, py, vx, vy, radius, nx, ny, nvx, nvy, nradius, c, tau, dt):
    """orca.orca_lines for one pair: (point x, point y, direction x, direction y)."""
    rpx = nx - px
    rpy = ny - py
    rvx = vx - nvx
    rvy = vy - nvy
    dist2 = rpx * rpx + rpy * rpy
    big_r = radius + nradius
    big_r2 = big_r * big_r
    apart = dist2 > big_r2
    inv_h = 1.0 / tau if apart else 1.0 / dt
    wx = rvx - inv_h * rpx
    wy = rvy - inv_h * rpy
    w2 = wx * wx + wy * wy
    dot1 = wx * rpx + wy * rpy
    if not apart or (dot1 < 0.0 and dot1 * dot1 > big_r2 * w2):  # the cut-off circle
        wl = math.sqrt(w2)
        if wl == 0.0:
            ux, uy = 1.0, 0.0
        else:
            ux, uy = wx / wl, wy / wl
        scale = big_r * inv_h - wl
        return vx + c * (scale * ux), vy + c * (scale * uy), uy, -ux
    leg = math.sqrt(max(dist2 - big_r2, 0.0))  # a leg of the cone
    if not rpx * wy - rpy * wx > 0.0:
        leg = -leg
    inv_d2 = 1.0 / (dist2 if dist2 > 0.0 else 1.0)
    ldx = (rpx * leg - rpy * big_r) * inv_d2
    ldy = (rpy * leg + rpx * big_r) * inv_d2
    dot2 = rvx * ldx + rvy * ldy
    return vx + c * (dot2 * ldx - rvx), vy + c * (dot2 * ldy - rvy), ldx, ldy


@njit(cache=True, inline="always")
def _keep(px, py, dx, dy, vmax):
    """orca.drop_redundant: is the line not satisfied by the whole speed disk?"""
    return dx * py - dy * px > -vmax


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _robot_lines(
    i,
    position,
    velocity,
    radius,
    nbr_p,
    nbr_v,
    nbr_r,
    nbr_left,
    nbr_lead,
    nbr_c,
    nbr_ok,
    m,
    vmax,
    margin,
    horizon,
    dt,
    px,
    py,
    dx,
    dy,
    start,
):
    """The robot lines (horizon ``horizon``, margin on both radii, neighbours without the growth
    ``nbr_left`` to the safety lines: orca.orca_velocity) from index ``start``: the new count."""
    n = start
    for k in range(m):
        if not nbr_ok[k]:
            continue
        a, b, c, d = _orca_line(
            position[i, 0],
            position[i, 1],
            velocity[i, 0],
            velocity[i, 1],
            radius + margin,
            nbr_p[k, 0] + nbr_lead[k] * nbr_v[k, 0],
            nbr_p[k, 1] + nbr_lead[k] * nbr_v[k, 1],
            nbr_v[k, 0],
            nbr_v[k, 1],
            nbr_r[k] - nbr_left[k] + margin,
            nbr_c[k],
            horizon,
            dt,
        )
        if _keep(a, b, c, d, vmax):
            px[n], py[n], dx[n], dy[n] = a, b, c, d
            n += 1
    return n


@njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _control_core_one(
    i,
    position,
    velocity,
    pref,
    radius,
    vmax,
    nbr_position,
    nbr_velocity,
    nbr_radius,
    nbr_age,
    nbr_valid,
    nbr_cooperative,
    segments,
    tau,
    tau_obst,
    dt,
    margin,
    timeout,
    noise,
    committed,
    safety,
    nbr_p,
    nbr_v,
    nbr_f,
    nbr_ok,
    lines,
    every,
    bisectors,
    flags,
):
    """One robot: its neighbours prepared (neighbours.prepare_neighbours), then eq. 14 with the safety
    lines, the shrinking horizon and the fallback (orca.orca_velocity); without ``safety``, RVO2's
    program (no safety lines, least violation at the full horizon). Returns (vx, vy, fallback).
    Scratch, so that a robot allocates nothing: nbr_p, nbr_v (M,2), nbr_f (4,M), nbr_ok (M,),
    lines and bisectors (4, S + 2M), every (S + 2M,) all True, flags (2, S + 2M)."""
    m = nbr_valid.shape[1]
    n_seg = segments.shape[0]
    px_, py_ = position[i, 0], position[i, 1]
    # prepare_neighbours: where each neighbour is now, how big (and how much of it is growth), how
    # responsible
    nbr_r, nbr_g, nbr_c, nbr_left, nbr_lead = nbr_f[0], nbr_f[1], nbr_f[2], nbr_f[3], nbr_f[4]
    for k in range(m):
        x, y = nbr_position[i, k, 0], nbr_position[i, k, 1]
        u, w = nbr_velocity[i, k, 0], nbr_velocity[i, k, 1]
        r = nbr_radius[i, k]
        age = max(nbr_age[i, k], 0.0)
        ok = (
            nbr_valid[i, k]
            and np.isfinite(x)
            and np.isfinite(y)
            and np.isfinite(u)
            and np.isfinite(w)
            and np.isfinite(r)
            and np.isfinite(age)
        )
        stale = age > timeout
        horizon = max((timeout if stale else age) - committed, 0.0)
        shift = 0.0 if stale else age - horizon
        if not ok:
            x, y, u, w, r, horizon = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        nbr_p[k, 0], nbr_p[k, 1] = x + shift * u, y + shift * w
        nbr_v[k, 0], nbr_v[k, 1] = u, w
        nbr_g[k] = horizon * (2.0 if stale else 1.0) * vmax
        nbr_r[k] = r + noise + nbr_g[k]
        nbr_left[k] = nbr_g[k] if safety else 0.0  # growth the robot lines leave to the safety lines
        nbr_lead[k] = horizon if safety and not stale else 0.0
        nbr_c[k] = COOPERATING if nbr_cooperative[i, k] and not stale else NON_COOPERATING
        nbr_ok[k] = ok
    px, py, dx, dy = lines[0], lines[1], lines[2], lines[3]
    n = 0
    # hard lines: the obstacle edges (own radius with the margin) ...
    r_obst = (radius + margin) * BUFFER
    for s in range(n_seg):
        ax, ay = segments[s, 0, 0], segments[s, 0, 1]
        ex, ey = segments[s, 1, 0] - ax, segments[s, 1, 1] - ay
        len2 = ex * ex + ey * ey
        t = min(max(((px_ - ax) * ex + (py_ - ay) * ey) / (len2 if len2 > 0.0 else 1.0), 0.0), 1.0)
        nx = px_ - (ax + t * ex)
        ny = py_ - (ay + t * ey)
        d = math.sqrt(nx * nx + ny * ny)
        if d == 0.0:  # centre on the edge: the free side is on its right
            el = math.sqrt(len2 if len2 > 0.0 else 1.0)
            nx, ny = ey / el, -ex / el
        else:
            nx, ny = nx / d, ny / d
        offset = max(d - r_obst, 0.0) / tau_obst
        if offset < vmax:
            a, b, c, e = -nx * offset, -ny * offset, ny, -nx
            if _keep(a, b, c, e, vmax):
                px[n], py[n], dx[n], dy[n] = a, b, c, e
                n += 1
    # ... and the safety lines (horizon dt around zero velocities, true radii, growth up to our surface)
    own = radius * BUFFER
    for k in range(m):
        if not (safety and nbr_ok[k]):
            continue
        ex, ey = nbr_p[k, 0] - px_, nbr_p[k, 1] - py_
        dist = math.sqrt(ex * ex + ey * ey)
        nr = nbr_r[k] * BUFFER
        certain = nr - nbr_g[k] * BUFFER
        nr = min(nr, max(dist * (1.0 - 1e-9) - own, certain))
        gap = dist - (own + nr)
        keep = nbr_c[k] >= 1.0
        if not (keep or gap < 2.0 * dt * vmax):
            continue
        nvx, nvy = (nbr_v[k, 0], nbr_v[k, 1]) if keep else (0.0, 0.0)
        a, b, c, e = _orca_line(px_, py_, 0.0, 0.0, own, nbr_p[k, 0], nbr_p[k, 1], nvx, nvy, nr, nbr_c[k], dt, dt)
        if _keep(a, b, c, e, vmax):
            px[n], py[n], dx[n], dy[n] = a, b, c, e
            n += 1
    n_hard = n
    n = _robot_lines(
        i,
        position,
        velocity,
        radius,
        nbr_p,
        nbr_v,
        nbr_r,
        nbr_left,
        nbr_lead,
        nbr_c,
        nbr_ok,
        m,
        vmax,
        margin,
        tau,
        dt,
        px,
        py,
        dx,
        dy,
        n_hard,
    )
    tx, ty = pref[i, 0], pref[i, 1]
    vx, vy, feasible = _optimise(px, py, dx, dy, n, vmax, tx, ty, every)
    if feasible:
        return vx, vy, False
    horizon = tau
    while safety and horizon > dt:  # paper 5.3: a shorter horizon until feasible, down to dt
        horizon = max(horizon / SHRINK, dt)
        n = _robot_lines(
            i,
            position,
            velocity,
            radius,
            nbr_p,
            nbr_v,
            nbr_r,
            nbr_left,
            nbr_lead,
            nbr_c,
            nbr_ok,
            m,
            vmax,
            margin,
            horizon,
            dt,
            px,
            py,
            dx,
            dy,
            n_hard,
        )
        vx, vy, ok = _optimise_few(px, py, dx, dy, every, n, vmax, tx, ty, False)
        if ok:
            return vx, vy, True
    vx, vy = _least_violation(px, py, dx, dy, n, n_hard, vmax, tx, ty, bisectors, flags)
    return vx, vy, True


@njit(cache=True, nogil=True)
def control_core(
    position,
    velocity,
    pref,
    radius,
    vmax,
    nbr_position,
    nbr_velocity,
    nbr_radius,
    nbr_age,
    nbr_valid,
    nbr_cooperative,
    segments,
    tau,
    tau_obst,
    dt,
    margin,
    timeout,
    noise,
    committed,
):
    """The collision-free velocity (B,2) and fallback flags (B,) of a batch of robots of one radius and
    maximum speed, from their neighbours' states (agent.core.step's compiled path). One core: in the
    central engine the other runs the auction (sim.central), and a second numba thread does not pay
    for starting it."""
    b = position.shape[0]
    return _each_robot(
        position,
        velocity,
        pref,
        np.full(b, radius),
        np.full(b, vmax),
        nbr_position,
        nbr_velocity,
        nbr_radius,
        nbr_age,
        nbr_valid,
        nbr_cooperative,
        segments,
        tau,
        tau_obst,
        dt,
        margin,
        timeout,
        noise,
        committed,
        True,
    )


@njit(cache=True, nogil=True)
def central_core(position, velocity, pref, radius, vmax, index, segments, tau, tau_obst, dt, margin, safety):
    """The collision-free velocity (B,2) and fallback flags (B,) of robots that know each other
    perfectly (agent.core.rvo.CentralOrca): each robot's neighbours are the rows ``index`` (B,M) of
    the batch itself (-1: none), now, cooperating, of their own radius; radius and vmax are per robot
    (B,). The numpy twin: orca.orca_velocity with responsibility 0.5 and no growth."""
    b, m = index.shape
    nbr_position, nbr_velocity = np.zeros((b, m, 2)), np.zeros((b, m, 2))
    nbr_radius, nbr_valid = np.zeros((b, m)), index >= 0
    for i in range(b):
        for k in range(m):
            j = index[i, k]
            if j >= 0:
                nbr_position[i, k, 0], nbr_position[i, k, 1] = position[j, 0], position[j, 1]
                nbr_velocity[i, k, 0], nbr_velocity[i, k, 1] = velocity[j, 0], velocity[j, 1]
                nbr_radius[i, k] = radius[j]
    # as prepare_neighbours leaves them: age 0 and nothing committed (no growth), never stale
    nbr_age, nbr_cooperative = np.zeros((b, m)), np.ones((b, m), np.bool_)
    return _each_robot(
        position,
        velocity,
        pref,
        radius,
        vmax,
        nbr_position,
        nbr_velocity,
        nbr_radius,
        nbr_age,
        nbr_valid,
        nbr_cooperative,
        segments,
        tau,
        tau_obst,
        dt,
        margin,
        0.0,
        0.0,
        0.0,
        safety,
    )


@njit(cache=True, nogil=True)
def _each_robot(
    position,
    velocity,
    pref,
    radius,
    vmax,
    nbr_position,
    nbr_velocity,
    nbr_radius,
    nbr_age,
    nbr_valid,
    nbr_cooperative,
    segments,
    tau,
    tau_obst,
    dt,
    margin,
    timeout,
    noise,
    committed,
    safety,
):
    """One robot after the other with one scratch (a robot allocates nothing); radius and vmax (B,)."""
    b, m = nbr_valid.shape
    size = segments.shape[0] + 2 * m
    nbr_p, nbr_v, nbr_f = np.empty((m, 2)), np.empty((m, 2)), np.empty((5, m))
    nbr_ok, lines, every = np.empty(m, np.bool_), np.empty((4, size)), np.ones(size, np.bool_)
    bisectors, flags = np.empty((4, size)), np.empty((2, size), np.bool_)
    out, fallback = np.empty((b, 2)), np.empty(b, np.bool_)
    for i in range(b):
        out[i, 0], out[i, 1], fallback[i] = _control_core_one(
            i,
            position,
            velocity,
            pref,
            radius[i],
            vmax[i],
            nbr_position,
            nbr_velocity,
            nbr_radius,
            nbr_age,
            nbr_valid,
            nbr_cooperative,
            segments,
            tau,
            tau_obst,
            dt,
            margin,
            timeout,
            noise,
            committed,
            safety,
            nbr_p,
            nbr_v,
            nbr_f,
            nbr_ok,
            lines,
            every,
            bisectors,
            flags,
        )
    return out, fallback
