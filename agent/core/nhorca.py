"""NH-ORCA for differential-drive robots (paper 5.4; Alonso-Mora et al., DARS 2010).

A differential-drive robot tracks a holonomic velocity v_H at angle theta to its heading by turning at
omega = theta/T and driving an arc at speed v; the tracking error is largest at T. With the error bound
E (the tracking error), the holonomic velocities it can track form S_AHV, approximated by the convex
polygon P_AHV whose edges are hard lines of the ORCA program; robot radii are inflated by E.

Closed forms (derived in the project notes, section 2; 1 - cos theta = 2 sin^2(theta/2) simplifies them):
  squared error at T:      E(v)^2 = T^2 [v_H^2 - 2 v_H v sin(th)/th + 2 v^2 (1 - cos th)/th^2]
  error-minimising speed:  v*_E = v_H (th/2) cot(th/2)          (-> v_H as th -> 0)
  case A (v*_E reachable): V_H^max = E / (T |sin(th/2)|)
  case B (v saturated at v_s = v_max - |omega| l_w/2): the larger root of E(v_s)^2 = E^2,
                           V_H^max = v_s sin(th)/th + sqrt(E^2/T^2 - v_s^2 (1 - cos th)^2 / th^2)
  case C (|th|/T > omega_max): A/B with T replaced by |th|/omega_max; finally clipped to v_max.
omega_max is capped at 2 v_max / l_w so that the wheel speeds v +- omega l_w/2 stay within v_max.

Trigonometry of per-robot angles uses Python's math module element by element, so that results are
bit-identical whether a robot is computed alone or in a batch (numpy's vectorised transcendental
functions may take different code paths with the array's length).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from agent.core.lp import NumpyDecides, plain
from agent.core.orca import Lines, orca_velocity, orca_velocity_one, seg_values, segments_one
from agent.core.params import RobotParams

__all__ = [
    "NHResult",
    "omega_cap",
    "vertex_angles",
    "max_trackable_speed",
    "min_error_speed",
    "tracking_error",
    "ahv_polygon",
    "ahv_lines",
    "controls",
    "wheel_speeds",
    "nh_orca_wheel_speeds",
]

# P_AHV vertices: angles to the heading, denser ahead where the boundary turns fastest
_N_VERTICES = 24


def omega_cap(params: RobotParams) -> float:
    """Largest usable angular speed: omega_max, and no more than keeps a wheel within v_max."""
    return min(params.omega_max, 2.0 * params.v_max / params.wheel_base)


def min_error_speed(v_h: ArrayLike, theta: ArrayLike) -> np.ndarray:
    """v*_E: the linear speed that minimises the tracking error of v_H at angle theta (numpy)."""
    half = 0.5 * np.abs(np.asarray(theta, dtype=float))
    safe = np.where(half > 1e-8, half, 1.0)
    factor = np.where(half > 1e-8, safe * np.cos(safe) / np.sin(safe), 1.0)
    return np.asarray(v_h, dtype=float) * factor


class _AngleTerms(NamedTuple):
    """The parts of V_H^max(theta) that depend on the angle only (`max_trackable_speed`)."""

    turning: np.ndarray  # |theta| > 1e-8
    t_eff: np.ndarray
    t_eff_s_half: np.ndarray  # t_eff sin(|theta|/2)
    k: np.ndarray
    v_s: np.ndarray
    v_s_sinc: np.ndarray  # v_s sin(theta)/theta
    v_s_omc2: np.ndarray  # (v_s (1 - cos theta)/theta)^2


def _angle_terms(theta: ArrayLike, params: RobotParams) -> _AngleTerms:
    a = np.abs(np.asarray(theta, dtype=float))
    w_cap = omega_cap(params)
    t_eff = np.where(a > params.t_orient * w_cap, a / w_cap, params.t_orient)
    v_s = np.maximum(params.v_max - (a / t_eff) * (0.5 * params.wheel_base), 0.0)
    turning = a > 1e-8
    a_safe = np.where(turning, a, 1.0)
    s_half = np.sin(0.5 * a_safe)
    k = np.where(turning, 0.5 * a_safe * np.cos(0.5 * a_safe) / s_half, 1.0)
    sinc = np.where(turning, np.sin(a_safe) / a_safe, 1.0)
    one_minus_cos = np.where(turning, (1.0 - np.cos(a_safe)) / a_safe, 0.0)
    return _AngleTerms(turning, t_eff, t_eff * s_half, k, v_s, v_s * sinc, (v_s * one_minus_cos) ** 2)


def _speed_bound(terms: _AngleTerms, error: np.ndarray, v_max: float) -> np.ndarray:
    """V_H^max from the angle's terms and the tracking error (cases A, B, C)."""
    with np.errstate(divide="ignore"):
        v_a = np.where(terms.turning, error / terms.t_eff_s_half, np.inf)
    case_b = v_a * terms.k > terms.v_s
    root = (error / terms.t_eff) ** 2 - terms.v_s_omc2
    v_b = terms.v_s_sinc + np.sqrt(np.maximum(root, 0.0))
    return np.minimum(np.where(case_b, v_b, v_a), v_max)


def max_trackable_speed(theta: ArrayLike, error: ArrayLike, params: RobotParams) -> np.ndarray:
    """V_H^max(theta): the largest holonomic speed at angle theta to the heading trackable within
    ``error`` (the boundary of S_AHV; cases A, B, C of the module docstring). numpy, broadcasting."""
    return _speed_bound(_angle_terms(theta, params), np.asarray(error, dtype=float), params.v_max)


def _shape(params: RobotParams) -> RobotParams:
    """Params that differ from ``params`` only where P_AHV does not look (the radius above all), as
    the key of the caches below: a real-time agent grows its radius by its lateness every tick
    (agent.lateness), and each grown radius missed them."""
    return _shape_of(params.v_max, params.omega_max, params.wheel_base, params.t_orient)


@functools.lru_cache(maxsize=16)
def _shape_of(v_max: float, omega_max: float, wheel_base: float, t_orient: float) -> RobotParams:
    return RobotParams(v_max=v_max, omega_max=omega_max, wheel_base=wheel_base, t_orient=t_orient)


def vertex_angles(params: RobotParams, n: int = _N_VERTICES) -> np.ndarray:
    """Angles (to the heading) of the P_AHV vertices, increasing in (-pi, pi].

    Denser ahead, where the boundary turns fastest. S_AHV is convex except for a dent where case C
    begins (|theta| = T omega_cap); that angle is a vertex, so every edge is a chord of a convex arc
    of the boundary and lies in S_AHV (the half-planes of the edges then cut a convex subset).
    """
    return _vertex_angles(_shape(params), n)


@functools.lru_cache(maxsize=16)
def _vertex_angles(params: RobotParams, n: int) -> np.ndarray:
    u = np.linspace(-1.0, 1.0, n, endpoint=False)[1:]
    angles = np.concatenate([np.pi * np.sign(u) * np.abs(u) ** 1.5, [np.pi]])
    dent = params.t_orient * omega_cap(params)
    if dent < np.pi:
        angles = np.concatenate([angles, [-dent, dent]])
    angles = np.array(sorted(set(angles.tolist())))  # distinct (np.unique would load numpy.ma)
    angles.setflags(write=False)  # shared by every call with these params
    return angles


def _polygon_terms(params: RobotParams) -> tuple[_AngleTerms, np.ndarray, np.ndarray]:
    """What P_AHV's vertices owe to their angles alone: computed once per params' shape."""
    return _polygon_terms_of(_shape(params))


@functools.lru_cache(maxsize=16)
def _polygon_terms_of(params: RobotParams) -> tuple[_AngleTerms, np.ndarray, np.ndarray]:
    angles = vertex_angles(params)
    out = (_angle_terms(angles[None, :], params), np.cos(angles), np.sin(angles))
    for a in (*out[0], *out[1:]):
        a.setflags(write=False)
    return out


def tracking_error(
    position: ArrayLike,
    radius: ArrayLike,
    nbr_position: np.ndarray,
    nbr_radius: np.ndarray,
    nbr_valid: np.ndarray,
    params: RobotParams,
) -> tuple[np.ndarray, np.ndarray]:
    """Tracking error E of each robot and an upper bound of each neighbour's.

    Each robot takes at most half of the free gap to its nearest neighbour, between error_min and
    error_max: E_i = clip(min_j gap_ij / 2, E_min, E_max). Both robots of a pair follow the rule, so
    (r_i + E_i) + (r_j + E_j) <= |p_i - p_j| whenever the gap is at least 2 E_min; and
    clip(gap_ij / 2, E_min, E_max) bounds E_j from i's side without knowing j's other neighbours.
    Returns (E (B,), neighbour bound (B,M)).
    """
    p = np.asarray(position, dtype=float)
    ex = nbr_position[..., 0] - p[:, None, 0]
    ey = nbr_position[..., 1] - p[:, None, 1]
    gap = np.sqrt(ex * ex + ey * ey) - (np.asarray(radius, dtype=float)[:, None] + nbr_radius)
    half = np.clip(0.5 * gap, params.error_min, params.error_max)
    nearest = np.where(nbr_valid, half, params.error_max).min(axis=1, initial=params.error_max)
    return nearest, half


def _heading_cos_sin(heading) -> tuple[np.ndarray, np.ndarray]:
    h = np.asarray(heading, dtype=float).reshape(-1)
    return (np.array([math.cos(x) for x in h], dtype=float), np.array([math.sin(x) for x in h], dtype=float))


def ahv_polygon(heading: ArrayLike, error: ArrayLike, params: RobotParams) -> np.ndarray:
    """Vertices (B,K,2) of P_AHV in the world frame, counter-clockwise: V_H^max sampled at
    `vertex_angles` to the heading."""
    c, s = _heading_cos_sin(heading)
    terms, cos_a, sin_a = _polygon_terms(params)
    radius = _speed_bound(terms, np.asarray(error, dtype=float)[:, None], params.v_max)
    lx, ly = radius * cos_a, radius * sin_a
    return np.stack([c[:, None] * lx - s[:, None] * ly, s[:, None] * lx + c[:, None] * ly], axis=-1)


def ahv_lines(vertices: np.ndarray) -> Lines:
    """Edges of a counter-clockwise convex polygon as lines (interior on the left)."""
    nxt = np.roll(vertices, -1, axis=1)
    ex, ey = nxt[..., 0] - vertices[..., 0], nxt[..., 1] - vertices[..., 1]
    n = np.sqrt(ex * ex + ey * ey)
    return Lines(vertices.copy(), np.stack([ex / n, ey / n], axis=-1), np.ones(vertices.shape[:2], dtype=bool))


def controls(
    velocity: ArrayLike, heading: ArrayLike, params: RobotParams, reverse: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Linear and angular speed (v, omega) tracking holonomic velocities (B,2) from headings (B,).

    omega = sign(theta) min(|theta|/T, omega_cap), v = min(v*_E, v_max - |omega| l_w/2), theta the
    angle from the heading (from the reversed heading, and v negated, where ``reverse``).
    """
    vel = np.asarray(velocity, dtype=float)
    c, s = _heading_cos_sin(heading)
    rev = np.zeros(len(c), dtype=bool) if reverse is None else np.asarray(reverse, dtype=bool)
    v_out = np.empty(len(c))
    w_out = np.empty(len(c))
    for i in range(len(c)):
        v_out[i], w_out[i] = _control_one(float(vel[i, 0]), float(vel[i, 1]), c[i], s[i], bool(rev[i]), params)
    return v_out, w_out


def _control_one(vx: float, vy: float, c: float, s: float, reverse: bool, params: RobotParams) -> tuple[float, float]:
    """`controls` of one robot: (v, omega) from its velocity and the cosine and sine of its heading."""
    hx, hy = (-c, -s) if reverse else (c, s)
    speed = math.sqrt(vx * vx + vy * vy)
    theta = math.atan2(hx * vy - hy * vx, hx * vx + hy * vy) if speed > 0.0 else 0.0
    omega = math.copysign(min(abs(theta) / params.t_orient, omega_cap(params)), theta)
    half = 0.5 * abs(theta)
    v_star = speed * (half / math.tan(half)) if half > 1e-8 else speed
    v = max(0.0, min(v_star, params.v_max - abs(omega) * (0.5 * params.wheel_base)))
    return -v if reverse else v, omega


def wheel_speeds(v: ArrayLike, omega: ArrayLike, params: RobotParams) -> tuple[np.ndarray, np.ndarray]:
    """Linear wheel speeds (left, right) in m/s of a unicycle command."""
    half = 0.5 * params.wheel_base
    return np.asarray(v) - np.asarray(omega) * half, np.asarray(v) + np.asarray(omega) * half


class NHResult(NamedTuple):
    wheel_left: np.ndarray  # (B,) m/s
    wheel_right: np.ndarray  # (B,) m/s
    velocity: np.ndarray  # (B,2) the collision-free holonomic velocity v_cf (next step's v_opt)
    fallback: np.ndarray  # (B,) bool: infeasible with P_AHV (mirrored polygon or least violation)
    reverse: np.ndarray  # (B,) bool: the mirrored polygon was used, the robot drives backwards
    error: np.ndarray  # (B,) tracking error E used


def _take(rows, *arrays):
    return [None if a is None else np.asarray(a)[rows] for a in arrays]


def nh_orca_wheel_speeds(
    position: ArrayLike,
    heading: ArrayLike,
    velocity: ArrayLike,
    pref_velocity: ArrayLike,
    radius: ArrayLike,
    nbr_position: ArrayLike,
    nbr_velocity: ArrayLike,
    nbr_radius: ArrayLike,
    nbr_responsibility: ArrayLike,
    nbr_valid: ArrayLike,
    obstacle_segments: np.ndarray | None = None,
    *,
    params: RobotParams,
    safety: bool = True,
    nbr_growth: ArrayLike | None = None,
    nbr_lead: ArrayLike | None = None,
) -> NHResult:
    """NH-ORCA step for a batch of differential-drive robots.

    ``velocity`` is each robot's previous v_cf and ``nbr_velocity`` the neighbours' broadcast v_cf.
    Radii are inflated by the tracking error E (own) and its bound (neighbours'); P_AHV is kept hard.
    ``nbr_growth``, ``nbr_lead``: how far each neighbour may have strayed since its state, and how
    much further along its velocity it most likely is (see `orca_velocity`).
    Where the program is infeasible at the full horizon the mirrored polygon -P_AHV (driving
    backwards) is tried at the full horizon; if that is infeasible too, the forward result of
    `orca_velocity`'s fallback (shrunk horizon, else least violation) stands.
    """
    position = np.asarray(position, dtype=float)
    b = position.shape[0]
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (b,))
    nbr_position = np.asarray(nbr_position, dtype=float)
    nbr_radius = np.asarray(nbr_radius, dtype=float)
    nbr_valid = np.asarray(nbr_valid, dtype=bool)
    if b == 1 and safety:
        try:
            one = _nh_orca_one(
                position,
                heading,
                velocity,
                pref_velocity,
                radius,
                nbr_position,
                nbr_velocity,
                nbr_radius,
                nbr_responsibility,
                nbr_valid,
                obstacle_segments,
                params,
                nbr_growth,
                nbr_lead,
            )
            if one is not None:
                return one
        except NumpyDecides:
            pass
    error, nbr_error = tracking_error(position, radius, nbr_position, nbr_radius, nbr_valid, params)
    polygon = ahv_lines(ahv_polygon(heading, error, params))
    args = [
        position,
        velocity,
        pref_velocity,
        radius + error,
        nbr_position,
        nbr_velocity,
        nbr_radius + nbr_error,
        nbr_responsibility,
        nbr_valid,
        nbr_growth,
        nbr_lead,
    ]

    def solve(robots: Sequence[Any], hard: Lines) -> tuple[np.ndarray, np.ndarray]:
        """orca_velocity of these robots' ``args`` (all of them or some rows) with hard lines ``hard``."""
        pos, vel, pref, rad, nbr_pos, nbr_vel, nbr_rad, nbr_resp, nbr_ok, nbr_grow, nbr_ahead = robots
        return orca_velocity(
            pos,
            vel,
            pref,
            rad,
            params.v_max,
            nbr_pos,
            nbr_vel,
            nbr_rad,
            nbr_resp,
            nbr_ok,
            obstacle_segments,
            tau=params.tau,
            tau_obst=params.tau_obst,
            dt=params.dt,
            safety=safety,
            extra_hard_lines=hard,
            nbr_growth=nbr_grow,
            nbr_lead=nbr_ahead,
        )

    v_cf, fallback = solve(args, polygon)
    reverse = np.zeros(b, dtype=bool)
    rows = np.nonzero(fallback)[0]
    if rows.size:
        mirrored = Lines(-polygon.point[rows], -polygon.direction[rows], polygon.valid[rows])
        v_back, fb_back = solve(_take(rows, *args), mirrored)
        use = ~fb_back
        v_cf[rows[use]] = v_back[use]
        reverse[rows[use]] = True
    v, omega = controls(v_cf, heading, params, reverse)
    left, right = wheel_speeds(v, omega, params)
    return NHResult(left, right, v_cf, fallback, reverse, error)


# A batch of one robot (an agent process): nh_orca_wheel_speeds on Python floats, the same
# operations in the same order as the numpy code above (numpy's per-call overhead dominates on
# arrays of one); ORCA itself is agent.core.orca's `orca_velocity_one`.


def _polygon_terms_one(params: RobotParams) -> list[tuple]:
    """`_polygon_terms` vertex by vertex as Python values."""
    return _polygon_terms_one_of(_shape(params))


@functools.lru_cache(maxsize=16)
def _polygon_terms_one_of(params: RobotParams) -> list[tuple]:
    terms, cos_a, sin_a = _polygon_terms(params)
    return list(zip(*(np.asarray(x).reshape(-1).tolist() for x in (*terms, cos_a, sin_a))))


def _ahv_lines_one(c: float, s: float, error: float, params: RobotParams) -> list[tuple]:
    """`ahv_lines` of `ahv_polygon` for one robot: (px, py, dx, dy) edge by edge."""
    v_max = params.v_max
    vertices = []
    for turning, t_eff, t_eff_s_half, k, v_s, v_s_sinc, v_s_omc2, cos_a, sin_a in _polygon_terms_one(params):
        v_a = error / t_eff_s_half if turning else math.inf
        if v_a * k > v_s:
            q = error / t_eff
            root = q * q - v_s_omc2  # numpy's ** 2 is a square; root is never -0
            v = v_s_sinc + (math.sqrt(root) if root > 0.0 else 0.0)
        else:
            v = v_a
        radius = v if v < v_max else v_max
        lx, ly = radius * cos_a, radius * sin_a
        vertices.append((c * lx - s * ly, s * lx + c * ly))
    lines = []
    for (x, y), (nx, ny) in zip(vertices, vertices[1:] + vertices[:1]):
        ex, ey = nx - x, ny - y
        n = math.sqrt(ex * ex + ey * ey)
        if n == 0.0:
            raise NumpyDecides  # numpy divides by zero, Python raises
        lines.append((x, y, ex / n, ey / n))
    return lines


def _nh_orca_one(
    position,
    heading,
    velocity,
    pref_velocity,
    radius,
    nbr_position,
    nbr_velocity,
    nbr_radius,
    nbr_responsibility,
    nbr_valid,
    obstacle_segments,
    params: RobotParams,
    nbr_growth,
    nbr_lead,
) -> NHResult | None:
    """nh_orca_wheel_speeds (with safety) of a batch of one robot; None where the Python floats
    might not be numpy's (inputs not finite or huge)."""
    (px, py) = position[0].tolist()
    (vx, vy) = np.asarray(velocity, dtype=float)[0].tolist()
    (tx, ty) = np.asarray(pref_velocity, dtype=float)[0].tolist()
    h = float(np.asarray(heading, dtype=float).reshape(-1)[0])
    r = float(radius[0])
    m = nbr_valid.shape[1]
    grow = [0.0] * m if nbr_growth is None else np.asarray(nbr_growth, dtype=float)[0].tolist()
    leads = [0.0] * m if nbr_lead is None else np.asarray(nbr_lead, dtype=float)[0].tolist()
    nbrs = [
        (q, w, nr, c, g, a)
        for q, w, nr, c, g, a, ok in zip(
            nbr_position[0].tolist(),
            np.asarray(nbr_velocity, dtype=float)[0].tolist(),
            nbr_radius[0].tolist(),
            np.broadcast_to(np.asarray(nbr_responsibility, dtype=float), (1, m))[0].tolist(),
            grow,
            leads,
            nbr_valid[0].tolist(),
        )
        if ok
    ]
    seg = segments_one(obstacle_segments)
    flat = [x for q, w, nr, c, g, a in nbrs for x in (*q, *w, nr, c, g, a)]
    p = params
    settings = [p.v_max, p.tau, p.tau_obst, p.dt, p.error_min, p.error_max, p.wheel_base, p.t_orient, p.omega_max]
    if not plain([px, py, vx, vy, tx, ty, h, r], flat, seg_values(seg), settings):
        return None
    # tracking_error: half the gap to each neighbour, clipped; E the smallest
    e_min, e_max = params.error_min, params.error_max
    error, grown = e_max, []
    for (qx, qy), w, nr, c, g, a in nbrs:
        ex = qx - px
        ey = qy - py
        half = 0.5 * (math.sqrt(ex * ex + ey * ey) - (r + nr))
        half = half if half > e_min else e_min
        half = half if half < e_max else e_max
        error = half if half < error else error
        grown.append(((qx, qy), w, nr + half, c, g, a))
    c, s = math.cos(h), math.sin(h)
    polygon = _ahv_lines_one(c, s, error, params)
    solve = (px, py, vx, vy, tx, ty, r + error, params.v_max, grown, seg)
    rest = (nbr_growth is not None, params.tau, params.tau_obst, params.dt, 0.0)
    x, y, fallback = orca_velocity_one(*solve, polygon, *rest)
    reverse = False
    if fallback:
        mirrored = [(-a, -b, -d, -e) for a, b, d, e in polygon]
        bx, by, back_fallback = orca_velocity_one(*solve, mirrored, *rest)
        if not back_fallback:
            x, y, reverse = bx, by, True
    v, omega = _control_one(x, y, c, s, reverse, params)
    half_base = 0.5 * params.wheel_base
    return NHResult(
        np.array([v - omega * half_base]),
        np.array([v + omega * half_base]),
        np.array([[x, y]]),
        np.array([fallback]),
        np.array([reverse]),
        np.array([error]),
    )
