"""The shipped 1000- and 10,000-robot scenes (paper 7.5, Fig. 12 bottom row) are the paper's sequence at
1000 and 10,000 robots. Running them takes the central engine minutes on 2 cores: bench/bench_large.py is
their check; this only checks the scenes themselves (a few seconds each)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from scipy.spatial import cKDTree

from coordinator.goals.resize import auto_arena
from coordinator.scene import load_scene, parse_scene, scene_goal_set
from sim.cli import main as cli


def colour_counts(colors: np.ndarray) -> dict[tuple[int, ...], int]:
    values, counts = np.unique(colors, axis=0, return_counts=True)
    return {tuple(int(c) for c in v): int(n) for v, n in zip(values, counts)}


@pytest.mark.parametrize("robots", [1000, pytest.param(10000, marks=pytest.mark.slow)])  # 10,000: goals for seconds
def test_paper_sequence_at_scale_is_the_paper_sequence_with_that_many_robots(robots):
    big, small = load_scene(f"paper-sequence-{robots}"), load_scene("paper-sequence")
    assert big.robots == robots and big.robot["kinematics"] == "holonomic"
    assert big.poses.shape == (robots, 3)  # (test_shipped_scenes_load's check of this scene)
    assert [s.name for s in big.steps] == [s.name for s in small.steps]
    assert [s.shape for s in big.steps] == [s.shape for s in small.steps]
    r = big.radius
    k_r = big.image_goals.arena
    own = []
    for k in range(len(big.steps)):
        goals, colors = scene_goal_set(big, k, big.robots)
        assert goals.shape == (robots, 2)
        # every goal fits a robot: two robots' width apart (the conservative arena aims at 4 r, CVT aside)
        d, _ = cKDTree(goals).query(goals, k=2)
        assert d[:, 1].min() >= 2 * r
        own.append(auto_arena(d[:, 1].min() / k_r, r))  # the arena this image alone would ask for
        # the regions' shares are the 14-robot sequence's (10 + 4, 6 + 8), to within one robot
        big_counts = colour_counts(colors)
        small_counts = colour_counts(scene_goal_set(small, k, small.robots)[1])
        assert big_counts.keys() == small_counts.keys()
        for colour, n in small_counts.items():
            assert abs(big_counts[colour] - robots * n / 14) <= 1, (big.steps[k].name, colour)
    # the paper's rule (4.4): one arena K_r for every image, the conservative 2 K_r of the closest goals
    # of the image that needs the most
    assert k_r == pytest.approx(max(own), rel=1e-9)
    # the robots start on a grid inside the arena, clear of each other
    xmin, ymin, xmax, ymax = big.arena
    assert np.all((big.poses[:, 0] > xmin + r) & (big.poses[:, 0] < xmax - r))
    assert np.all((big.poses[:, 1] > ymin + r) & (big.poses[:, 1] < ymax - r))
    d, _ = cKDTree(big.poses[:, :2]).query(big.poses[:, :2], k=2)
    assert d[:, 1].min() > 2 * r


def test_goal_sets_that_take_a_while_are_said_before_and_after(monkeypatch):
    """`pixelswarm run` says what it is doing once the goal sets take GOALS_SAID_AFTER, and nothing
    when they are quick (a refused scene stays one line)."""
    said = io.StringIO()
    monkeypatch.setattr(cli, "GOALS_SAID_AFTER", 0.0)
    scene = cli._make_goal_sets(parse_scene("paper-sequence"), said)
    assert scene.image_goals is not None
    lines = said.getvalue().splitlines()
    assert lines[0] == "[paper-sequence] 14 robots: making the goals of 6 images (segmentation, CVT)"
    assert lines[1].startswith("[paper-sequence] goals of 6 images made in ") and len(lines) == 2
    quiet = io.StringIO()
    monkeypatch.setattr(cli, "GOALS_SAID_AFTER", 60.0)
    cli._make_goal_sets(parse_scene("paper-sequence"), quiet)
    assert quiet.getvalue() == ""
