"""Centroidal Voronoi tessellation of a region R_i by Lloyd iterations (paper 4.3), on the pixel grid.

A domain is pixel centres with a mass density: eq. 2's over the convex hull of R_i (K_m on R_i, times
K_d per chessboard step outside, cut where it falls below 1e-16 K_m and cannot move a centroid), or the
binary k-means one. The cost is eq. 1 / K_m in the normalised square Q, each pixel weighing its area.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .defaults import MAX_ITER, RELAX, TOLERANCE
from .sampling import pixel_centres, region_box

K_M = 1e15
K_D = 0.1
_GROW = 1.25
_MAX_RELAX = 4.0
_CELL = 2.0  # side of the cells that localise the bounds of the nearest-generator search, in spacings
_BLOCK = 2  # cells either side of a pixel's own whose generators' moves loosen its bound
_PARALLEL = 20000  # tree queries of more pixels than this use every core


@dataclass
class Domain:
    """Pixel centres (x, y) in pixel units and their mass density rho / K_m."""

    points: np.ndarray
    weights: np.ndarray
    inside: np.ndarray  # pixel belongs to R_i

    def __post_init__(self) -> None:  # contiguous copies for the Lloyd iterations' hot loop
        self.x = np.ascontiguousarray(self.points[:, 0])
        self.y = np.ascontiguousarray(self.points[:, 1])
        self.wx = self.weights * self.x
        self.wy = self.weights * self.y


def binary_domain(rows: np.ndarray, cols: np.ndarray) -> Domain:
    """Binary density: the pixels of R_i with weight 1."""
    return Domain(pixel_centres(rows, cols), np.ones(len(rows)), np.ones(len(rows), bool))


def density_domain(rows: np.ndarray, cols: np.ndarray) -> Domain:
    """Eq. 2 density over the convex hull R^_i of R_i."""
    inside, r0, c0 = region_box(rows, cols)
    hull = np.zeros(inside.shape, np.uint8)
    pts = np.stack([cols - c0, rows - r0], axis=1).astype(np.int32)
    cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
    ring = ndimage.distance_transform_cdt(~inside, metric="chessboard")
    max_ring = int(np.floor(16.0 / -np.log10(K_D)))
    rr, cc = np.nonzero(inside | ((hull > 0) & (ring <= max_ring)))
    weights = np.power(K_D, ring[rr, cc].astype(float))
    return Domain(pixel_centres(rr + r0, cc + c0), weights, inside[rr, cc])


class _Assigner:
    """Nearest generator of every pixel, exact and incremental (Hamerly's bounds, localised on a coarse
    grid): only pixels near generators that moved far are queried again."""

    def __init__(self, domain: Domain) -> None:
        self.domain = domain
        self.prev: np.ndarray | None = None
        n = len(domain.points)
        self.idx = np.zeros(n, np.int64)
        self.lower = np.zeros(n)
        self.origin = domain.points.min(axis=0)  # a domain is never empty: R_i has pixels

    def _grid(self, k: int) -> None:
        self.cell = max(_CELL * float(np.sqrt(len(self.domain.points) / k)), 2.0)
        ij = np.floor((self.domain.points - self.origin) / self.cell).astype(np.int64)
        self.shape = (int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1)
        self.pixel_cell = ij[:, 0] * self.shape[1] + ij[:, 1]

    def _cells_of(self, gen: np.ndarray) -> np.ndarray:  # off the grid: its border cells
        ij = np.floor((gen - self.origin) / self.cell).astype(np.int64)
        i = np.clip(ij[:, 0], 0, self.shape[0] - 1)
        j = np.clip(ij[:, 1], 0, self.shape[1] - 1)
        return i * self.shape[1] + j

    def _query(self, gen: np.ndarray, sel: np.ndarray | slice) -> None:
        pts = self.domain.points[sel]
        k = 2 if len(gen) > 1 else 1
        d, i = cKDTree(gen).query(pts, k=k, workers=-1 if len(pts) > _PARALLEL else 1)
        if k == 1:
            self.idx[sel], self.lower[sel] = i, np.inf
        else:
            self.idx[sel], self.lower[sel] = i[:, 0], d[:, 1]

    def _loosen(self, gen: np.ndarray, prev: np.ndarray) -> None:
        """Lower the bounds by what the generators' moves from prev to gen may have taken off them."""
        step = gen - prev
        move = np.sqrt((step * step).sum(axis=1))
        near = np.zeros(self.shape[0] * self.shape[1])
        np.maximum.at(near, self._cells_of(prev), move)
        near = ndimage.maximum_filter(near.reshape(self.shape), size=2 * _BLOCK + 1, mode="constant").ravel()
        far = _BLOCK * self.cell - float(move.max())
        self.lower = np.minimum(self.lower - near[self.pixel_cell], far)

    def assign(self, gen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index of the nearest generator, squared distance to it) per pixel."""
        x, y = self.domain.x, self.domain.y
        if self.prev is None or len(self.prev) != len(gen):
            self._grid(len(gen))
            self._query(gen, slice(None))
        else:
            self._loosen(gen, self.prev)
            dx, dy = x - gen[:, 0][self.idx], y - gen[:, 1][self.idx]
            check = np.sqrt(dx * dx + dy * dy) >= self.lower
            if check.any():
                self._query(gen, np.nonzero(check)[0])
        # the same arithmetic for every pixel: the cost does not depend on which were queried again
        dx, dy = x - gen[:, 0][self.idx], y - gen[:, 1][self.idx]
        self.prev = gen.copy()
        return self.idx, dx * dx + dy * dy


def cell_centroids(domain: Domain, idx: np.ndarray, gen: np.ndarray) -> np.ndarray:
    """Mass centroids C_j of the cells (eq. 4); a generator with an empty cell stays put."""
    k = len(gen)
    mass = np.bincount(idx, domain.weights, k)
    moments = np.stack([np.bincount(idx, domain.wx, k), np.bincount(idx, domain.wy, k)], axis=1)
    out, ok = gen.copy(), mass > 0
    out[ok] = moments[ok] / mass[ok, None]
    return out


def lloyd(
    domain: Domain,
    init: np.ndarray,
    scale: float,
    *,
    tol: float = TOLERANCE,
    max_iter: int = MAX_ITER,
    relax: float = RELAX,
) -> tuple[np.ndarray, list[float]]:
    """Lloyd iterations (eq. 4) from `init` until the cost of eq. 1 falls by less than `tol` (relative):
    (generators in pixels, cost per iteration from init's). An over-relaxed step q + w (C - q), kept only
    if it lowers the cost, shortens Lloyd's slow tails; the cost never rises."""
    gen = np.asarray(init, dtype=float).copy()
    if len(gen) == 0:
        return gen, []
    assigner = _Assigner(domain)
    norm = 1.0 / scale**4

    def cost_of(g: np.ndarray) -> float:
        return float(np.dot(domain.weights, assigner.assign(g)[1])) * norm

    cost = cost_of(gen)
    history = [cost]
    omega = relax
    for _ in range(max_iter):
        target = cell_centroids(domain, assigner.idx, gen)
        new, new_cost = None, 0.0
        if omega > 1.0:
            trial = gen + omega * (target - gen)
            trial_cost = cost_of(trial)
            if trial_cost < cost:
                new, new_cost = trial, trial_cost
                omega = min(omega * _GROW, _MAX_RELAX)
            else:
                omega = relax
        if new is None:
            new, new_cost = target, cost_of(target)
            if new_cost > cost:  # rounding noise at convergence: keep the current generators
                break
        done = cost - new_cost <= tol * cost
        gen, cost = new, new_cost
        history.append(cost)
        if done:
            break
    return gen, history
