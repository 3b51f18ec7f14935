"""Small, pure geometry helpers for the simulated world: arena rectangle, polygon obstacles, angles.

All functions work on numpy arrays with a trailing coordinate axis; SI units (metres, radians).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon


def wrap_angle(theta: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(theta, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi


def make_arena(arena: Sequence[float] | None) -> tuple[float, float, float, float] | None:
    """Validate an arena (xmin, ymin, xmax, ymax); None means unbounded."""
    if arena is None:
        return None
    try:
        values = tuple(float(v) for v in arena)
    except (TypeError, ValueError):
        raise ValueError(f"arena must be (xmin, ymin, xmax, ymax) numbers, not {arena!r}") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"arena must be four finite numbers (xmin, ymin, xmax, ymax), not {arena!r}")
    xmin, ymin, xmax, ymax = values
    if not (xmin < xmax and ymin < ymax):
        raise ValueError(f"arena must have xmin < xmax and ymin < ymax, not {values}")
    return values


def rect_signed_distance(xy: np.ndarray, arena: tuple[float, float, float, float]) -> np.ndarray:
    """Signed distance from points to the arena boundary: positive inside, negative outside.

    ``xy`` has shape (..., 2); the result has shape (...).
    """
    xmin, ymin, xmax, ymax = arena
    x, y = xy[..., 0], xy[..., 1]
    inside = np.minimum(np.minimum(x - xmin, xmax - x), np.minimum(y - ymin, ymax - y))
    ox = np.maximum(np.maximum(xmin - x, x - xmax), 0.0)
    oy = np.maximum(np.maximum(ymin - y, y - ymax), 0.0)
    return np.where(inside >= 0.0, inside, -np.hypot(ox, oy))


def make_polygon(vertices: Sequence[Sequence[float]], index: int = 0) -> Polygon:
    """A simple polygon (no holes) from a vertex list; ValueError if degenerate or self-intersecting."""
    try:
        arr = np.asarray(vertices, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"obstacle {index}: vertices must be (x, y) number pairs") from None
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 3:
        raise ValueError(f"obstacle {index}: need at least 3 (x, y) vertices, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"obstacle {index}: vertices must be finite")
    poly = Polygon(arr)
    if not poly.is_valid:
        raise ValueError(f"obstacle {index}: polygon is not valid ({shapely.is_valid_reason(poly)})")
    if poly.area <= 0.0:
        raise ValueError(f"obstacle {index}: polygon has zero area")
    shapely.prepare(poly)
    return poly


def polygon_signed_distance(poly: Polygon, xy: np.ndarray) -> np.ndarray:
    """Signed distance from points (M, 2) to a polygon: positive outside, negative inside."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    d = shapely.distance(poly.exterior, shapely.points(xy))
    inside = shapely.contains_xy(poly, xy[:, 0], xy[:, 1])
    return np.where(inside, -d, d)
