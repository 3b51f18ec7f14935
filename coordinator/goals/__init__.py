"""Goal generation (paper section 4): an image becomes N goal positions and colours.

The pipeline's names (OpenCV, the CVT) are imported on first use, so a process that only reads a scene
or a stored goal set (the world) never loads them."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .model import IMAGE_SUFFIXES, GoalError, GoalSet

if TYPE_CHECKING:  # the names __getattr__ imports on first use, for type checkers
    from .pipeline import GoalOptions, PreparedImage, generate_goals, goals_from_prepared, prepare_image  # noqa: F401

_PIPELINE = ("GoalOptions", "PreparedImage", "generate_goals", "goals_from_prepared", "prepare_image")
__all__ = ["IMAGE_SUFFIXES", "GoalError", "GoalSet", *_PIPELINE]


def __getattr__(name: str) -> Any:
    if name in _PIPELINE:
        return getattr(importlib.import_module(".pipeline", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
