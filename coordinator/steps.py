"""Image sequences (paper 7.2, Fig. 12): a scene's ``[[steps]]`` (docs/scenes.md), each an image shown for
``hold`` seconds; every step's goal sets, for every robot count, share one arena K_r. Errors: GoalError."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .goals import GoalError
from .goals.defaults import METHODS
from .motion import StepMotion, check_keys, one_of, parse_motion, positive
from .shapes import SHAPES, draw

if TYPE_CHECKING:
    from .goals import GoalSet, PreparedImage

STEP_KEYS = ("name", "image", "shape", "hold", "region_counts", "method", "motion")
SHAPE_PIXELS = 256  # canvas side of the drawn shapes (goals live in the normalised square anyway)
SHAPE_ROBOTS = 1000  # robots a SHAPE_PIXELS canvas serves; more get a canvas with as many pixels per robot


def shape_pixels(robots: int) -> int:
    """Canvas side of a drawn shape for `robots`: beyond SHAPE_ROBOTS it grows, keeping the pixels per robot."""
    return max(SHAPE_PIXELS, math.ceil(SHAPE_PIXELS * math.sqrt(robots / SHAPE_ROBOTS)))


@dataclass(frozen=True)
class ImageStep:
    """One image of a sequence and how long it is shown."""

    name: str
    image: Path | None  # a picture file, or None for a drawn shape
    shape: str | None  # a name from coordinator.shapes.SHAPES
    hold: float  # seconds the image is shown
    region_counts: dict[int, int] | None = None  # the artist's N_i per region id
    method: str = "cvt"  # Lloyd with the density of eq. 2, or k-means
    motion: StepMotion | None = None  # a dynamic image (paper 7.4.1): the goal set moves (eq. 28)
    frame_period: float = 0.0  # an animation keyframe's K_f dt (paper 6.2, eq. 27); 0: not a keyframe
    keyframe: int | None = None  # an animation keyframe: its index (goals from coordinator.keyframe_steps)


def parse_step(data: Any, label: str, source: str = "") -> ImageStep:
    """An ImageStep from a TOML table; `label` names it in errors (e.g. "steps[2]")."""
    if not isinstance(data, dict):
        raise GoalError(f'{label} must be a table with shape = "name" or image = "path", and hold')
    check_keys(data, STEP_KEYS, label)
    hold = positive(data.get("hold"), f"{label}: hold")
    if ("image" in data) == ("shape" in data):
        raise GoalError(f'{label} needs exactly one of image = "path" or shape = "name"')
    image, shape = None, None
    if "shape" in data:
        shape = one_of(data["shape"], SHAPES, f"{label}: shape")
    else:
        image = scene_relative(str(data["image"]), source)
        if not image.is_file():
            raise GoalError(f"{label}: image {image} not found")
    method = one_of(data.get("method", "cvt"), METHODS, f"{label}: method")
    name = str(data.get("name", shape if shape is not None else image.stem))  # type: ignore[union-attr]  # image is set where shape is not
    motion = parse_motion(data["motion"], label) if "motion" in data else None
    return ImageStep(name, image, shape, hold, parse_region_counts(data.get("region_counts"), label), method, motion)


def scene_relative(path: str, source: str) -> Path:
    """A path that a scene names: a relative one is relative to the scene file (when there is one)."""
    p = Path(path)
    if not p.is_absolute() and Path(source).suffix == ".toml":
        p = Path(source).parent / p
    return p


def parse_region_counts(value: Any, label: str) -> dict[int, int] | None:
    """A scene's ``region_counts`` table (region id -> robots), checked; None when it has none."""
    if value is None:
        return None
    try:
        counts = {int(k): v for k, v in dict(value).items()}  # TOML keys are strings: { 0 = 10 }
    except (TypeError, ValueError):
        raise GoalError(f"{label}: region_counts must map region ids to robots, e.g. {{ 0 = 10, 1 = 4 }}") from None
    if not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in counts.values()):
        raise GoalError(f"{label}: region_counts values must be whole numbers of robots >= 0")
    return counts


def scale_region_counts(counts: Mapping[int, int] | None, full: int, n: int) -> dict[int, int] | None:
    """The artist's N_i for `full` robots scaled to n by largest remainder, keeping every region shown."""
    if counts is None or n == full:
        return None if counts is None else dict(counts)
    ids = sorted(counts)
    free = full - sum(counts.values())  # robots the allocator spreads over the regions not named
    wanted = np.array([counts[i] for i in ids] + [max(free, 0)], float)
    quota = wanted * n / max(wanted.sum(), 1.0)
    out = np.floor(quota).astype(int)
    order = np.lexsort((np.arange(len(quota)), -(quota - out)))  # largest remainder, ties to lower id
    out[order[: n - int(out.sum())]] += 1
    shown = wanted > 0
    if n >= int(shown.sum()):
        for j in np.flatnonzero(shown & (out == 0)):  # a region rounded away: take one from the fullest
            donor = int(np.argmax(np.where(out >= 2, out - quota, -np.inf)))
            out[donor] -= 1
            out[j] = 1
    return {i: int(c) for i, c in zip(ids, out[:-1])}


class GoalSets:
    """Goal sets of a scene's steps for 1..robots robots in one arena K_r: made by _made, cached, read-only."""

    STEP = "step"  # how errors name a step
    arena: float  # K_r, metres: set by each subclass

    def __init__(self, steps: int, robots: int, seed: int, radius: float, counts_for: int | None) -> None:
        self.step_count, self.robots, self.seed, self.radius = steps, robots, seed, radius
        self.counts_for = counts_for or robots  # the robot count the artist's region_counts were written for
        self._sets: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def goal_set(self, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Goals (n,2) in metres (arena frame, origin at the centre) and colours (n,3) uint8."""
        if not 0 <= step < self.step_count:
            raise GoalError(f"{self.STEP} {step} does not exist: there are {self.STEP}s 0..{self.step_count - 1}")
        if not 1 <= n <= self.robots:
            raise GoalError(f"goal sets exist for 1..{self.robots} robots, not {n}")
        if (step, n) not in self._sets:
            self._keep(step, n, *self._made(step, n))
        return self._sets[(step, n)]

    def _made(self, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _keep(self, step: int, n: int, goals: np.ndarray, colors: np.ndarray) -> None:
        goals, colors = np.array(goals, float), np.array(colors, np.uint8)
        goals.setflags(write=False)  # shared by every caller of the cache
        colors.setflags(write=False)
        self._sets[(step, n)] = goals, colors


class StepGoals(GoalSets):
    """The image steps' goal sets, seeded, in the shared arena K_r."""

    def __init__(
        self,
        steps: list[ImageStep],
        robots: int,
        seed: int,
        radius: float,
        arena: float | None = None,
        labels: list[str] | None = None,
        counts_for: int | None = None,
    ) -> None:
        super().__init__(len(steps), robots, seed, radius, counts_for)
        self.steps = steps
        self.labels = labels or [f"steps[{k}]" for k in range(len(steps))]  # how errors name each step
        self._prepared: dict[int, PreparedImage] = {}
        self.arena = float(arena) if arena is not None else self._shared_arena()

    def _made(self, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        gs = self._generate(step, n, self.arena)
        return gs.goals, gs.colors

    def _shared_arena(self) -> float:
        """K_r: the largest of the steps' own conservative arenas with all N robots."""
        own = {k: self._generate(k, self.robots, None) for k in range(len(self.steps))}
        shared = max(gs.arena for gs in own.values())
        for k, gs in own.items():
            self._keep(k, self.robots, gs.goals * (shared / gs.arena), gs.colors)  # goals scale linearly with K_r
        return shared

    def _generate(self, k: int, n: int, arena: float | None) -> GoalSet:
        from .goals import GoalOptions, goals_from_prepared, prepare_image  # the image pipeline: only where made

        step = self.steps[k]
        try:
            if k not in self._prepared:  # background and regions once per image, for every count
                source: Any = draw(step.shape, shape_pixels(self.robots)) if step.shape is not None else step.image
                self._prepared[k] = prepare_image(source)
            counts = scale_region_counts(step.region_counts, self.counts_for, n)
            options = GoalOptions(arena, step.method, self.seed, self.radius, counts)
            return goals_from_prepared(self._prepared[k], n, options)
        except GoalError as err:
            raise GoalError(f"{self.labels[k]} ({step.name}), {n} robots: {err}") from None
