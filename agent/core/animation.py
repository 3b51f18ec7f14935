"""Real-time control of animations (paper 6.2, eq. 27), over a batch of robots: pure, no clock.

v_pref = min(v_max, |g - p| / (K_f dt)) toward a new keyframe's goal, held for the K_f iterations left: the
arrival time is held, not the velocity, so a slowed robot catches up (docs/scenes.md, "Frame timing").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # numpy.typing stays out of a robot's process: annotations only
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
    """One iteration of eq. 27's hold: a ``restart`` (new goal) holds over ``iterations`` (K_f, or what is
    left of the frame), else over the ``left``. Returns (preferred velocity, NaN rows: eq. 9; new left)."""
    p = np.asarray(position, float)
    restart = np.asarray(restart, bool)
    k = np.maximum(np.asarray(iterations, np.int64), 0)
    left = np.where(restart, k, np.asarray(left, np.int64))  # a goal after its frame ended: no hold, eq. 9
    holding = left > 0
    pref = np.where(holding[:, None], synchronised_velocity(p, goal, v_max, np.maximum(left, 1), dt), np.nan)
    return pref, np.where(holding, left - 1, 0)
