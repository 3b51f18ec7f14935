"""The result of goal generation (a goal set G of paper 4.4) and the error it raises."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

FORMAT = "pixelswarm.goals/1"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")  # the files load_image reads


class GoalError(ValueError):
    """Bad input to goal generation; the message is one line meant for the user."""


@dataclass
class GoalSet:
    """N goal positions and colours representing an image."""

    goals: np.ndarray  # (N, 2) metres in the arena frame (origin at its centre, x right, y up)
    colors: np.ndarray  # (N, 3) uint8 RGB, the colour of each goal's Voronoi cell
    regions: np.ndarray  # (N,) region id R_i of each goal (0: the largest)
    cost_history: list[float] = field(default_factory=list)  # eq. 1 / K_m after each Lloyd iteration
    params: dict[str, Any] = field(default_factory=dict)  # the parameters used (n, arena, method, ...) and notes

    def __post_init__(self) -> None:
        self.goals = np.asarray(self.goals, dtype=float).reshape(-1, 2)
        self.colors = np.asarray(self.colors, dtype=np.uint8).reshape(-1, 3)
        self.regions = np.asarray(self.regions, dtype=int).reshape(-1)
        n = len(self.goals)
        if len(self.colors) != n or len(self.regions) != n:
            raise ValueError("goals, colors and regions must have the same length")
        self.cost_history = [float(c) for c in self.cost_history]

    def __len__(self) -> int:
        return len(self.goals)

    @property
    def arena(self) -> float:
        """K_r, the side of the square display arena in metres."""
        return float(self.params["arena"])

    def min_spacing(self) -> float:
        """Smallest distance between two goals, in metres (inf for fewer than two goals)."""
        return min_distance(self.goals)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "frame": "arena: metres, origin at the arena's centre, x right, y up",
            "goals": np.round(self.goals, 6).tolist(),
            "colors": self.colors.astype(int).tolist(),
            "regions": self.regions.tolist(),
            "cost_history": self.cost_history,
            "params": self.params,
        }

    def to_json(self, indent: int = 1) -> str:
        """JSON text (goals.json), one goal (colour, ...) per line."""
        pad = " " * indent
        lines = []
        for key, value in self.to_dict().items():
            if isinstance(value, list) and value and isinstance(value[0], list):
                rows = (",\n" + pad * 2).join(json.dumps(v) for v in value)
                text = f"[\n{pad * 2}{rows}\n{pad}]"
            else:
                text = json.dumps(value, indent=indent).replace("\n", "\n" + pad)
            lines.append(f"{pad}{json.dumps(key)}: {text}")
        return "{\n" + ",\n".join(lines) + "\n}"


def min_distance(points: np.ndarray) -> float:
    """Smallest distance between two of the points (inf for fewer than two)."""
    if len(points) < 2:
        return math.inf
    from scipy.spatial import cKDTree  # here only: a run's coordinator reads goal sets without SciPy

    d, _ = cKDTree(points).query(points, k=2)
    return float(d[:, 1].min())


def rescale(gs: GoalSet, arena: float) -> GoalSet:
    """The same goals in an arena of another size (goals scale linearly with K_r)."""
    k = arena / gs.arena
    params = dict(gs.params, arena=float(arena))
    if params.get("min_spacing") is not None:
        params["min_spacing"] = params["min_spacing"] * k
    params["regions"] = [dict(r, k_s=r["k_s"] * k) for r in params.get("regions", [])]
    return GoalSet(gs.goals * k, gs.colors, gs.regions, gs.cost_history, params)
