"""Test shapes drawn as RGB images in the unit square (x right, y down): the paper's Fig. 4 patterns (disk,
disk and line, line, L, T), a ring, two touching squares and the triangle of Fig. 18."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

RGB = tuple[int, int, int]
RED: RGB = (220, 40, 40)
BLUE: RGB = (30, 80, 200)
WHITE: RGB = (255, 255, 255)

Inside = Callable[[np.ndarray, np.ndarray], np.ndarray]
Part = tuple[Inside, RGB]


def _rect(x0: float, x1: float, y0: float, y1: float) -> Inside:
    return lambda x, y: (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def circle(cx: float, cy: float, r: float) -> Inside:
    """The disk of radius r around (cx, cy)."""
    return lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 < r * r


def union(*parts: Inside) -> Inside:
    """Inside any of the parts."""
    return lambda x, y: np.logical_or.reduce([p(x, y) for p in parts])


def _ring(cx: float, cy: float, r_out: float, r_in: float) -> Inside:
    outer, inner = circle(cx, cy, r_out), circle(cx, cy, r_in)
    return lambda x, y: outer(x, y) & ~inner(x, y)


def polygon(points: list[tuple[float, float]]) -> Inside:
    """A convex polygon (vertices in order)."""
    p = np.asarray(points, float)
    q = np.roll(p, -1, axis=0)
    sign = np.sign(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
    edges = list(zip(p, q))
    return lambda x, y: np.logical_and.reduce(
        [sign * ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) > 0 for (x0, y0), (x1, y1) in edges]
    )


def _triangle(cx: float, cy: float, r: float) -> Inside:
    """An equilateral triangle, apex up, centroid (cx, cy), circumradius r (paper Fig. 18)."""
    return polygon([(cx + r * math.cos(a), cy - r * math.sin(a)) for a in (math.pi / 2, math.pi * 7 / 6, -math.pi / 6)])


def _fig4_rect(x0: float, x1: float, y0: float, y1: float) -> Inside:
    """A rectangle measured in pixels of the paper's Fig. 4 (512 px canvas)."""
    return _rect(x0 / 512, x1 / 512, y0 / 512, y1 / 512)


# name -> list of (part, default colour); proportions measured on the paper's Fig. 4 (512 px canvas)
_SHAPES: dict[str, list[Part]] = {
    "disk": [(circle(0.5, 0.5, 150 / 512), RED)],
    "disk_and_line": [(circle(190 / 512, 0.5, 120 / 512), RED), (_fig4_rect(380, 420, 80, 430), BLUE)],
    "line": [(_fig4_rect(236, 276, 60, 452), BLUE)],
    "L": [(union(_fig4_rect(140, 220, 80, 430), _fig4_rect(140, 400, 350, 430)), RED)],
    "T": [(union(_fig4_rect(100, 412, 80, 160), _fig4_rect(216, 296, 80, 440)), BLUE)],
    "ring": [(_ring(0.5, 0.5, 0.36, 0.2), RED)],
    "two_squares": [(_rect(0.15, 0.5, 0.3, 0.7), RED), (_rect(0.5, 0.85, 0.3, 0.7), BLUE)],
    "triangle": [(_triangle(0.5, 0.5, 0.3), RED)],
}
SHAPES = tuple(_SHAPES)


def coverage(inside: Inside, size: int, ss: int) -> np.ndarray:
    """Fraction of each pixel covered by the shape, from ss x ss samples per pixel."""
    offs = (np.arange(ss) + 0.5) / ss
    g = (np.arange(size)[:, None] + offs[None, :]).ravel() / size
    y, x = np.meshgrid(g, g, indexing="ij")
    return inside(x, y).reshape(size, ss, size, ss).mean(axis=(1, 3))


def paint(
    parts: list[Part], size: int = 256, *, background: RGB = WHITE, antialias: bool = False, alpha: bool = False
) -> np.ndarray:
    """Paint the parts in order (later ones on top) on a size x size canvas (antialias: 4 x 4 supersampled;
    alpha: RGBA of coverage); crisp pixel edges without antialias."""
    img = np.empty((size, size, 3), float)
    img[:] = background
    total = np.zeros((size, size))
    for inside, col in parts:
        cov = coverage(inside, size, 4 if antialias else 1)
        img = img * (1 - cov[..., None]) + np.asarray(col, float) * cov[..., None]
        total = np.maximum(total, cov)
    out = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if alpha:
        a = np.clip(np.round(total * 255), 0, 255).astype(np.uint8)
        return np.dstack([out, a])
    return out


def draw(name: str, size: int = 256, **options: Any) -> np.ndarray:
    """Draw shape `name` on a size x size canvas (options: paint's)."""
    if name not in _SHAPES:
        raise ValueError(f"unknown shape {name!r}; choose from {', '.join(SHAPES)}")
    return paint(_SHAPES[name], size, **options)
