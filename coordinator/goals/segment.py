"""Segmentation of the foreground into regions R_i by colour and connectivity (paper 4.1).

Each 8-connected set of one palette colour is a candidate region; weak ones (small or thin) join the
neighbour they share the longest border with, and touching regions meeting in a smooth gradient
(shading) merge. Region ids are ordered by area, largest first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from .image import lab_sums, lab_to_rgb, to_lab

COLOR_TOLERANCE = 20.0  # Delta E below which two foreground colours are one palette colour
_EIGHT = np.ones((3, 3), bool)
_HALF_NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass
class Region:
    """Region R_i: its id, area in pixels and mean colour."""

    id: int
    area: int
    color: tuple[int, int, int]
    lab: np.ndarray


@dataclass
class Segmentation:
    """labels: (H, W) region id per pixel, -1 for background; regions ordered by id."""

    labels: np.ndarray
    regions: list[Region]
    notes: list[str] = field(default_factory=list)
    _order: np.ndarray | None = field(default=None, repr=False)
    _starts: np.ndarray | None = field(default=None, repr=False)

    def pixels(self, region_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the pixels of region R_i."""
        flat = self.labels.ravel()
        if self._order is None or self._starts is None:
            self._order = np.argsort(flat, kind="stable")
            self._starts = np.searchsorted(flat[self._order], np.arange(-1, len(self.regions) + 1))
        idx = self._order[self._starts[region_id + 1] : self._starts[region_id + 2]]
        return np.divmod(idx, self.labels.shape[1])


def _palette(lab: np.ndarray, tol: float) -> np.ndarray:
    """Palette index per colour (rows of lab): leader clustering on a coarse Lab histogram, refined."""
    q = tol / 2.0
    k = np.floor((lab - np.array([0.0, -128.0, -128.0])) / q).astype(np.int64)
    base = int(np.ceil(300.0 / q)) + 2
    keys = (k[:, 0] * base + k[:, 1]) * base + k[:, 2]
    _, inv, counts = np.unique(keys, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    means = lab_sums(lab, inv, len(counts))[0] / counts[:, None]
    centres: list[np.ndarray] = []
    for b in np.argsort(-counts, kind="stable"):
        if not centres or np.min(np.linalg.norm(np.asarray(centres) - means[b], axis=1)) >= tol:
            centres.append(means[b])
    cen = np.asarray(centres)
    for _ in range(3):  # a few weighted Lloyd steps on the histogram
        assign = np.argmin(np.linalg.norm(means[:, None, :] - cen[None], axis=2), axis=1)
        w = np.bincount(assign, counts, len(cen))
        keep = w > 0
        sums = lab_sums(means * counts[:, None], assign, len(cen))[0]
        cen = sums[keep] / w[keep, None]
    assign = np.argmin(np.linalg.norm(means[:, None, :] - cen[None], axis=2), axis=1)
    return assign[inv]


def _components(pal_img: np.ndarray) -> np.ndarray:
    comp = np.full(pal_img.shape, -1, np.int64)
    offset = 0
    for k in np.unique(pal_img[pal_img >= 0]):
        lab, n = ndimage.label(pal_img == k, structure=_EIGHT)
        comp[lab > 0] = lab[lab > 0] - 1 + offset
        offset += n
    return comp


def _neighbour_pairs(
    comp: np.ndarray, lab: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(a, b, Delta E if lab is given) for every pair of 8-adjacent pixels in different components, both ways."""
    h, w = comp.shape
    aa, bb, dd = [], [], []
    for dy, dx in _HALF_NEIGHBOURS:
        sa = (slice(0, h - dy), slice(max(0, -dx), w - max(0, dx)))
        sb = (slice(dy, h), slice(max(0, dx), w - max(0, -dx)))
        a, b = comp[sa], comp[sb]
        m = (a >= 0) & (b >= 0) & (a != b)
        aa += [a[m], b[m]]
        bb += [b[m], a[m]]
        if lab is not None:
            step = np.linalg.norm(lab[sa][m] - lab[sb][m], axis=1)
            dd += [step, step]
    return np.concatenate(aa), np.concatenate(bb), (np.concatenate(dd) if lab is not None else None)


def _merge_smooth(comp: np.ndarray, lab: np.ndarray, step: float) -> tuple[np.ndarray, int]:
    """Merge touching regions whose mean colour step across their border is below `step` (shading)."""
    a, b, d = _neighbour_pairs(comp, lab)
    if len(a) == 0:
        return comp, 0
    n = int(comp.max()) + 1
    key = a * n + b
    uniq, inv = np.unique(key, return_inverse=True)
    mean = np.bincount(inv.reshape(-1), d) / np.bincount(inv.reshape(-1))
    ua, ub = np.divmod(uniq[mean < step], n)
    if len(ua) == 0:
        return comp, 0
    graph = sparse.coo_matrix((np.ones(len(ua)), (ua, ub)), shape=(n, n))
    _, group = csgraph.connected_components(graph, directed=False)
    merged = len(np.unique(comp[comp >= 0])) - len(np.unique(group[comp[comp >= 0]]))
    return np.where(comp >= 0, group[np.maximum(comp, 0)], -1), merged


def _interior_counts(comp: np.ndarray, n: int) -> np.ndarray:
    """Per component, the number of pixels whose 8 neighbours all belong to it (off the image: none)."""
    low = ndimage.minimum_filter(comp, size=3, mode="constant", cval=-2)
    high = ndimage.maximum_filter(comp, size=3, mode="constant", cval=-2)
    inside = (comp >= 0) & (low == comp) & (high == comp)
    return np.bincount(comp[inside], minlength=n)


def _absorb_weak(comp: np.ndarray, weak: np.ndarray) -> tuple[np.ndarray, int]:
    """Relabel weak components into their strong neighbour with the longest shared border."""
    n = len(weak)
    absorbed = 0
    weak = weak.copy()
    for _ in range(64):
        a, b, _ = _neighbour_pairs(comp)
        sel = weak[a] & ~weak[b]
        if not sel.any():
            break
        key = a[sel] * n + b[sel]
        uniq, cnt = np.unique(key, return_counts=True)
        ua, ub = np.divmod(uniq, n)
        order = np.lexsort((-cnt, ua))
        first = np.r_[True, ua[order][1:] != ua[order][:-1]]
        src, dst = ua[order][first], ub[order][first]
        mapping = np.arange(n)
        mapping[src] = dst
        comp = np.where(comp >= 0, mapping[np.maximum(comp, 0)], -1)
        weak[src] = False
        absorbed += len(src)
    return comp, absorbed


def speck_area(shape: tuple[int, ...], min_area: int | None = None) -> int:
    """Pixels a region needs in an image of ``shape`` (H, W, ...): fewer make a speck, dropped (or min_area)."""
    return max(16, int(round(2e-4 * shape[0] * shape[1]))) if min_area is None else int(min_area)


def segment(rgb: np.ndarray, mask: np.ndarray, *, min_area: int | None = None) -> Segmentation:
    """Split the foreground `mask` of `rgb` into regions R_i; specks under min_area pixels are none."""
    h, w = mask.shape
    min_area = speck_area(mask.shape, min_area)
    notes: list[str] = []
    if not mask.any():
        return Segmentation(np.full((h, w), -1, np.int64), [], notes)
    lab = to_lab(rgb).astype(np.float64)
    pal = np.full((h, w), -1, np.int64)
    pal[mask] = _palette(lab[mask], COLOR_TOLERANCE)
    comp = _components(pal)
    n = int(comp.max()) + 1
    area = np.bincount(comp[comp >= 0], minlength=n)
    thin = _interior_counts(comp, n) * 10 < area
    weak = (area < min_area) | thin
    comp, absorbed = _absorb_weak(comp, weak)
    if absorbed:
        notes.append(f"{absorbed} thin or small fragment(s) merged into neighbouring regions")
    # touching strong regions that meet in a smooth gradient are one region
    left = np.zeros(comp.shape, bool)
    left[comp >= 0] = weak[comp[comp >= 0]]
    comp, merged = _merge_smooth(np.where(left, -1, comp), lab, COLOR_TOLERANCE / 2.0)
    if merged:
        notes.append(f"{merged} region(s) joined across smooth colour gradients (shading)")
    # weak pieces that touch no strong region: merge them with each other by connectivity
    if left.any():
        groups, ng = ndimage.label(left, structure=_EIGHT)
        garea = np.bincount(groups.ravel(), minlength=ng + 1)
        big = garea >= min_area
        big[0] = False
        comp[left] = np.where(big[groups[left]], int(comp.max()) + 1 + groups[left], -1)
        dropped = int((~big[1:]).sum())
        if dropped:
            notes.append(f"dropped {dropped} speck(s) smaller than {min_area} pixels")
    # final ids by area, largest first (ties: first pixel in raster order)
    flat = comp.ravel()
    ids, first, areas = np.unique(flat[flat >= 0], return_index=True, return_counts=True)
    order = np.lexsort((first, -areas))
    remap = np.full(int(flat.max()) + 2 if flat.size else 1, -1, np.int64)
    remap[ids[order]] = np.arange(len(ids))
    labels = np.where(comp >= 0, remap[np.maximum(comp, 0)], -1)
    lflat = labels.ravel()
    sel = lflat >= 0
    if not sel.any():  # the foreground was specks alone: no region (the caller says so)
        return Segmentation(labels, [], notes)
    lf = to_lab(np.asarray(rgb).reshape(-1, 3)[sel], precise=True).astype(np.float64)
    sums, cnt = lab_sums(lf, lflat[sel], len(ids))
    means = sums / np.maximum(cnt, 1)[:, None]
    rgbs = lab_to_rgb(means)
    regions = [
        Region(i, int(cnt[i]), (int(rgbs[i, 0]), int(rgbs[i, 1]), int(rgbs[i, 2])), means[i]) for i in range(len(ids))
    ]
    return Segmentation(labels, regions, notes)
