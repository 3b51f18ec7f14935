"""Dynamic image display (paper 7.4.1, docs/scenes.md): each robot computes its moving goal from G^0 (eq. 28),

    g_j(t) = p_OG + t v_G + s(t) R(omega_G t) (g_j^0 - p_OG),   s(t) = (1 + K_eG)^t or 1 + K_eG t,
    v_j(t) = v_G + (s'(t) / s(t) + omega_G J) (g_j(t) - p_OG - t v_G),   J = [[0, -1], [1, 0]],

t the display time since the step began (a scalar or one per row). Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .control import preferred_velocity

if TYPE_CHECKING:  # numpy.typing stays out of a robot's process: annotations only
    from numpy.typing import ArrayLike


@dataclass(frozen=True)
class GoalMotion:
    """The constant motion and deformation of a goal set (paper 7.4.1), in SI units."""

    v_g: tuple[float, float] = (0.0, 0.0)  # v_G, translation of the pattern's centre (m/s)
    omega_g: float = 0.0  # omega_G, rotation about the centre (rad/s, counter-clockwise)
    p_og: tuple[float, float] = (0.0, 0.0)  # p_OG, the pattern's centre at t = 0 (m)
    k_eg: float = 0.0  # K_eG, expansion (> 0) or contraction (< 0) per second
    geometric: bool = False  # geometric: s(t) = (1 + K_eG)^t; linear: s(t) = 1 + K_eG t

    def __post_init__(self) -> None:
        if self.geometric and not self.k_eg > -1.0:
            raise ValueError(f"a geometric expansion K_eG must be > -1, not {self.k_eg}")

    def scale(self, t: ArrayLike) -> np.ndarray:
        """s(t): how much the pattern has grown since t = 0 (1 at t = 0)."""
        t = np.asarray(t, float)
        if self.geometric:
            return (1.0 + self.k_eg) ** t
        return 1.0 + self.k_eg * t

    def scale_rate(self, t: ArrayLike) -> np.ndarray:
        """s'(t)."""
        t = np.asarray(t, float)
        if self.geometric:
            return (1.0 + self.k_eg) ** t * np.log1p(self.k_eg)
        return np.full_like(t, self.k_eg)

    def _turn(self, d: np.ndarray, t: np.ndarray, sign: float) -> np.ndarray:
        """Vectors d (B,2) turned by sign * omega_G t: eq. 28's rotation (sign 1) or its inverse (-1)."""
        a = self.omega_g * t
        c, s = np.cos(a), sign * np.sin(a)
        return np.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1]], axis=-1)

    def positions(self, g0: ArrayLike, t: ArrayLike) -> np.ndarray:
        """g_j(t) (eq. 28) of goals g0 (B,2) at time t (scalar or (B,))."""
        g0 = np.asarray(g0, float)
        t = np.broadcast_to(np.asarray(t, float), g0.shape[:-1])
        centre = np.asarray(self.p_og, float)
        turned = self._turn(g0 - centre, t, 1.0)
        return centre + t[..., None] * np.asarray(self.v_g, float) + self.scale(t)[..., None] * turned

    def velocities(self, g0: ArrayLike, t: ArrayLike) -> np.ndarray:
        """dg_j/dt (B,2): the derivative of eq. 28 at time t."""
        g0 = np.asarray(g0, float)
        t = np.broadcast_to(np.asarray(t, float), g0.shape[:-1])
        v_g = np.asarray(self.v_g, float)
        d = self.positions(g0, t) - np.asarray(self.p_og, float) - t[..., None] * v_g  # Delta g_j,OG(t)
        growth = (self.scale_rate(t) / self.scale(t))[..., None]
        return v_g + growth * d + self.omega_g * np.stack([-d[..., 1], d[..., 0]], axis=-1)

    def to_initial_frame(self, points: ArrayLike, t: ArrayLike) -> np.ndarray:
        """The inverse of eq. 28's map at time t (points (B,2) relative to G^0): a similarity, so the
        auction on G^0 with mapped-back robots assigns as on the moving goals."""
        p = np.asarray(points, float)
        t = np.broadcast_to(np.asarray(t, float), p.shape[:-1])
        centre = np.asarray(self.p_og, float)
        d = p - centre - t[..., None] * np.asarray(self.v_g, float)
        return centre + self._turn(d, t, -1.0) / self.scale(t)[..., None]


def tracking_velocity(
    position: ArrayLike, goal: ArrayLike, goal_velocity: ArrayLike, v_pref: float, k_a: float, v_max: float
) -> np.ndarray:
    """Preferred velocity toward a moving goal: v_goal (no lag) + eq. 9's correction, clipped to v_max
    keeping the direction. Rows without a goal (NaN) get zero."""
    correction = preferred_velocity(position, goal, v_pref, k_a)
    gv = np.asarray(goal_velocity, float)
    has = np.isfinite(np.asarray(goal, float)).all(axis=-1) & np.isfinite(gv).all(axis=-1)
    v = np.where(has[..., None], correction + np.where(has[..., None], gv, 0.0), 0.0)
    speed = np.hypot(v[..., 0], v[..., 1])
    factor = np.where(speed > v_max, v_max / np.maximum(speed, 1e-12), 1.0)
    return v * factor[..., None]
