"""Goal colours (paper 4.1/4.3): each goal takes the mean colour, in CIE Lab, of the image pixels of
its Voronoi cell within its own region R_i. Pixels on the region's edge (anti-aliased, mixed with the
background) count only for cells that have no other pixel."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .image import lab_sums, lab_to_rgb, to_lab
from .sampling import pixel_centres
from .segment import Segmentation


def voronoi_cells(seg: Segmentation, goals_px: np.ndarray, goal_regions: np.ndarray) -> np.ndarray:
    """(H, W) index of the goal whose Voronoi cell within its region holds each pixel; -1 on background."""
    cells = np.full(seg.labels.shape, -1, np.int64)
    for region in seg.regions:
        mine = np.nonzero(goal_regions == region.id)[0]
        if len(mine) == 0:
            continue
        rows, cols = seg.pixels(region.id)
        _, j = cKDTree(goals_px[mine]).query(pixel_centres(rows, cols), workers=-1)
        cells[rows, cols] = mine[j]
    return cells


def _edge(labels: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour in another region (or background, or off the image)."""
    p = np.pad(labels, 1, constant_values=-2)
    c = p[1:-1, 1:-1]
    return (c != p[:-2, 1:-1]) | (c != p[2:, 1:-1]) | (c != p[1:-1, :-2]) | (c != p[1:-1, 2:])


def cell_colors(rgb: np.ndarray, cells: np.ndarray, n: int, fallback_px: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 Lab mean of each cell's pixels off the edges of the regions `labels` (else of all its
    pixels, else of fallback_px's)."""
    flat = cells.ravel()
    fg = flat >= 0
    lab = to_lab(np.asarray(rgb).reshape(-1, 3)[fg], precise=True).astype(np.float64)
    sums, cnt = lab_sums(lab, flat[fg], n)
    isums, icnt = lab_sums(lab, np.where(_edge(labels).ravel()[fg], -1, flat[fg]), n)
    use = icnt > 0
    sums[use], cnt[use] = isums[use], icnt[use]
    means = sums.astype(np.float64)
    empty = cnt == 0
    means[~empty] /= cnt[~empty, None]
    if empty.any():
        h, w = cells.shape
        c = np.clip(fallback_px[empty, 0].astype(int), 0, w - 1)
        r = np.clip(fallback_px[empty, 1].astype(int), 0, h - 1)
        means[empty] = to_lab(np.asarray(rgb)[r, c], precise=True)
    return lab_to_rgb(means)
