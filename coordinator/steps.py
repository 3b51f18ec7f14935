"""Image sequences (paper 7.2, Fig. 12) and animations (paper 6) as scene steps (docs/scenes.md): a scene's
``[[steps]]``, each an image shown for ``hold`` seconds, or its ``[animation]``, one step per keyframe, whose
robots reach its goals when the next begins (eq. 27). Every step's goal sets, for every robot count, share one
arena K_r. Errors: GoalError."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .drawings import KEYFRAME_ANIMATIONS, SIZE, keyframes
from .goals import IMAGE_SUFFIXES, GoalError
from .goals.allocate import largest_remainder
from .goals.defaults import METHODS
from .motion import StepMotion, check_keys, is_number, one_of, parse_motion, positive
from .shapes import SHAPES, draw

if TYPE_CHECKING:
    from .goals import GoalSet, PreparedImage
    from .keyframes import KeyframeGoals

STEP_KEYS = ("name", "image", "shape", "hold", "region_counts", "method", "motion")
SHAPE_PIXELS = 256  # canvas side of the drawn shapes (goals live in the normalised square anyway)
SHAPE_ROBOTS = 1000  # robots a SHAPE_PIXELS canvas serves; more get a canvas with as many pixels per robot


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
    keyframe: int | None = None  # an animation keyframe: its index (goals from FrameGoals)


def parse_step(data: Any, label: str, source: str = "") -> ImageStep:
    """An ImageStep from a TOML table; `label` names it in errors (e.g. "steps[2]")."""
    if not isinstance(data, dict):
        raise GoalError(f'{label} must be a table with shape = "name" or image = "path", and hold')
    check_keys(data, STEP_KEYS, label)
    hold = positive(data.get("hold"), f"{label}: hold")
    if ("image" in data) == ("shape" in data):
        raise GoalError(f'{label} needs exactly one of image = "path" or shape = "name"')
    shape = one_of(data["shape"], SHAPES, f"{label}: shape") if "shape" in data else None
    image = scene_relative(str(data["image"]), source) if "image" in data else None
    if image is not None and not image.is_file():
        raise GoalError(f"{label}: image {image} not found")
    method = one_of(data.get("method", "cvt"), METHODS, f"{label}: method")
    name = str(data.get("name", shape if image is None else image.stem))
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
    shown = np.flatnonzero(wanted > 0)  # every region shown keeps a robot, if there are robots enough
    out = largest_remainder(wanted * n / max(wanted.sum(), 1.0), n, shown if n >= len(shown) else [])
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
                side = max(SHAPE_PIXELS, math.ceil(SHAPE_PIXELS * math.sqrt(self.robots / SHAPE_ROBOTS)))
                source: Any = draw(step.shape, side) if step.shape is not None else step.image
                self._prepared[k] = prepare_image(source)
            counts = scale_region_counts(step.region_counts, self.counts_for, n)
            options = GoalOptions(arena, step.method, self.seed, self.radius, counts)
            return goals_from_prepared(self._prepared[k], n, options)
        except GoalError as err:
            raise GoalError(f"{self.labels[k]} ({step.name}), {n} robots: {err}") from None


ANIMATION_KEYS = tuple(
    "keyframes frame_time first_hold last_hold times region_counts method keep_counts init_from_previous "
    "size arena".split()
)
DEFAULT_FRAME_TIME = 5.0  # s between keyframes: K_f = 50 control periods at 10 Hz
DEFAULT_FIRST_HOLD = 30.0  # s to form the first keyframe from the start layout (as an image step of Fig. 12)


@dataclass(frozen=True)
class Animation:
    """The keyframes of a scene and how their goal sets are made."""

    name: str
    images: tuple[Any, ...]  # RGB arrays (drawn) or image paths, in play order
    steps: tuple[ImageStep, ...]  # one per keyframe, with its hold and K_f dt
    region_counts: dict[int, int] | None = None
    method: str = "cvt"
    keep_counts: bool = False
    init_from_previous: bool = True
    arena: float | None = None  # K_r, metres; None: the largest conservative arena any keyframe needs


def parse_animation(data: Any, source: str = "") -> Animation:
    """An Animation from the [animation] table (paths relative to the scene file): the first keyframe's K_f dt is
    `first_hold`, the last's `frame_time`, then it is shown for `last_hold`. GoalError (one line)."""
    if not isinstance(data, dict):
        raise GoalError('animation must be a table with keyframes = "name", "folder/" or ["a.png", ...]')
    check_keys(data, ANIMATION_KEYS, "animation")
    name, images = _keyframes(data.get("keyframes"), source, data.get("size", SIZE))
    frame_time = positive(data.get("frame_time", DEFAULT_FRAME_TIME), "animation: frame_time")
    last_hold = positive(data.get("last_hold", frame_time), "animation: last_hold")
    if "times" in data:
        if "first_hold" in data:
            raise GoalError("animation: give either times or first_hold (times[1] is when the first keyframe ends)")
        starts = _times(data["times"], len(images))
    else:
        first = positive(data.get("first_hold", DEFAULT_FIRST_HOLD), "animation: first_hold")
        starts = [0.0] + [first + frame_time * f for f in range(len(images) - 1)]
    periods = [b - a for a, b in zip(starts, starts[1:])] + [frame_time]
    holds = periods[:-1] + [frame_time + last_hold]
    method = one_of(data.get("method", "cvt"), METHODS, "animation: method")
    steps = tuple(
        ImageStep(f"{name}[{f}]", None, None, hold, method=method, frame_period=period, keyframe=f)
        for f, (hold, period) in enumerate(zip(holds, periods))
    )
    return Animation(
        name,
        tuple(images),
        steps,
        parse_region_counts(data.get("region_counts"), "animation"),
        method,
        _flag(data.get("keep_counts", False), "keep_counts"),
        _flag(data.get("init_from_previous", True), "init_from_previous"),
        positive(data["arena"], "animation: arena", "metres") if "arena" in data else None,
    )


def _keyframes(value: Any, source: str, size: Any) -> tuple[str, list[Any]]:
    if isinstance(value, str) and value in KEYFRAME_ANIMATIONS:
        if not (isinstance(size, int) and not isinstance(size, bool) and 32 <= size <= 2048):
            raise GoalError(f"animation: size must be a whole number of pixels in 32..2048, not {size!r}")
        return value, keyframes(value, size)
    if isinstance(value, str):
        from .keyframes import keyframe_paths  # the image pipeline (OpenCV): only for a folder of keyframes

        folder = scene_relative(value, source)
        if not folder.is_dir():
            raise GoalError(
                f"animation: keyframes {value!r} is neither a drawn animation "
                f"({', '.join(KEYFRAME_ANIMATIONS)}) nor a folder"
            )
        return folder.name, list(keyframe_paths(folder))
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        paths = [scene_relative(v, source) for v in value]
        for p in paths:
            if p.suffix.lower() not in IMAGE_SUFFIXES or not p.is_file():
                raise GoalError(f"animation: keyframe {p} is not an image file ({', '.join(IMAGE_SUFFIXES)})")
        return paths[0].parent.name or "animation", paths
    raise GoalError(
        "animation: keyframes must be a drawn animation "
        f"({', '.join(KEYFRAME_ANIMATIONS)}), a folder, or a list of image files, not {value!r}"
    )


def _flag(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise GoalError(f"animation: {key} must be true or false, not {value!r}")
    return value


def _times(value: Any, frames: int) -> list[float]:
    if not (isinstance(value, list) and all(is_number(v) for v in value)) or len(value) != frames:
        raise GoalError(f"animation: times must list the start of each of the {frames} keyframes in seconds")
    starts = [float(v) for v in value]
    if starts[0] != 0.0 or any(b <= a for a, b in zip(starts, starts[1:])):
        raise GoalError("animation: times must begin at 0 and increase")
    return starts


class FrameGoals(GoalSets):
    """The keyframes' goal sets, generated with keyframe_goals, seeded, and all in one arena K_r."""

    STEP = "keyframe"

    def __init__(
        self,
        animation: Animation,
        robots: int,
        seed: int,
        radius: float,
        arena: float | None = None,
        counts_for: int | None = None,
    ) -> None:
        super().__init__(len(animation.steps), robots, seed, radius, counts_for)
        self.animation = animation
        self._keyframes: dict[int, KeyframeGoals] = {}
        arena = arena if arena is not None else animation.arena
        self.arena = float(arena) if arena is not None else self._generate(robots, None).arena

    def _made(self, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        kg = self._keyframes.get(n) or self._generate(n, self.arena)
        return kg.sets[step].goals, kg.sets[step].colors

    def _generate(self, n: int, arena: float | None) -> KeyframeGoals:
        from .goals import GoalOptions
        from .keyframes import keyframe_goals  # the image pipeline: only where made

        a = self.animation
        counts = scale_region_counts(a.region_counts, self.counts_for, n)
        try:
            options = GoalOptions(arena, a.method, self.seed, self.radius, counts)
            kg = keyframe_goals(
                list(a.images), n, options, init_from_previous=a.init_from_previous, keep_counts=a.keep_counts
            )
        except GoalError as err:
            raise GoalError(f"animation {a.name}, {n} robots: {err}") from None
        self._keyframes[n] = kg
        return kg
