"""Goal generation end to end (paper section 4): image -> regions R_i -> N_i per region -> initial
samples (K_s) -> Lloyd iterations (CVT with the mass density of eq. 2, or k-means) -> colours -> arena."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from transport import epuck
from transport.codec import MAX_ROBOTS

from .allocate import allocate_robots
from .colors import cell_colors, voronoi_cells
from .cvt import K_D, K_M, binary_domain, density_domain, lloyd
from .defaults import MAX_ITER, METHODS, RELAX, TOLERANCE
from .image import BG_TOLERANCE, Foreground, foreground_mask, load_image, split_channels
from .model import GoalError, GoalSet, min_distance
from .resize import auto_arena, check_feasible, to_arena
from .sampling import KS_FACTOR, in_region, ks_distance, lattice_samples, pixel_centres, poisson_samples
from .segment import Segmentation, segment, speck_area

MAX_SIDE = 1024  # longer image side (pixels) used for goal generation; larger images are scaled down
PAPER_SAMPLES_MAX = 1000  # larger regions start from a hexagonal lattice, not the paper's random samples
MIN_PIXELS_PER_GOAL = 3  # below it goals snap to pixel centres: the picture is scaled up (each pixel k x k)
MAX_UPSCALED_SIDE = 2 * MAX_SIDE


@dataclass
class PreparedImage:
    """An image after background subtraction and segmentation; reusable for several N."""

    rgb: np.ndarray
    foreground: Foreground  # the background subtraction: where an alpha channel counts
    seg: Segmentation
    source: str

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.rgb.shape[0]), int(self.rgb.shape[1]))

    @property
    def scale(self) -> float:
        """Pixels per unit of the normalised square Q (the longer image side)."""
        return float(max(self.shape))


@dataclass(frozen=True)
class GoalOptions:
    """How goals are made from an image (paper section 4)."""

    arena: float | None = None  # K_r in metres; None: the conservative 2 K_r, rounded up to a centimetre
    method: str = "cvt"  # Lloyd with the mass density of eq. 2, or "kmeans" (binary density)
    seed: int = 0  # of the random initial samples (4.2)
    robot_radius: float = epuck.RADIUS
    region_counts: Mapping[int, int] | None = None  # the artist's N_i per region id (largest region first)
    conservative: bool = False  # with an explicit arena, require 2 K_r rather than K_r
    tol: float = TOLERANCE  # tol, max_iter, relax: see cvt.lloyd
    max_iter: int = MAX_ITER
    relax: float = RELAX

    def check(self, n: Any) -> None:
        """GoalError (one line) unless these options can make n goals."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
            raise GoalError(f"N must be an integer, not {n!r}")
        if not 1 <= n <= MAX_ROBOTS:
            raise GoalError(f"N must be from 1 to {MAX_ROBOTS} (robot ids are 16-bit on the bus), not {n}")
        if self.method not in METHODS:
            raise GoalError(f"method must be one of {', '.join(METHODS)}, not {self.method!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise GoalError(f"seed must be a non-negative integer, not {self.seed!r}")
        if self.arena is not None and not (np.isfinite(self.arena) and self.arena > 0):
            raise GoalError(f"arena must be a positive size in metres, not {self.arena!r}")
        if not (np.isfinite(self.robot_radius) and self.robot_radius > 0):
            raise GoalError(f"robot radius must be a positive length in metres, not {self.robot_radius!r}")
        if not (self.tol > 0) or self.max_iter < 1 or not (1.0 <= self.relax <= 4.0):
            raise GoalError("the Lloyd settings need tol > 0, max_iter >= 1 and 1 <= relax <= 4")


# the paper's settings, the default of every goal maker, but Lloyd steps over-relaxed (cvt.lloyd: the cost
# never rises) and, past PAPER_SAMPLES_MAX goals in a region, a lattice start
PAPER_OPTIONS = GoalOptions()


def _shrink(rgb: np.ndarray, alpha: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None, str | None]:
    h, w = rgb.shape[:2]
    if max(h, w) <= MAX_SIDE:
        return rgb, alpha, None
    k = MAX_SIDE / max(h, w)
    size = (max(1, round(w * k)), max(1, round(h * k)))
    small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    a = None if alpha is None else cv2.resize(alpha, size, interpolation=cv2.INTER_AREA)
    return small, a, f"image scaled from {w}x{h} to {size[0]}x{size[1]} pixels for goal generation"


def prepare_image(
    image: str | os.PathLike[str] | np.ndarray, *, background: Any = None, min_area: int | None = None
) -> PreparedImage:
    """Load (path, or an RGB/RGBA/gray array), subtract the background and segment into regions R_i; an
    image larger than MAX_SIDE is scaled down first (goals live in the normalised square)."""
    if isinstance(image, np.ndarray):
        (rgb, alpha), source = split_channels(image), "<array>"
    else:
        (rgb, alpha), source = load_image(image), os.fspath(image)
    rgb, alpha, scaled = _shrink(rgb, alpha)
    fg = foreground_mask(rgb, alpha, background=background)
    seg = segment(fg.work, fg.mask, min_area=min_area)
    if scaled:
        seg.notes.insert(0, scaled)
    if not seg.regions:
        how = {
            "alpha": "every pixel is transparent",
            "color": f"every pixel is within {BG_TOLERANCE:g} of the background colour",
        }.get(fg.source, "the image is a single background colour")
        if fg.mask.any():
            how = f"its only foreground is specks smaller than {speck_area(fg.mask.shape, min_area)} pixels"
        raise GoalError(f"no foreground in {source}: {how}")
    return PreparedImage(rgb, fg, seg, source)


def _snap_inside(gen: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, int]:
    """Move generators outside R_i (a concavity or hole) into its nearest pixel with no other generator near."""
    out_idx = np.nonzero(~in_region(gen, rows, cols))[0]
    if len(out_idx) == 0:
        return gen, 0
    out = gen.copy()
    centres = pixel_centres(rows, cols)
    tree = cKDTree(centres)
    for j in out_idx:
        others = np.delete(out, j, axis=0)
        _, near = tree.query(out[j], k=min(len(centres), 64))
        for i in np.atleast_1d(near):
            cand = np.clip(out[j], centres[i] - 0.49, centres[i] + 0.49)
            if len(others) == 0 or np.min(np.hypot(*(others - cand).T)) >= 1.0:
                break
        out[j] = cand
    return out, len(out_idx)


def _enlarged(prep: PreparedImage, counts: np.ndarray) -> tuple[PreparedImage, int]:
    """prep, or prep with each pixel made k x k (and k) if a region has under MIN_PIXELS_PER_GOAL pixels a goal."""
    tight = min((r.area / c for r, c in zip(prep.seg.regions, counts) if c > 0), default=math.inf)
    if tight >= MIN_PIXELS_PER_GOAL:
        return prep, 1
    k = min(math.ceil(math.sqrt(MIN_PIXELS_PER_GOAL / tight)), MAX_UPSCALED_SIDE // max(prep.shape))
    if k < 2:
        return prep, 1

    def up(a: np.ndarray) -> np.ndarray:
        return np.repeat(np.repeat(a, k, axis=0), k, axis=1)

    regions = [replace(r, area=r.area * k * k) for r in prep.seg.regions]
    seg = Segmentation(up(prep.seg.labels), regions, list(prep.seg.notes))
    return replace(prep, rgb=up(prep.rgb), seg=seg), k


def _check_init(init: Mapping[int, np.ndarray] | None, counts: np.ndarray) -> dict[int, np.ndarray]:
    """The caller's initial samples per region id, checked: N_i finite (x, y) pixel positions each."""
    out: dict[int, np.ndarray] = {}
    for rid, pts in (init or {}).items():
        if not 0 <= int(rid) < len(counts):
            raise GoalError(f"initial samples name region {rid}, but the image has regions 0..{len(counts) - 1}")
        a = np.asarray(pts, dtype=float)
        if a.ndim != 2 or a.shape[1] != 2 or len(a) != counts[int(rid)] or not np.isfinite(a).all():
            raise GoalError(
                f"region {rid} needs {int(counts[int(rid)])} finite initial samples (x, y), "
                f"got an array of shape {a.shape}"
            )
        if len(np.unique(a, axis=0)) < len(a):  # two generators on one point would stay together
            raise GoalError(f"initial samples of region {rid} coincide")
        out[int(rid)] = a
    return out


def goals_from_prepared(
    prep: PreparedImage, n: int, options: GoalOptions = PAPER_OPTIONS, init: Mapping[int, np.ndarray] | None = None
) -> GoalSet:
    """N goals for a prepared image; see generate_goals."""
    options.check(n)
    counts, notes = allocate_robots([r.area for r in prep.seg.regions], int(n), options.region_counts)
    notes = list(prep.seg.notes) + notes
    given = _check_init(init, counts)
    shown, (prep, k) = prep, _enlarged(prep, counts)
    if k > 1:
        notes.append(f"image scaled up {k} x: under {MIN_PIXELS_PER_GOAL} pixels a goal, goals snap to pixels")
        given = {rid: pts * k for rid, pts in given.items()}
    if given:
        notes.append(f"initial samples of region(s) {', '.join(map(str, sorted(given)))} given by the caller")
    goals_px, goal_regions, history, ks_used = _lloyd_regions(prep, counts, given, options, notes)
    seg = prep.seg
    cells = voronoi_cells(seg, goals_px, goal_regions)
    colors = cell_colors(prep.rgb, cells, len(goals_px), goals_px, seg.labels)
    d_min = min_distance(goals_px) / prep.scale  # in Q
    if options.arena is None:
        arena = auto_arena(d_min, options.robot_radius)
    else:
        arena = float(options.arena)
        check_feasible(d_min, int(n), arena, options.robot_radius, options.conservative)
    params: dict[str, Any] = {
        "n": int(n),
        "arena": float(arena),
        "arena_auto": options.arena is None,
        **_options_record(options),
        **_image_record(prep, shown),
        "regions": [
            {
                "id": r.id,
                "color": list(r.color),
                "area_px": r.area,
                "robots": int(c),
                "k_s": round(ks_used.get(r.id, 0.0) * float(arena), 6),
            }
            for r, c in zip(seg.regions, counts)
        ],
        "iterations": max(len(history) - 1, 0),
        "cost": "eq. 1 / K_m in the normalised square Q (longer image side = 1)",
        "min_spacing": float(d_min * arena) if np.isfinite(d_min) else None,
        "notes": notes,
    }
    return GoalSet(to_arena(goals_px, prep.shape, float(arena)), colors, goal_regions, history, params)


def _lloyd_regions(
    prep: PreparedImage, counts: np.ndarray, given: dict[int, np.ndarray], options: GoalOptions, notes: list[str]
) -> tuple[np.ndarray, np.ndarray, list[float], dict[int, float]]:
    """Each region's N_i goals in pixels (4.2-4.3), region ids, summed cost per iteration, K_s per region."""
    seg, scale = prep.seg, prep.scale
    goals, regions, histories, ks_used = [], [], [], {}
    lattice: list[int] = []  # regions whose initial samples are a lattice
    snapped = snapped_init = 0
    for region, n_i in zip(seg.regions, counts):
        if n_i == 0:
            continue
        if n_i > region.area:
            raise GoalError(
                f"region {region.id} has {region.area} pixels, too few for {n_i} goals: "
                "use a larger image or fewer robots"
            )
        rows, cols = seg.pixels(region.id)
        start, ks, how, moved = _initial_samples(region, int(n_i), rows, cols, given, options.seed)
        ks_used[region.id], snapped_init = ks / scale, snapped_init + moved
        if how == "lattice":
            lattice.append(region.id)
        elif ks < ks_distance(region.area, int(n_i)) * (1 - 1e-9):
            notes.append(
                f"region {region.id} is too thin for K_s: initial samples used K_s "
                f"{ks / ks_distance(region.area, int(n_i)):.2f} x 1.2 sqrt(A_i/(pi N_i))"
            )
        domain = density_domain(rows, cols) if options.method == "cvt" else binary_domain(rows, cols)
        gen, hist = lloyd(domain, start, scale, tol=options.tol, max_iter=options.max_iter, relax=options.relax)
        gen, moved = _snap_inside(gen, rows, cols)
        snapped += moved
        goals.append(gen)
        regions.append(np.full(len(gen), region.id))
        histories.append(hist)
    if lattice:
        notes.append(
            f"region(s) {', '.join(map(str, lattice))} of more than {PAPER_SAMPLES_MAX} goals: initial samples "
            "on a hexagonal lattice"
        )
    if snapped_init:
        notes.append(f"{snapped_init} given initial sample(s) lay outside their region and were moved into it")
    if snapped:
        notes.append(f"{snapped} goal(s) ended in a concavity or hole and were moved into their region")
    length = max(len(h) for h in histories)  # the total cost per iteration: a converged region keeps its last
    total = np.array([h + [h[-1]] * (length - len(h)) for h in histories]).sum(axis=0).tolist()
    return np.concatenate(goals), np.concatenate(regions), total, ks_used


def _initial_samples(
    region: Any, n_i: int, rows: np.ndarray, cols: np.ndarray, given: dict[int, np.ndarray], seed: int
) -> tuple[np.ndarray, float, str, int]:
    """R_i's initial samples, their K_s (pixels), their kind and how many given ones were moved inside R_i."""
    paper_ks = ks_distance(region.area, n_i)
    if region.id in given:
        # generators outside R_i could sit outside the Lloyd domain with an empty cell for ever
        start, moved = _snap_inside(given[region.id], rows, cols)
        return start, paper_ks, "given", moved
    rng = np.random.default_rng([int(seed), region.id])
    if n_i > PAPER_SAMPLES_MAX:
        return lattice_samples(rows, cols, n_i, rng), paper_ks, "lattice", 0
    start, ks = poisson_samples(rows, cols, n_i, rng)
    return start, ks, "paper", 0


def _options_record(options: GoalOptions) -> dict[str, Any]:
    cvt = options.method == "cvt"
    return {
        "method": options.method,
        "seed": int(options.seed),
        "robot_radius": float(options.robot_radius),
        "conservative": bool(options.conservative),
        "k_s_factor": KS_FACTOR,
        "k_m": K_M if cvt else None,
        "k_d": K_D if cvt else None,
        "tol": options.tol,
        "max_iter": options.max_iter,
        "relax": options.relax,
    }


def _image_record(prep: PreparedImage, shown: PreparedImage) -> dict[str, Any]:
    """The image as given (``shown``, before any scaling up) and its background."""
    fg = prep.foreground
    return {
        "image": prep.source,
        "image_size": [shown.shape[1], shown.shape[0]],
        "background": {
            "source": fg.source,
            "color": list(fg.background) if fg.background else None,
            "tolerance": round(float(fg.tolerance), 3),
        },
    }


def generate_goals(
    image_or_path: str | os.PathLike[str] | np.ndarray,
    n: int,
    options: GoalOptions = PAPER_OPTIONS,
    *,
    init: Mapping[int, np.ndarray] | None = None,
) -> GoalSet:
    """N goal positions and colours that represent an image (paper section 4). init: {region id: (N_i, 2)
    pixel positions} replacing the random samples of 4.2 (paper 6.1: the previous keyframe's). GoalError."""
    return goals_from_prepared(prepare_image(image_or_path), n, options, init)
