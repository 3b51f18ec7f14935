"""Goal generation (paper section 4): an image becomes N goal positions and colours.

from coordinator.goals import generate_goals
gs = generate_goals("logo.png", 50, arena=2.0, seed=1)
gs.goals   # (50, 2) metres, arena frame (origin at the centre, y up)
gs.colors  # (50, 3) uint8
"""

from .family import GoalFamily, goal_family
from .image import IMAGE_SUFFIXES
from .model import GoalError, GoalSet
from .pipeline import PreparedImage, generate_goals, goals_from_prepared, prepare_image

__all__ = [
    "IMAGE_SUFFIXES",
    "GoalError",
    "GoalFamily",
    "GoalSet",
    "PreparedImage",
    "generate_goals",
    "goal_family",
    "goals_from_prepared",
    "prepare_image",
]
