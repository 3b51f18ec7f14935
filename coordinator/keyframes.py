"""Goal generation for animations (paper 6.1): one goal set G_f per keyframe I_f, all in one arena K_r.

Regions of consecutive frames are paired on colour, centroid shift and area ratio together; G_{f-1} of a
region, moved by its T_i^f and M_i^f and scaled with the area per goal, starts frame f's Lloyd iterations,
unless it matches poorly or the region count changed (then fresh random samples, 4.2).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from .goals import IMAGE_SUFFIXES, GoalError, GoalOptions, GoalSet, PreparedImage, goals_from_prepared, prepare_image
from .goals.allocate import allocate_robots
from .goals.family import rescale
from .goals.pipeline import PAPER_OPTIONS
from .goals.resize import from_arena
from .keyframe_motion import MIN_CORRELATION, RegionShape, estimate_motion, fit_count, region_shape

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
    cost = np.zeros((len(cur), len(prev)))
    for i, c in enumerate(cur):
        for j, p in enumerate(prev):
            cost[i, j] = (
                np.linalg.norm(c.lab - p.lab) / COLOR_SCALE
                + np.linalg.norm(c.centroid - p.centroid) / SHIFT_SCALE
                + abs(np.log(c.area / p.area)) / AREA_SCALE
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


def _carried_counts(prep: PreparedImage, match: list[int], prev_set: GoalSet) -> dict[int, int] | None:
    """N_i of each region's corresponding region in frame f-1, if every region has room for them."""
    carried = {rid: int(np.sum(prev_set.regions == pid)) for rid, pid in enumerate(match)}
    return carried if all(carried[r.id] <= r.area for r in prep.seg.regions) else None


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


def _match_previous(shapes: list[list[RegionShape]], reason: str) -> tuple[list[int] | None, str]:
    """The newest keyframe's regions matched to the previous one's (None and why not, if they cannot be)."""
    if len(shapes) < 2:
        return None, reason
    if len(shapes[-1]) != len(shapes[-2]):
        return None, f"the number of regions changed from {len(shapes[-2])} to {len(shapes[-1])}"
    return match_regions(shapes[-2], shapes[-1]), reason


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
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise GoalError(f"N must be a whole number of robots, at least 1, not {n!r}")
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
            match, reason = _match_previous(shapes, reason)
        counts = options.region_counts
        if keep_counts and match is not None:
            counts = _carried_counts(prep, match, sets[-1]) or options.region_counts
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
