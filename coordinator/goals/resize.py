"""Goals from the normalised square Q (the image's longer side = 1) to the arena of side K_r (paper 4.4):
origin at the arena's centre, x right, y up. Robots of radius r_A fit if K_r >= 2 r_A / d_min; the default
arena is the conservative twice that, rounded up to a centimetre."""

from __future__ import annotations

import math

import numpy as np

from .model import GoalError


def min_arena(d_min: float, robot_radius: float, conservative: bool = False) -> float:
    """Smallest K_r (metres) with K_r d_min >= 2 r_A, doubled if conservative."""
    k_r = 2.0 * robot_radius / d_min if d_min > 0 else math.inf
    return (2.0 if conservative else 1.0) * k_r


def auto_arena(d_min: float, robot_radius: float) -> float:
    """Default arena: the conservative 2 K_r rounded up to a centimetre, and at least 4 r_A."""
    if d_min <= 0:
        raise GoalError("two goals coincide: no arena fits them; use fewer robots or a larger image")
    k_r = max(min_arena(d_min, robot_radius, conservative=True), 4.0 * robot_radius)
    return math.ceil(round(k_r * 100.0, 6)) / 100.0


def check_feasible(d_min: float, n: int, arena: float, robot_radius: float, conservative: bool = False) -> None:
    """Raise GoalError naming the smallest arena and the largest N (an estimate) that fit."""
    need = min_arena(d_min, robot_radius, conservative)
    if arena >= need * (1.0 - 1e-9):
        return
    if not math.isfinite(need):
        raise GoalError(f"two of the N={n} goals coincide: no arena fits robots of radius {robot_radius:g} m")
    fit = int(n * (arena / need) ** 2)
    rule = "2 K_r (conservative)" if conservative else "K_r >= 2 r_A / d_min"
    raise GoalError(
        f"N={n} goals are as close as {arena * d_min:.3f} m in a {arena:g} m arena, too close for robots of "
        f"radius {robot_radius:g} m ({rule}): use an arena of at least {math.ceil(need * 100) / 100:.2f} m "
        f"or at most about {fit} robots"
    )


def to_arena(goals_px: np.ndarray, shape: tuple[int, ...], arena: float) -> np.ndarray:
    """Pixel coordinates (x, y) of an image of shape (H, W) to metres in the arena frame."""
    h, w = shape[:2]
    s = float(max(h, w))
    q = np.asarray(goals_px, dtype=float) / s
    return np.stack([arena * (q[:, 0] - w / (2 * s)), arena * (h / (2 * s) - q[:, 1])], axis=1)


def from_arena(goals_m: np.ndarray, shape: tuple[int, ...], arena: float) -> np.ndarray:
    """Inverse of to_arena: metres in the arena frame to pixel coordinates (x, y)."""
    h, w = shape[:2]
    s = float(max(h, w))
    g = np.asarray(goals_m, dtype=float) / arena
    return np.stack([(g[:, 0] + w / (2 * s)) * s, (h / (2 * s) - g[:, 1]) * s], axis=1)
