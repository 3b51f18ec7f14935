"""Goal generation for animations (paper 6.1): one goal set G_f per keyframe I_f, all in one arena K_r.
Regions of consecutive frames are paired (match_regions); G_{f-1} of a region, moved by T_i^f and M_i^f
(estimate_motion), starts frame f's Lloyd iterations unless it matches poorly or the region count changed
(then fresh random samples, 4.2). Angles: counter-clockwise, y up."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from .goals import IMAGE_SUFFIXES, GoalError, GoalOptions, GoalSet, PreparedImage, goals_from_prepared, prepare_image
from .goals.allocate import allocate_robots
from .goals.model import rescale
from .goals.pipeline import PAPER_OPTIONS
from .goals.resize import from_arena, to_arena
from .goals.sampling import in_region, pixel_centres
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
    pts = to_arena(pixel_centres(rows, cols), shape, 1.0)
    centroid = pts.mean(axis=0)
    area = len(rows) / side**2
    r0, c0 = max(int(rows.min()) - 2, 0), max(int(cols.min()) - 2, 0)
    crop = (seg.labels[r0 : int(rows.max()) + 3, c0 : int(cols.max()) + 3] == region_id).astype(np.uint8) * 255
    er, ec = np.nonzero(cv2.Canny(crop, 50, 150))
    if len(er) == 0:  # a region of a pixel or two: its pixels are its border
        er, ec = rows - r0, cols - c0
    edges = to_arena(pixel_centres(er + r0, ec + c0), shape, 1.0)
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
    pts = pts[in_region(pts, rows, cols)]
    while len(pts) > n:
        d, _ = cKDTree(pts).query(pts, k=2)
        pts = np.delete(pts, int(np.argmin(d[:, 1])), axis=0)
    if len(pts) < n:
        centres = pixel_centres(rows, cols)
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


# a Delta E of 25, a shift of a quarter of the image and an area ratio of 2 each cost 1
COLOR_SCALE, SHIFT_SCALE, AREA_SCALE = 25.0, 0.25, float(np.log(2.0))

ImageLike = np.ndarray | str | os.PathLike[str]


@dataclass
class RegionMotion:
    """How region R_i of frame f relates to its region in frame f-1 (paper 6.1)."""

    region: int  # R_i in frame f
    previous: int  # the corresponding region of frame f-1
    translation: tuple[float, float]  # T_i^f: centroid shift in metres (arena frame, y up)
    rotation: float  # M_i^f: turn in radians, counter-clockwise as seen
    scale: float  # sqrt of the area ratio A_f / A_{f-1}
    correlation: float  # match of the border features at the estimated rotation, -1..1
    initialised: bool  # G_{f-1} of this region started the Lloyd iterations


@dataclass
class FrameReport:
    """How frame f's goals were found: mode "first", "previous" (every region from G_{f-1}), "partial" or "fresh"."""

    frame: int
    mode: str
    reason: str
    regions: list[RegionMotion] = field(default_factory=list)
    iterations: int = 0
    seconds: float = 0.0


@dataclass
class KeyframeGoals:
    """Goal sets G_1..G_F of an animation in one arena, with a report per frame."""

    sets: list[GoalSet]
    reports: list[FrameReport]
    image_size: tuple[int, int]  # (width, height) in pixels

    @property
    def goals(self) -> np.ndarray:
        """(F, N, 2) goal positions in metres (arena frame: origin at the centre, y up)."""
        return np.stack([s.goals for s in self.sets])

    @property
    def colors(self) -> np.ndarray:
        """(F, N, 3) uint8 RGB goal colours."""
        return np.stack([s.colors for s in self.sets])

    @property
    def regions(self) -> np.ndarray:
        """(F, N) region id of each goal in its own frame's segmentation."""
        return np.stack([s.regions for s in self.sets])

    @property
    def arena(self) -> float:
        """K_r, the common side of the arena in metres."""
        return self.sets[0].arena

    @property
    def metres_per_pixel(self) -> float:
        """The common scale of every frame."""
        return self.arena / max(self.image_size)

    def disparities(self) -> np.ndarray:
        """(F-1,) goal_disparity between consecutive frames, in metres."""
        return np.array([goal_disparity(a.goals, b.goals) for a, b in zip(self.sets, self.sets[1:])])


def goal_disparity(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance between the goals of two sets matched by goal_correspondence (eq. 7)."""
    a, b = np.asarray(a, float).reshape(-1, 2), np.asarray(b, float).reshape(-1, 2)
    previous = goal_correspondence(a, b)
    return float(np.hypot(*(b - a[previous]).T).mean())


def goal_correspondence(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each goal of ``b``, its goal in ``a`` by the matching of least total squared distance (eq. 7)."""
    a, b = np.asarray(a, float).reshape(-1, 2), np.asarray(b, float).reshape(-1, 2)
    if len(a) != len(b) or len(a) == 0:
        raise GoalError(f"goal correspondence needs two non-empty goal sets of one size, not {len(a)} and {len(b)}")
    rows, cols = linear_sum_assignment(cdist(a, b, "sqeuclidean"))
    previous = np.empty(len(b), np.int64)
    previous[cols] = rows
    return previous


def keyframe_paths(folder: str | os.PathLike[str]) -> list[Path]:
    """The keyframe images of a folder, in file-name order. Raises GoalError if there are none."""
    root = Path(folder)
    if not root.is_dir():
        raise GoalError(f"keyframe folder {root} does not exist or is not a folder")
    paths = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise GoalError(f"keyframe folder {root} holds no image ({', '.join(IMAGE_SUFFIXES)})")
    return paths


def match_regions(prev: Sequence[RegionShape], cur: Sequence[RegionShape]) -> list[int]:
    """For each region of the current frame, its region in the previous one (least cost of colour, shift, area)."""
    if len(prev) != len(cur):
        raise ValueError("match_regions needs two frames with the same number of regions")
    cost = (
        cdist([c.lab for c in cur], [p.lab for p in prev]) / COLOR_SCALE
        + cdist([c.centroid for c in cur], [p.centroid for p in prev]) / SHIFT_SCALE
        + np.abs(np.log(np.divide.outer([c.area for c in cur], [p.area for p in prev]))) / AREA_SCALE
    )
    _, cols = linear_sum_assignment(cost)  # square: every row, in order
    return [int(c) for c in cols]


def _initial_samples(
    prep: PreparedImage,
    shapes: list[RegionShape],
    prev_shapes: list[RegionShape],
    match: list[int],
    prev_set: GoalSet,
    counts: np.ndarray,
    min_correlation: float,
) -> tuple[dict[int, np.ndarray], list[RegionMotion], str]:
    """Initial samples (pixels) per region of frame f, G_{f-1} moved by T_i^f and M_i^f; the motions; poor matches."""
    prev_goals = prev_set.goals / prev_set.arena  # normalised arena frame, like the region shapes
    init: dict[int, np.ndarray] = {}
    motions, poor = [], []
    for rid, pid in enumerate(match):
        cur, old = shapes[rid], prev_shapes[pid]
        rotation, scale, corr = estimate_motion(old, cur)
        pts = prev_goals[prev_set.regions == pid]
        if corr < min_correlation:
            poor.append(f"region {rid} (border correlation {corr:.2f} < {min_correlation:g})")
        elif counts[rid] > 0 and len(pts) > 0:
            c, s = np.cos(rotation), np.sin(rotation)
            # spacing follows the area per goal A_i / N_i: the region's growth, less what N_i changed by
            spread = scale * np.sqrt(len(pts) / counts[rid])
            m = np.array([[c, -s], [s, c]]) * spread  # M_i^f
            moved = (pts - old.centroid) @ m.T + cur.centroid  # M_i^f about the centroid, then T_i^f
            init[rid] = fit_count(from_arena(moved, prep.shape, 1.0), int(counts[rid]), *prep.seg.pixels(rid))
        shift = cur.centroid - old.centroid  # T_i^f, in units of the image's longer side for now
        motions.append(RegionMotion(rid, pid, (float(shift[0]), float(shift[1])), rotation, scale, corr, rid in init))
    return init, motions, ("poor match of " + ", ".join(poor)) if poor else ""


def _load(images: Sequence[ImageLike] | str | os.PathLike[str]) -> list[PreparedImage]:
    if isinstance(images, (str, os.PathLike)):
        images = keyframe_paths(images)
    if len(images) == 0:
        raise GoalError("an animation needs at least one keyframe")
    preps = []
    for k, img in enumerate(images):
        try:
            preps.append(prepare_image(img))
        except GoalError as err:
            raise GoalError(f"keyframe {k}: {err}") from None
    if len({p.shape for p in preps}) > 1:
        sizes = ", ".join(sorted({f"{p.shape[1]}x{p.shape[0]}" for p in preps}))
        raise GoalError(f"keyframes must all have one size in pixels, got {sizes}")
    return preps


def keyframe_goals(
    images: Sequence[ImageLike] | str | os.PathLike[str],
    n: int,
    options: GoalOptions = PAPER_OPTIONS,
    *,
    init_from_previous: bool = True,
    keep_counts: bool = False,
    min_correlation: float = MIN_CORRELATION,
) -> KeyframeGoals:
    """N goals per keyframe I_1..I_F (paper 6.1) of one size in pixels (arrays, paths or a folder), in one
    arena. keep_counts: a region keeps its previous N_i (robots stay in their region); frame f uses seed + f.
    Raises GoalError on bad input."""
    options.check(n)  # before the keyframes are read
    preps = _load(images)
    matching = init_from_previous or keep_counts
    shapes: list[list[RegionShape]] = []
    sets: list[GoalSet] = []
    reports: list[FrameReport] = []
    for f, prep in enumerate(preps):
        t0 = time.perf_counter()
        match, reason = None, "first keyframe"
        if matching:
            shapes.append([region_shape(prep.seg, r.id, r.lab) for r in prep.seg.regions])
            if f > 0 and len(shapes[f]) != len(shapes[f - 1]):
                reason = f"the number of regions changed from {len(shapes[f - 1])} to {len(shapes[f])}"
            elif f > 0:
                match = match_regions(shapes[f - 1], shapes[f])
        counts = options.region_counts
        if keep_counts and match is not None:  # N_i of each region's match in frame f-1, if every region has room
            carried = {rid: int(np.sum(sets[-1].regions == pid)) for rid, pid in enumerate(match)}
            counts = carried if all(carried[r.id] <= r.area for r in prep.seg.regions) else counts
        init: dict[int, np.ndarray] = {}
        motions: list[RegionMotion] = []
        if f > 0 and not init_from_previous:
            reason = "init_from_previous is off"
        elif match is not None:
            n_i, _ = allocate_robots([r.area for r in prep.seg.regions], int(n), counts)
            init, motions, reason = _initial_samples(
                prep, shapes[f], shapes[f - 1], match, sets[-1], n_i, min_correlation
            )
        try:
            gs = goals_from_prepared(prep, n, replace(options, seed=options.seed + f, region_counts=counts), init)
        except GoalError as err:
            raise GoalError(f"keyframe {f}: {err}") from None
        reports.append(_frame_report(f, gs, motions, reason, time.perf_counter() - t0))
        sets.append(gs)
    shared = float(options.arena) if options.arena is not None else max(s.arena for s in sets)
    for r in reports:  # the translations in metres of the shared arena
        r.regions = [replace(m, translation=(m.translation[0] * shared, m.translation[1] * shared)) for m in r.regions]
    return KeyframeGoals([rescale(s, shared) for s in sets], reports, (preps[0].shape[1], preps[0].shape[0]))


def _frame_report(f: int, gs: GoalSet, motions: list[RegionMotion], reason: str, seconds: float) -> FrameReport:
    """Frame f's report: its mode says whether its regions started from G_{f-1} moved."""
    done = {m.region for m in motions if m.initialised}
    used = {int(r) for r in np.unique(gs.regions)}
    mode = "first" if f == 0 else "fresh" if not done else "previous" if done >= used else "partial"
    return FrameReport(f, mode, reason, motions, int(gs.params["iterations"]), seconds)
