"""Goal sets as tests and benchmarks read and weigh them: a goals.json read back, and the cost of eq. 1 of
any generators."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from coordinator.goals import GoalSet
from coordinator.goals.cvt import Domain, _Assigner
from coordinator.goals.model import FORMAT


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
