"""Centroidal Voronoi tessellation of a region R_i by Lloyd iterations (paper 4.3).

The plane is the pixel grid. A domain is a set of pixel centres with a mass density rho:
- `density_domain`: eq. 2 over the convex region R^_i enclosing R_i: rho = K_m on pixels of R_i and
  K_d times the largest 8-neighbour density outside, i.e. K_m K_d^d at chessboard distance d from R_i.
  Pixels with rho < K_m 1e-16 (d > 16 for K_d = 0.1) cannot move a centroid at double precision and are
  left out.
- `binary_domain`: the fast variant, rho = 1 on R_i and 0 elsewhere (k-means on the pixels of R_i).

Each Lloyd iteration assigns every pixel to its nearest generator (its Voronoi cell V_j, eq. 3) and
moves each generator towards the mass centroid of its cell (eq. 4), over-relaxed when that lowers the
cost (see `lloyd`). The reported cost is eq. 1 divided by K_m in the normalised square Q (longer image
side = 1), each pixel weighing its area, so it does not depend on the image resolution. It never rises.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

K_M = 1e15
K_D = 0.1
TOLERANCE = 1e-4  # stop when the cost of eq. 1 falls by less than this fraction in one iteration
MAX_ITER = 300
RELAX = 1.8  # initial over-relaxation of the Lloyd step (1 = plain Lloyd), see lloyd()
_GROW = 1.25
_MAX_RELAX = 4.0


@dataclass
class Domain:
    """Pixel centres (x, y) in pixel units and their mass density rho / K_m."""

    points: np.ndarray
    weights: np.ndarray
    inside: np.ndarray  # pixel belongs to R_i

    def __post_init__(self) -> None:
        # contiguous copies for the hot loop of the Lloyd iterations
        self.x = np.ascontiguousarray(self.points[:, 0])
        self.y = np.ascontiguousarray(self.points[:, 1])
        self.wx = self.weights * self.x
        self.wy = self.weights * self.y


def _domain(rr: np.ndarray, cc: np.ndarray, weights: np.ndarray, inside: np.ndarray) -> Domain:
    pts = np.stack([cc + 0.5, rr + 0.5], axis=1).astype(float)
    return Domain(pts, weights, inside)


def binary_domain(rows: np.ndarray, cols: np.ndarray) -> Domain:
    """Binary density: the pixels of R_i with weight 1."""
    return _domain(rows, cols, np.ones(len(rows)), np.ones(len(rows), bool))


def density_domain(rows: np.ndarray, cols: np.ndarray, *, k_d: float = K_D) -> Domain:
    """Eq. 2 density over the convex hull R^_i of R_i (see the module docstring)."""
    r0, c0 = int(rows.min()), int(cols.min())
    h, w = int(rows.max()) - r0 + 1, int(cols.max()) - c0 + 1
    inside = np.zeros((h, w), bool)
    inside[rows - r0, cols - c0] = True
    hull = np.zeros((h, w), np.uint8)
    pts = np.stack([cols - c0, rows - r0], axis=1).astype(np.int32)
    cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
    ring = ndimage.distance_transform_cdt(~inside, metric="chessboard")
    max_ring = int(np.floor(16.0 / -np.log10(k_d))) if 0 < k_d < 1 else 0
    rr, cc = np.nonzero(inside | ((hull > 0) & (ring <= max_ring)))
    weights = np.power(float(k_d), ring[rr, cc].astype(float))
    return _domain(rr + r0, cc + c0, weights, inside[rr, cc])


class _Assigner:
    """Nearest generator of every pixel, exact and incremental (Hamerly's bounds): a pixel keeps its
    generator while its distance to it is below a lower bound on the distance to any other generator
    (the second-nearest distance at its last query, less the largest move of a generator since).
    Only the other pixels, a few percent in late Lloyd iterations, are queried again."""

    def __init__(self, domain: Domain) -> None:
        self.domain = domain
        self.prev: np.ndarray | None = None
        n = len(domain.points)
        self.idx = np.zeros(n, np.int64)
        self.dist = np.zeros(n)
        self.lower = np.zeros(n)

    def _query(self, gen: np.ndarray, sel: np.ndarray | slice) -> None:
        pts = self.domain.points[sel]
        k = 2 if len(gen) > 1 else 1
        d, i = cKDTree(gen).query(pts, k=k, workers=-1 if len(pts) > 50000 else 1)
        if k == 1:
            self.idx[sel], self.dist[sel], self.lower[sel] = i, d, np.inf
        else:
            self.idx[sel], self.dist[sel], self.lower[sel] = i[:, 0], d[:, 0], d[:, 1]

    def assign(self, gen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index of the nearest generator, squared distance to it) per pixel."""
        if self.prev is None:
            self._query(gen, slice(None))
        else:
            step = gen - self.prev
            self.lower -= float(np.sqrt((step * step).sum(axis=1).max()))
            dx = self.domain.x - gen[:, 0][self.idx]
            dy = self.domain.y - gen[:, 1][self.idx]
            self.dist = np.sqrt(dx * dx + dy * dy)
            check = self.dist > self.lower
            if check.any():
                self._query(gen, np.nonzero(check)[0])
        self.prev = gen.copy()
        return self.idx, self.dist * self.dist


def cell_centroids(domain: Domain, idx: np.ndarray, gen: np.ndarray) -> np.ndarray:
    """Mass centroids C_j of the cells (eq. 4); a generator with an empty cell stays put."""
    k = len(gen)
    mass = np.bincount(idx, domain.weights, k)
    cx = np.bincount(idx, domain.wx, k)
    cy = np.bincount(idx, domain.wy, k)
    out = gen.copy()
    ok = mass > 0
    out[ok, 0] = cx[ok] / mass[ok]
    out[ok, 1] = cy[ok] / mass[ok]
    return out


def cvt_cost(domain: Domain, gen: np.ndarray, scale: float) -> float:
    """Cost of eq. 1 (divided by K_m, in units of Q whose side is `scale` pixels) of generators gen."""
    _, d2 = _Assigner(domain).assign(gen)
    return float(np.dot(domain.weights, d2)) / scale**4


def lloyd(
    domain: Domain,
    init: np.ndarray,
    scale: float,
    *,
    tol: float = TOLERANCE,
    max_iter: int = MAX_ITER,
    relax: float = RELAX,
) -> tuple[np.ndarray, list[float]]:
    """Lloyd iterations from `init` until the cost of eq. 1 falls by less than `tol` (relative).

    Each iteration computes the Voronoi cells and their mass centroids C_j (eq. 4). With relax = 1 the
    generators move to C_j (plain Lloyd). With relax > 1 they first try the over-relaxed step
    q + w (C - q) (w starts at `relax`, grows by 25 % after each accepted step up to 4, and resets when
    a step is refused) and keep it only if it lowers the cost; otherwise they take the plain Lloyd step.
    Either way the cost never rises; over-relaxation shortens the slow tails of Lloyd's method (a
    generator creeping round a corner) so that the cost settles within a few tens of iterations.

    Returns (generators in pixel units, cost of eq. 1 per iteration: history[0] is the cost of `init`,
    history[-1] the cost of the returned generators)."""
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
