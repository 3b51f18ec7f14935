"""Goal sets as tests and benchmarks read and weigh them: a goals.json read back, the cost of eq. 1 of any
generators, and goal-set families (paper 5.1.2, eq. 8: G_r for a range of robot counts r in one arena, so
the picture keeps its size when robots drop out or join; a run makes these through coordinator.steps.GoalSets)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coordinator.goals import GoalError, GoalSet
from coordinator.goals.cvt import Domain, _Assigner
from coordinator.goals.model import FORMAT, rescale
from coordinator.goals.pipeline import PAPER_OPTIONS, GoalOptions, goals_from_prepared, prepare_image

FAMILY_FORMAT = "pixelswarm.goal-family/1"


def goal_set_from_dict(data: dict[str, Any]) -> GoalSet:
    """A GoalSet from its to_dict() (a goals.json)."""
    if data.get("format", FORMAT) != FORMAT:
        raise ValueError(f"unsupported goal-set format {data.get('format')!r}")
    return GoalSet(  # __post_init__ makes the arrays
        data["goals"], data["colors"], data["regions"], data.get("cost_history", []), dict(data.get("params", {}))
    )


def goal_set_from_json(text: str) -> GoalSet:
    return goal_set_from_dict(json.loads(text))


def cvt_cost(domain: Domain, gen: np.ndarray, scale: float) -> float:
    """Cost of eq. 1 (divided by K_m, in units of Q whose side is `scale` pixels) of generators gen."""
    _, d2 = _Assigner(domain).assign(gen)
    return float(np.dot(domain.weights, d2)) / scale**4


@dataclass
class GoalFamily:
    """Goal sets keyed by their number of robots r (eq. 8)."""

    sets: dict[int, GoalSet] = field(default_factory=dict)

    @property
    def counts(self) -> list[int]:
        return sorted(self.sets)

    def for_robots(self, available: int) -> GoalSet:
        """The goal set for the most robots not exceeding `available`."""
        fitting = [r for r in self.sets if r <= available]
        if not fitting:
            raise GoalError(f"no goal set for {available} robots: the family starts at {min(self.sets)}")
        return self.sets[max(fitting)]

    def to_json(self, indent: int | None = None) -> str:
        return json.dumps(
            {"format": FAMILY_FORMAT, "sets": [self.sets[r].to_dict() for r in self.counts]}, indent=indent
        )

    @classmethod
    def from_json(cls, text: str) -> GoalFamily:
        data = json.loads(text)
        if data.get("format") != FAMILY_FORMAT:
            raise ValueError(f"unsupported goal-family format {data.get('format')!r}")
        sets = [goal_set_from_dict(d) for d in data["sets"]]
        return cls({len(s): s for s in sets})


def goal_family(
    image_or_path: str | os.PathLike[str] | np.ndarray, counts: Iterable[int], options: GoalOptions = PAPER_OPTIONS
) -> GoalFamily:
    """Goal sets for every robot count in `counts` in one arena (default: the most demanding set's)."""
    wanted = sorted({int(c) for c in counts})
    if not wanted:
        raise GoalError("a goal family needs at least one robot count")
    prep = prepare_image(image_or_path)
    sets = {r: goals_from_prepared(prep, r, options) for r in wanted}
    if options.arena is None:
        shared = max(s.arena for s in sets.values())  # each is its own conservative (auto) arena
        sets = {r: rescale(s, shared) for r, s in sets.items()}
    return GoalFamily(sets)
