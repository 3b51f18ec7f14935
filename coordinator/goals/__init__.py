"""Goal generation (paper section 4): an image becomes N goal positions and colours.

from coordinator.goals import GoalOptions, generate_goals
gs = generate_goals("logo.png", 50, GoalOptions(arena=2.0, seed=1))
gs.goals   # (50, 2) metres, arena frame (origin at the centre, y up)
gs.colors  # (50, 3) uint8

The image pipeline (OpenCV, the CVT) is imported on first use of its names: a process that only
reads a scene or a stored goal set (the world) never loads it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .model import IMAGE_SUFFIXES, GoalError, GoalSet

if TYPE_CHECKING:
    from .family import GoalFamily, goal_family
    from .pipeline import GoalOptions, PreparedImage, generate_goals, goals_from_prepared, prepare_image

_PIPELINE = {
    "GoalFamily": "family",
    "goal_family": "family",
    "GoalOptions": "pipeline",
    "PreparedImage": "pipeline",
    "generate_goals": "pipeline",
    "goals_from_prepared": "pipeline",
    "prepare_image": "pipeline",
}

__all__ = [
    "IMAGE_SUFFIXES",
    "GoalError",
    "GoalFamily",
    "GoalOptions",
    "GoalSet",
    "PreparedImage",
    "generate_goals",
    "goal_family",
    "goals_from_prepared",
    "prepare_image",
]


def __getattr__(name: str) -> Any:
    if name in _PIPELINE:
        return getattr(importlib.import_module(f".{_PIPELINE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
