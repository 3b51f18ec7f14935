"""Initial samples inside a region R_i (paper 4.2): darts at least K_s = 1.2 sqrt(A_i / (pi N_i)) apart,
or for regions of many goals a hexagonal lattice. Pixel (row r, column c) is the square [c, c+1) x [r, r+1).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

KS_FACTOR = 1.2
_TRIES_PER_SAMPLE = 40  # darts per wanted sample before K_s is relaxed
_RELAX = 0.9  # K_s shrink factor when the region is too crowded (thin regions) to place N_i samples
_LATTICE_STEPS = 24  # bisections of the lattice spacing: to 1e-7 of it


def region_box(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The pixels (rows, cols) of R_i as a mask of their bounding box, and the box's first row and column."""
    r0, c0 = int(rows.min()), int(cols.min())
    mask = np.zeros((int(rows.max()) - r0 + 1, int(cols.max()) - c0 + 1), bool)
    mask[rows - r0, cols - c0] = True
    return mask, r0, c0


def pixel_centres(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The centres (x, y) of the pixels (rows, cols)."""
    return np.stack([cols + 0.5, rows + 0.5], axis=1)


def in_region(pts: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Whether each point (x, y), pixel units, lies in a pixel of R_i (pixels rows, cols)."""
    mask, r0, c0 = region_box(rows, cols)
    px, py = np.floor(pts[:, 0]).astype(int) - c0, np.floor(pts[:, 1]).astype(int) - r0
    ok = (px >= 0) & (px < mask.shape[1]) & (py >= 0) & (py < mask.shape[0])
    ok[ok] = mask[py[ok], px[ok]]
    return ok


def ks_distance(area: float, n: int) -> float:
    """K_s (paper 4.2): KS_FACTOR times the radius of a circle of area A_i / N_i."""
    return KS_FACTOR * math.sqrt(area / (math.pi * n))


def poisson_samples(
    rows: np.ndarray, cols: np.ndarray, n: int, rng: np.random.Generator, ks: float | None = None
) -> tuple[np.ndarray, float]:
    """n samples (x, y) in pixels inside R_i, pairwise >= K_s apart (shrunk if too thin), and the K_s used."""
    if n <= 0:
        return np.zeros((0, 2)), 0.0
    npx = len(rows)
    if n > npx:
        raise ValueError(f"cannot place {n} samples in {npx} pixels")
    ks = ks_distance(npx, n) if ks is None else float(ks)
    xs_c = cols.astype(float)
    ys_c = rows.astype(float)
    accepted = np.zeros((0, 2))
    while True:
        budget = _TRIES_PER_SAMPLE * n
        while budget > 0 and len(accepted) < n:
            batch = min(budget, max(256, 4 * (n - len(accepted))))
            budget -= batch
            pick = rng.integers(npx, size=batch)
            jit = rng.random((batch, 2))
            darts = np.stack([xs_c[pick] + jit[:, 0], ys_c[pick] + jit[:, 1]], axis=1)
            if len(accepted):  # no closer than K_s to a sample taken
                gap, _ = cKDTree(accepted).query(darts, distance_upper_bound=ks)
                darts = darts[gap >= ks]
            darts = _first_apart(darts, ks)[: n - len(accepted)]
            accepted = np.concatenate([accepted, darts])
        if len(accepted) == n:
            return accepted, ks
        ks *= _RELAX


def _first_apart(darts: np.ndarray, ks: float) -> np.ndarray:
    """The darts taken in order, each unless closer than ks to one taken before it."""
    if len(darts) < 2:
        return darts
    pairs = cKDTree(darts).query_pairs(ks * (1 + 1e-9), output_type="ndarray")
    d = darts[pairs[:, 0]] - darts[pairs[:, 1]]
    first, then = pairs[d[:, 0] ** 2 + d[:, 1] ** 2 < ks * ks].T  # first < then
    kept = np.ones(len(darts), bool)
    open_ = np.ones(len(darts), bool)  # not decided yet
    while len(then):
        # a dart next to a kept one is dropped; one whose earlier neighbours are all decided is kept
        kept[then[kept[first] & ~open_[first]]] = False
        open_[then[~kept[then]]] = False
        waits = np.zeros(len(darts), bool)
        waits[then[open_[first]]] = True
        open_ &= waits
        live = open_[then]
        first, then = first[live], then[live]
    return darts[kept]


def lattice_samples(rows: np.ndarray, cols: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n samples (x, y) in pixels inside R_i on a hexagonal lattice (rows along R_i's long axis, seeded
    offset), the spacing bisected to hold n points: a large CVT is a lattice but near its border, so Lloyd
    settles in fewer iterations to a lower cost than from random samples."""
    if n <= 0:
        return np.zeros((0, 2))
    npx = len(rows)
    if n > npx:
        raise ValueError(f"cannot place {n} samples in {npx} pixels")
    inside, r0, c0 = region_box(rows, cols)
    offset = rng.random(2)
    # rows along the region's long axis: a bar's CVT lines up with its sides
    _, axes = np.linalg.eigh(np.cov(np.stack([cols, rows]).astype(float)) if npx > 1 else np.eye(2))
    angle = math.atan2(axes[1, 1], axes[0, 1])
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    basis = np.array([[1.0, 0.0], [0.5, math.sqrt(3) / 2]]) @ rot.T  # lattice (i, j) -> (x, y) at spacing 1
    corners = np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) * inside.shape[::-1] + [c0, r0]

    def lattice(h: float) -> tuple[np.ndarray, np.ndarray]:
        """(i, j) and position of the lattice points of spacing h in R_i."""
        ij = corners @ np.linalg.inv(basis * h) - offset  # the bounding box in lattice coordinates
        lo, hi = np.floor(ij.min(axis=0)) - 1, np.ceil(ij.max(axis=0)) + 1
        i, j = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        p = (np.stack([i.ravel(), j.ravel()], axis=1) + offset) @ (basis * h)
        keys = i.ravel().astype(np.int64) * (1 << 32) + j.ravel().astype(np.int64)  # one number a point
        ok = in_region(p, rows, cols)
        return keys[ok], p[ok]

    h0 = math.sqrt(2 * npx / (math.sqrt(3) * n))  # n hexagons of this spacing cover A_i
    lo, hi = min(h0 / 2, 0.86), 2 * h0  # below sqrt(3) / 2 every pixel holds a lattice point: n or more
    few = lattice(hi)
    while len(few[1]) > n:  # a spacing longer than R_i's bounding box holds one point at most
        hi *= 2
        few = lattice(hi)
    if len(few[1]) == n:
        return few[1]
    for _ in range(_LATTICE_STEPS):
        mid = (lo + hi) / 2
        keys, p = lattice(mid)
        if len(p) == n:
            return p
        if len(p) > n:
            lo = mid
        else:
            hi, few = mid, (keys, p)
    keys, p = lattice(lo)
    crossing = np.flatnonzero(~np.isin(keys, few[0]))
    pick = crossing[np.linspace(0, len(crossing) - 1, n - len(few[1])).round().astype(int)]
    return np.concatenate([few[1], p[pick]])
