"""An image displayed by the central engine: goals from the picture, re-assigned every iteration
by the auction (paper 5.1), LEDs in the goals' colours. The distributed auction is issue 5."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.core.params import EPUCK
from coordinator import shapes
from tests.conftest import run_pixelswarm


@pytest.mark.slow
def test_disk_and_line_shown_by_14_robots(tmp_path):
    image = tmp_path / "disk_and_line.png"
    cv2.imwrite(str(image), shapes.draw("disk_and_line", 256)[:, :, ::-1])
    out = tmp_path / "run"
    result = run_pixelswarm(
        "run",
        str(image),
        "--robots",
        "14",
        "--engine",
        "central",
        "--out",
        str(out),
        "--no-video",
        "--no-plots",
        "-q",
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    m = json.loads((out / "metrics.json").read_text())
    traj = np.load(out / "trajectory.npz")
    assert m["converged"] and m["contacts"] == 0
    assignment, goal, pose, color = traj["assignment"], traj["goal"], traj["pose"], traj["color"]
    for a in assignment[1:]:
        assert sorted(a.tolist()) == list(range(14))  # one robot per goal, every iteration
    # the first assignment is near the optimum on the same positions (noise and hysteresis aside)
    goals_by_index = np.empty((14, 2))
    goals_by_index[assignment[1]] = goal[1]
    cost = ((pose[1, :, None, :2] - goals_by_index[None]) ** 2).sum(-1)
    r, c = linear_sum_assignment(cost)
    ours = cost[np.arange(14), assignment[1]].sum()
    assert ours <= cost[r, c].sum() + 14 * (EPUCK.assign_eps + EPUCK.assign_hysteresis)
    # LEDs: red on the disk, blue on the line (the picture's colours)
    final = color[-1].astype(int)
    assert (final[:, 0] > 150).sum() >= 9 and (final[:, 2] > 150).sum() >= 2


@pytest.mark.slow
def test_any_image_displays_with_the_distributed_engine_by_default(tmp_path):
    """`pixelswarm run picture.png --robots N`: no scene file, the robots' own auction, LEDs in the
    picture's colours."""
    image = tmp_path / "two.png"
    cv2.imwrite(str(image), shapes.draw("two_squares", 128)[:, :, ::-1])
    out = tmp_path / "run"
    result = run_pixelswarm(
        "run", str(image), "--robots", "6", "--out", str(out), "--no-video", "--no-plots", "-q", timeout=300
    )
    assert result.returncode == 0, result.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["engine"] == "distributed" and metrics["contacts"] == 0
    assert metrics["steps"][0]["max_goal_error_at_end"] <= 0.01
    traj = np.load(out / "trajectory.npz")
    last = len(traj["t"]) - 1
    goal = traj["assignment"][last]
    assert sorted(goal.tolist()) == list(range(6))  # one robot per goal, as the agents announced
    row = list(traj["goal_set_epochs"]).index(int(traj["assignment_epoch"][last, 0]))
    assert np.array_equal(traj["color"][last], traj["goal_set_colors"][row][goal])
    assert {tuple(c) for c in traj["color"][last]} == {shapes.RED, shapes.BLUE}
