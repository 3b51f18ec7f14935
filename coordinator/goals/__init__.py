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

if TYPE_CHECKING:  # the names __getattr__ imports on first use, for type checkers
    from .family import GoalFamily, goal_family  # noqa: F401
    from .pipeline import GoalOptions, PreparedImage, generate_goals, goals_from_prepared, prepare_image  # noqa: F401

# the pipeline's names: the module each comes from on first use
_PIPELINE = dict.fromkeys(("GoalFamily", "goal_family"), "family") | dict.fromkeys(
    ("GoalOptions", "PreparedImage", "generate_goals", "goals_from_prepared", "prepare_image"), "pipeline"
)
__all__ = ["IMAGE_SUFFIXES", "GoalError", "GoalSet", *_PIPELINE]


def __getattr__(name: str) -> Any:
    if name in _PIPELINE:
        return getattr(importlib.import_module(f".{_PIPELINE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
