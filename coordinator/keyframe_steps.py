"""Animations in scenes (paper 6): the ``[animation]`` table (docs/scenes.md), one scene step per keyframe.
Keyframe f's robots reach its goals when f+1 begins (eq. 27); the first's K_f dt is `first_hold`, the
last's `frame_time`, then it is shown for `last_hold`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .drawings import KEYFRAME_ANIMATIONS, keyframes
from .goals import IMAGE_SUFFIXES, GoalError, GoalOptions
from .keyframes import KeyframeGoals, keyframe_goals, keyframe_paths
from .motion import check_keys, is_number, one_of, positive
from .steps import METHODS, GoalSets, ImageStep, parse_region_counts, scale_region_counts, scene_relative

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
    """An Animation from the [animation] table (paths relative to the scene file). GoalError (one line)."""
    if not isinstance(data, dict):
        raise GoalError('animation must be a table with keyframes = "name", "folder/" or ["a.png", ...]')
    check_keys(data, ANIMATION_KEYS, "animation")
    name, images = _keyframes(data.get("keyframes"), source, data.get("size", 256))
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
