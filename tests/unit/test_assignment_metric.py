"""A run reports, per image, what the robots' assignment cost over the optimum (issue 23's report)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.outputs.metrics import assignment_over_optimum
from sim.study.report import flatten


def test_the_optimal_assignment_costs_nothing_over_and_a_swapped_one_its_excess():
    pose = np.zeros((2, 2, 3))
    pose[:, 0, :2], pose[:, 1, :2] = (0.0, 0.0), (1.0, 0.0)
    goals = np.array([[0.0, 1.0], [1.0, 1.0]])
    step = np.array([0, 1])
    assignment = np.array([[0, 1], [1, 0]])  # image 0 optimal, image 1 crossed
    goal = goals[assignment]
    over = assignment_over_optimum(pose, goal, assignment, step)
    assert over[0] == pytest.approx(0.0)
    assert over[1] == pytest.approx((1 + 1 + 1 + 1) - (1 + 1))  # two diagonals (2 m^2 each) against two unit legs


def test_a_tick_with_two_robots_on_one_goal_has_no_figure():
    pose = np.zeros((1, 2, 3))
    assignment = np.array([[0, 0]])
    assert assignment_over_optimum(pose, np.zeros((1, 2, 2)), assignment, np.array([0])) == [None]


def test_a_goal_index_the_goal_set_does_not_have_gives_no_figure():
    """A damaged state's goal index (a faulty peer on the bus) is no assignment, not a crash."""
    pose = np.zeros((1, 2, 3))
    assignment = np.array([[0, 12807]])
    assert assignment_over_optimum(pose, np.zeros((1, 2, 2)), assignment, np.array([0])) == [None]


def test_runs_csv_gets_a_column_per_image_and_figure():
    row = flatten({"steps": [{"converged_at": 8.5, "assignment_over_optimum_m2": 0.0}, {"converged_at": None}]})
    assert row == {"steps.0.converged_at": 8.5, "steps.0.assignment_over_optimum_m2": 0.0, "steps.1.converged_at": None}


def test_above_the_optimums_bound_a_run_says_none(monkeypatch):
    """scipy's optimum at thousands of robots takes minutes; past OPTIMUM_UP_TO the run leaves it out."""
    import sim.outputs.metrics

    pose = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    goal = np.array([[[1.0, 0.0], [0.0, 0.0]]])
    assignment = np.array([[0, 1]])
    assert assignment_over_optimum(pose, goal, assignment, np.array([0])) == [pytest.approx(2.0)]  # crossed
    monkeypatch.setattr(sim.outputs.metrics, "OPTIMUM_UP_TO", 1)
    assert assignment_over_optimum(pose, goal, assignment, np.array([0])) == [None]
