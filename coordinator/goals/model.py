"""The result of goal generation (a goal set G of paper 4.4) and the error it raises."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

FORMAT = "pixelswarm.goals/1"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")  # the files load_image reads


class GoalError(ValueError):
    """Bad input to goal generation; the message is one line meant for the user."""


@dataclass
class GoalSet:
    """N goal positions and colours representing an image.

    goals: (N, 2) metres in the arena frame (origin at the arena's centre, x right, y up).
    colors: (N, 3) uint8 RGB, the representative colour of each goal's Voronoi cell.
    regions: (N,) region id R_i of each goal (0 is the largest region).
    cost_history: total cost of eq. 1 (divided by K_m, in normalised units) after each Lloyd iteration.
    params: the parameters used (n, arena, method, seed, robot_radius, ...) and notes.
    """

    goals: np.ndarray
    colors: np.ndarray
    regions: np.ndarray
    cost_history: list[float] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)

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
        if len(self.goals) < 2:
            return float("inf")
        # here only: every process that reads a goal set (a run's coordinator) would load SciPy for it
        from scipy.spatial import cKDTree

        d, _ = cKDTree(self.goals).query(self.goals, k=2)
        return float(d[:, 1].min())

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

    def to_json(self, indent: int | None = None) -> str:
        """JSON text; with indent, one goal (colour, ...) per line."""
        data = self.to_dict()
        if indent is None:
            return json.dumps(data)
        pad = " " * indent
        lines = []
        for key, value in data.items():
            if isinstance(value, list) and value and isinstance(value[0], list):
                rows = (",\n" + pad * 2).join(json.dumps(v) for v in value)
                text = f"[\n{pad * 2}{rows}\n{pad}]"
            else:
                text = json.dumps(value, indent=indent).replace("\n", "\n" + pad)
            lines.append(f"{pad}{json.dumps(key)}: {text}")
        return "{\n" + ",\n".join(lines) + "\n}"

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GoalSet:
        if data.get("format", FORMAT) != FORMAT:
            raise ValueError(f"unsupported goal-set format {data.get('format')!r}")
        # __post_init__ makes the arrays
        return cls(
            data["goals"], data["colors"], data["regions"], data.get("cost_history", []), dict(data.get("params", {}))
        )

    @classmethod
    def from_json(cls, text: str) -> GoalSet:
        return cls.from_dict(json.loads(text))
