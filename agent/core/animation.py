"""Real-time control of animations (paper 6.2, eq. 27), over a batch of robots: pure, no clock.

Keyframes follow one another K_f control periods apart. When a robot's goal changes to the next
frame's, its preferred velocity becomes

    v_pref = min(v_max, |g - p| / (K_f dt)) (g - p) / |g - p|          (eq. 27)

and is held for K_f iterations, so that every robot arrives when the next keyframe begins; then eq. 9
takes over. A robot that learns its goal late (the auction needs a few iterations) uses the iterations
left of the frame instead (``iterations_left``). What is held is the arrival time rather than the
velocity: each iteration takes eq. 27 from where the robot is over the iterations left, so a robot
that collision avoidance slowed down catches up, up to v_max, instead of arriving late.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def synchronised_velocity(position: ArrayLike, goal: ArrayLike, v_max: float, k_f: ArrayLike, dt: float) -> np.ndarray:
    """Eq. 27 for a batch: (B,2) velocities that cover |g - p| in k_f periods, at most v_max.
    k_f is a scalar or (B,) and must be >= 1; rows without a goal (NaN) or on it get zero."""
    p, g = np.asarray(position, float), np.asarray(goal, float)
    e = g - p
    dist = np.hypot(e[..., 0], e[..., 1])
    has = np.isfinite(dist) & (dist > 0.0)
    safe = np.where(has, dist, 1.0)
    speed = np.minimum(v_max, safe / (np.asarray(k_f, float) * dt))
    return np.where(has[..., None], np.where(has[..., None], e, 0.0) * (speed / safe)[..., None], 0.0)


def iterations_left(t_start: ArrayLike, frame_period: ArrayLike, t: ArrayLike, dt: float) -> np.ndarray:
    """Control iterations from display time t until the frame that began at t_start ends (its
    K_f = frame_period / dt iterations); 0 once it has ended. Integer array."""
    left = np.rint((np.asarray(t_start, float) + np.asarray(frame_period, float) - np.asarray(t, float)) / dt)
    return np.maximum(left, 0).astype(np.int64)


def frame_hold(
    position: ArrayLike,
    goal: ArrayLike,
    restart: ArrayLike,
    iterations: ArrayLike,
    left: ArrayLike,
    v_max: float,
    dt: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One control iteration of eq. 27's hold for a batch.

    restart (B,) bool: the robot's goal changed (a new frame, or reassigned within one): it takes
    eq. 27 toward the new goal over ``iterations`` (B,) periods (K_f, or what is left of the frame),
    and each later iteration of the hold eq. 27 over the periods left. left (B,): the iterations the
    hold still lasts. Returns (preferred velocity (B,2), NaN rows where no hold applies and eq. 9 is
    used, the new left).
    """
    p = np.asarray(position, float)
    restart = np.asarray(restart, bool)
    k = np.maximum(np.asarray(iterations, np.int64), 0)
    left = np.where(restart, k, np.asarray(left, np.int64))  # a goal after its frame ended: no hold, eq. 9
    holding = left > 0
    pref = np.where(holding[:, None], synchronised_velocity(p, goal, v_max, np.maximum(left, 1), dt), np.nan)
    return pref, np.where(holding, left - 1, 0)
