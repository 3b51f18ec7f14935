"""Dynamic images (paper 7.4.1): the ``[steps.motion]`` table, parsed and bounded (the robots move their
goals themselves, eq. 28); also the checks of scene values that steps, animations and scenes share."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeGuard

import numpy as np

from .goals import GoalError

MOTION_KEYS = ("velocity", "angular_velocity", "center", "expansion", "expansion_kind")
EXPANSION_KINDS = ("linear", "geometric")


@dataclass(frozen=True)
class StepMotion:
    """A goal set's constant motion and deformation (eq. 28), as the scene gives it."""

    velocity: tuple[float, float] = (0.0, 0.0)  # v_G, m/s
    angular_velocity: float = 0.0  # omega_G, rad/s, counter-clockwise about the centre
    center: tuple[float, float] = (0.0, 0.0)  # p_OG at the step's start, m
    expansion: float = 0.0  # K_eG, 1/s: > 0 grows, < 0 shrinks
    expansion_kind: str = "linear"  # s(t) = 1 + K_eG t, or "geometric": s(t) = (1 + K_eG)^t

    @property
    def geometric(self) -> bool:
        return self.expansion_kind == "geometric"

    def scale(self, t: float) -> float:
        """s(t) of eq. 28."""
        if self.geometric:
            return (1.0 + self.expansion) ** t
        return 1.0 + self.expansion * t

    def swept_box(self, goals: np.ndarray, duration: float) -> np.ndarray:
        """Corners (2,2) of a box holding the goal set for t in [0, duration] (s(t) is monotonic, any rotation)."""
        centre = np.asarray(self.center, float)
        reach = float(np.max(np.hypot(*(np.asarray(goals, float) - centre).T), initial=0.0))
        reach *= max(self.scale(0.0), self.scale(duration))
        ends = np.array([centre, centre + duration * np.asarray(self.velocity, float)])
        return np.array([ends.min(axis=0) - reach, ends.max(axis=0) + reach])


def parse_motion(data: Any, label: str) -> StepMotion:
    """A StepMotion from a TOML table. Raises GoalError (one line)."""
    if not isinstance(data, dict):
        raise GoalError(f"{label}.motion must be a table (keys: {', '.join(MOTION_KEYS)})")
    check_keys(data, MOTION_KEYS, f"{label}.motion")
    velocity = _pair(data.get("velocity", [0.0, 0.0]), f"{label}.motion.velocity", "[vx, vy] in m/s")
    center = _pair(data.get("center", [0.0, 0.0]), f"{label}.motion.center", "[x, y] in metres")
    omega = _number(data.get("angular_velocity", 0.0), f"{label}.motion.angular_velocity", "rad/s")
    expansion = _number(data.get("expansion", 0.0), f"{label}.motion.expansion", "per second")
    kind = one_of(data.get("expansion_kind", "linear"), EXPANSION_KINDS, f"{label}.motion.expansion_kind")
    if kind == "geometric" and expansion <= -1.0:
        raise GoalError(f"{label}.motion.expansion must be > -1 for a geometric expansion, not {expansion}")
    return StepMotion(velocity, omega, center, expansion, kind)


def check_window(motion: StepMotion, label: str, duration: float) -> None:
    """GoalError if a linear contraction shrinks the pattern to nothing within `duration` seconds."""
    if not motion.geometric and motion.expansion < 0 and motion.scale(duration) <= 0.0:
        raise GoalError(
            f"{label}.motion: a linear contraction of {motion.expansion}/s shrinks the pattern to "
            f"nothing after {-1.0 / motion.expansion:.1f} s, within the {duration:.1f} s it is shown"
        )


def check_keys(data: dict[str, Any], allowed: tuple[str, ...], label: str) -> None:
    """GoalError naming the keys of a scene table that are not ``allowed``."""
    if unknown := set(data) - set(allowed):
        raise GoalError(f"{label}: unknown key(s) {', '.join(sorted(unknown))} (allowed: {', '.join(allowed)})")


def is_number(value: Any) -> TypeGuard[float]:
    """A finite int or float (TOML's true and false are not numbers)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def is_positive(value: Any) -> TypeGuard[float]:
    """A finite number > 0."""
    return is_number(value) and value > 0


def positive(value: Any, label: str, unit: str = "seconds") -> float:
    """``value`` as a float if it is a positive number, else GoalError."""
    if not is_positive(value):
        raise GoalError(f"{label} must be a positive number of {unit}, not {value!r}")
    return float(value)


def one_of(value: Any, choices: tuple[str, ...], label: str) -> Any:
    """``value`` if it is one of ``choices``, else GoalError."""
    if value not in choices:
        raise GoalError(f"{label} must be one of {', '.join(choices)}, not {value!r}")
    return value


def _number(value: Any, label: str, unit: str) -> float:
    if not is_number(value):
        raise GoalError(f"{label} must be a number ({unit}), not {value!r}")
    return float(value)


def _pair(value: Any, label: str, what: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2):
        raise GoalError(f"{label} must be {what}, not {value!r}")
    return (_number(value[0], label, what), _number(value[1], label, what))
