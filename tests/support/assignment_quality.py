"""Checks of the agents' agreed assignments, from a run's trajectory.npz: the optimum is computed
here, by scipy, never by the system under test."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment


@dataclass
class Agreement:
    epoch: int
    instance: int
    announced: dict[int, int]  # robot -> goal, as the robots announced it
    members: list[int]  # the robots of the goal set
    cost: float = np.nan
    optimum: float = np.nan
    penalties: float = 0.0  # the members' deadlock penalties in force (m^2): the auction's costs exceed
    # squared distance by at most this much, so the agreed cost may exceed the optimum by it too


@dataclass
class Report:
    agreements: list[Agreement] = field(default_factory=list)
    inconsistent: int = 0  # a robot announced two goals for one instance
    shared_goals: int = 0  # agreements in which two robots announced one goal
    incomplete: int = 0  # agreements that some member never announced (superseded at once)

    def gaps(self) -> np.ndarray:
        return np.array([a.cost - a.optimum for a in self.agreements if np.isfinite(a.cost)])


def agreements(npz: dict) -> Report:
    """Every (goal set, instance) some robot announced, with its cost and scipy's optimum on the
    positions the robots bid from."""
    rep = Report()
    epochs = list(npz["goal_set_epochs"])
    assign, ep, inst = npz["assignment"], npz["assignment_epoch"], npz["assignment_instance"]
    for a, (e, k) in enumerate(npz["agreements"]):
        mask = (ep == e) & (inst == k)
        announced: dict[int, int] = {}
        for t, r in zip(*np.nonzero(mask)):
            g = int(assign[t, r])
            if announced.setdefault(int(r), g) != g:
                rep.inconsistent += 1
        row = epochs.index(e)
        members = [int(r) for r in np.flatnonzero(npz["goal_set_robots"][row])]
        ag = Agreement(int(e), int(k), announced, members)
        if len(set(announced.values())) < len(announced):
            rep.shared_goals += 1
        goals = npz["goal_sets"][row]
        goals = goals[np.isfinite(goals).all(axis=1)]
        pos = npz["agreement_positions"][a]
        if set(announced) != set(members) or not np.isfinite(pos[members]).all():
            rep.incomplete += 1
        else:
            p = pos[members]
            cost = ((p[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
            rows, cols = linear_sum_assignment(cost)
            ag.optimum = float(cost[rows, cols].sum())
            ag.cost = float(sum(cost[i, announced[r]] for i, r in enumerate(members)))
            ag.penalties = float(np.nansum(npz["agreement_penalties"][a][members]))
        rep.agreements.append(ag)
    return rep


def optimum(positions: np.ndarray, goals: np.ndarray) -> float:
    cost = ((positions[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].sum())


EPS_A = 1e-3  # m^2, the default epsilon_A (agent.core.params)


def assert_agreements_valid(traj: dict, bound_per_robot: float = EPS_A, min_complete: int = 10) -> np.ndarray:
    rep = agreements(traj)
    assert rep.inconsistent == 0, "a robot announced two goals for one agreed instance"
    assert rep.shared_goals == 0, "two robots announced the same goal in one agreed instance"
    complete = [a for a in rep.agreements if np.isfinite(a.cost)]
    assert len(complete) >= min_complete
    for a in complete:
        assert a.cost <= a.optimum + len(a.members) * bound_per_robot + a.penalties + 1e-6, (a.epoch, a.instance)
    return rep.gaps()
