"""What the goal pipeline should find in coordinator.shapes' drawings: each shape's parts as pixel masks,
and a photo-like picture with its subject's mask."""

from __future__ import annotations

import cv2
import numpy as np

from coordinator.shapes import _SHAPES, SHAPES, circle, coverage


def part_masks(name: str, size: int = 256) -> list[np.ndarray]:
    """Ground truth: the pixel mask (pixel centre inside) of each coloured part of a shape."""
    if name not in _SHAPES:
        raise ValueError(f"unknown shape {name!r}; choose from {', '.join(SHAPES)}")
    return [coverage(inside, size, 1) > 0.5 for inside, _ in _SHAPES[name]]


def shape_mask(name: str, size: int = 256) -> np.ndarray:
    """Ground truth foreground of a shape."""
    return np.logical_or.reduce(part_masks(name, size))


def photo_like(size: int = 256, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A photo-like scene (a shaded subject on an uneven, noisy, blurred background) and its subject mask."""
    rng = np.random.default_rng(seed)
    g = (np.arange(size) + 0.5) / size
    y, x = np.meshgrid(g, g, indexing="ij")
    vignette = 1.0 - 0.35 * ((x - 0.45) ** 2 + (y - 0.5) ** 2)
    bg = np.stack([205 + 30 * x - 20 * y, 200 + 15 * x - 25 * y, 185 - 10 * x - 30 * y], axis=-1)
    img: np.ndarray = bg * vignette[..., None]
    body = circle(0.5, 0.56, 0.25)(x, y) | (((x - 0.5) / 0.3) ** 2 + ((y - 0.6) / 0.22) ** 2 < 1)
    leaf = ((x - 0.6) / 0.1) ** 2 + ((y - 0.25) / 0.05) ** 2 < 1
    shade = 1.0 - 0.45 * np.clip(np.hypot(x - 0.4, y - 0.45) / 0.4, 0, 1)
    orange = np.array([235.0, 120.0, 30.0])
    img[body] = orange * shade[body, None]
    img[leaf & ~body] = np.array([50.0, 140.0, 45.0])
    img = cv2.GaussianBlur(img, (0, 0), 0.8)
    img = img + rng.normal(0.0, 9.0, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), body | leaf
