"""Motion of a region R_i between two keyframes (paper 6.1): T_i^f is the centroid shift; M_i^f the best
circular shift of the border signatures r(phi) (FFT cross-correlation, smallest turn on ties, refined by
ICP), whose normalised correlation is the paper's "sufficient correlation". Angles: counter-clockwise, y up.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .goals.resize import to_arena
from .goals.sampling import in_region
from .goals.segment import Segmentation

BINS = 360  # polar-angle bins of the border signature
MIN_CORRELATION = 0.8  # "sufficient correlation" of two region borders (paper 6.1)
SMALL_TURN_PRIOR = 0.05  # score penalty per pi radians of rotation (prefer small turns on ties)
ICP_REACH = np.radians(5.0)  # how far ICP may move the rotation of the signature search


@dataclass
class RegionShape:
    """What frame-to-frame matching needs of R_i, in the normalised arena frame (longer side 1, y up)."""

    centroid: np.ndarray  # (2,) centroid of R_i
    area: float  # A_i in the normalised square
    pixels: int  # A_i in pixels: the border is known to half a pixel, 0.5 / sqrt(pixels) of its scale
    lab: np.ndarray  # (3,) mean colour in Lab
    border: np.ndarray  # (K, 2) Canny edge points of R_i, centred on the centroid, per sqrt(A_i)


def region_shape(seg: Segmentation, region_id: int, lab: np.ndarray) -> RegionShape:
    """Centroid, area and border features of region R_i of a segmentation."""
    shape = seg.labels.shape
    rows, cols = seg.pixels(region_id)
    side = float(max(shape))
    pts = to_arena(np.stack([cols + 0.5, rows + 0.5], axis=1), shape, 1.0)
    centroid = pts.mean(axis=0)
    area = len(rows) / side**2
    r0, c0 = max(int(rows.min()) - 2, 0), max(int(cols.min()) - 2, 0)
    crop = (seg.labels[r0 : int(rows.max()) + 3, c0 : int(cols.max()) + 3] == region_id).astype(np.uint8) * 255
    er, ec = np.nonzero(cv2.Canny(crop, 50, 150))
    if len(er) == 0:  # a region of a pixel or two: its pixels are its border
        er, ec = rows - r0, cols - c0
    edges = to_arena(np.stack([ec + c0 + 0.5, er + r0 + 0.5], axis=1), shape, 1.0)
    return RegionShape(centroid, area, len(rows), np.asarray(lab, float), (edges - centroid) / np.sqrt(area))


def signature(border: np.ndarray) -> np.ndarray:
    """r(phi): the largest radius of the border points in each polar-angle bin; empty bins interpolated."""
    phi = np.arctan2(border[:, 1], border[:, 0])
    idx = np.floor((phi + np.pi) / (2 * np.pi) * BINS).astype(int) % BINS
    sig = np.full(BINS, -1.0)
    np.maximum.at(sig, idx, np.hypot(border[:, 0], border[:, 1]))
    filled = np.flatnonzero(sig >= 0)
    return np.interp(np.arange(BINS), filled, sig[filled], period=BINS)


def _icp_rotation(a: np.ndarray, b: np.ndarray, theta: float, iters: int = 30) -> float:
    """Refine the rotation of a onto b (both centred) by ICP, leaving out pairs over 3 x the median apart."""
    tree = cKDTree(b)
    for _ in range(iters):
        c, s = np.cos(theta), np.sin(theta)
        p = a @ np.array([[c, s], [-s, c]])
        d, j = tree.query(p)
        keep = d <= 3.0 * np.median(d) + 1e-12
        p, q = p[keep], b[j[keep]]
        delta = float(np.arctan2(np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]), np.sum(p * q)))
        theta += delta
        if abs(delta) < 1e-7:
            break
    return theta


def estimate_motion(prev: RegionShape, cur: RegionShape) -> tuple[float, float, float]:
    """(rotation M_i^f, scale sqrt(A_f / A_{f-1}), border correlation -1..1) from frame f-1 to f. The half
    pixel a signature is known to counts in its variance: rasterisation noise on a round region is no match."""
    scale = float(np.sqrt(cur.area / prev.area))
    sa, sb = signature(prev.border), signature(cur.border)
    noise_a, noise_b = 0.5 / np.sqrt(prev.pixels), 0.5 / np.sqrt(cur.pixels)  # half a pixel
    round_a, round_b = sa.std() < noise_a, sb.std() < noise_b
    if round_a and round_b:
        return 0.0, scale, 1.0
    za = (sa - sa.mean()) / np.sqrt(sa.var() + noise_a**2)
    zb = (sb - sb.mean()) / np.sqrt(sb.var() + noise_b**2)
    corr = np.fft.ifft(np.conj(np.fft.fft(za)) * np.fft.fft(zb)).real / BINS  # corr[k] = mean za[b] zb[b+k]
    shifts = (np.arange(BINS) + BINS // 2) % BINS - BINS // 2
    turns = shifts * (2 * np.pi / BINS)
    k = int(np.argmax(corr - SMALL_TURN_PRIOR * np.abs(turns) / np.pi))
    c0, c1, c2 = corr[k - 1], corr[k], corr[(k + 1) % BINS]  # parabola through the peak: sub-bin shift
    bend = c0 - 2 * c1 + c2
    theta = turns[k] + (0.5 * (c0 - c2) / bend if bend < 0 else 0.0) * (2 * np.pi / BINS)
    refined = _icp_rotation(prev.border, cur.border, theta)
    if abs(refined - theta) <= ICP_REACH:
        theta = refined
    theta = float((theta + np.pi) % (2 * np.pi) - np.pi)
    return theta, scale, float(c1)


def fit_count(px: np.ndarray, n: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """R_i's N_i initial samples from its moved goals (pixels): those outside R_i dropped (on its border they
    would crowd), surplus ones one of the closest pair at a time, missing ones by farthest-point insertion."""
    pts = np.asarray(px, float).reshape(-1, 2)
    pts = pts[in_region(pts, rows, cols)] if len(pts) else pts
    while len(pts) > n:
        d, _ = cKDTree(pts).query(pts, k=2)
        pts = np.delete(pts, int(np.argmin(d[:, 1])), axis=0)
    if len(pts) < n:
        centres = np.stack([cols + 0.5, rows + 0.5], axis=1)
        if len(pts) == 0:  # start at the pixel nearest the centroid
            pts = centres[[int(np.argmin(np.hypot(*(centres - centres.mean(axis=0)).T)))]]
        gap, _ = cKDTree(pts).query(centres)
        added = [pts]
        for _ in range(n - len(pts)):
            i = int(np.argmax(gap))
            added.append(centres[i : i + 1])
            gap = np.minimum(gap, np.hypot(centres[:, 0] - centres[i, 0], centres[:, 1] - centres[i, 1]))
        pts = np.concatenate(added)
    return pts
