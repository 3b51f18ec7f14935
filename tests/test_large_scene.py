"""The shipped 1000-robot scene (paper 7.5, Fig. 12 bottom row) is the paper's sequence at 1000 robots.
Running it takes the central engine tens of minutes on 2 cores: bench/bench_large.py is its check;
this only checks the scene itself (a few seconds)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from coordinator.scene import load_scene, scene_goal_set


def colour_counts(colors: np.ndarray) -> dict[tuple[int, ...], int]:
    values, counts = np.unique(colors, axis=0, return_counts=True)
    return {tuple(int(c) for c in v): int(n) for v, n in zip(values, counts)}


def test_paper_sequence_1000_is_the_paper_sequence_with_1000_robots():
    big, small = load_scene("paper-sequence-1000"), load_scene("paper-sequence")
    assert big.robots == 1000 and big.robot["kinematics"] == "holonomic"
    assert [s.name for s in big.steps] == [s.name for s in small.steps]
    assert [s.shape for s in big.steps] == [s.shape for s in small.steps]
    r = big.radius
    for k in range(len(big.steps)):
        goals, colors = scene_goal_set(big, k, big.robots)
        assert goals.shape == (1000, 2)
        # every goal fits a robot (the conservative arena keeps them 4 r apart, CVT aside)
        d, _ = cKDTree(goals).query(goals, k=2)
        assert d[:, 1].min() >= 2 * r
        # the regions' shares are the 14-robot sequence's (10 + 4, 6 + 8), to within one robot in 1000
        big_counts = colour_counts(colors)
        small_counts = colour_counts(scene_goal_set(small, k, small.robots)[1])
        assert big_counts.keys() == small_counts.keys()
        for colour, n in small_counts.items():
            assert abs(big_counts[colour] - 1000 * n / 14) <= 1, (big.steps[k].name, colour)
    # the robots start on a grid inside the arena, clear of each other
    xmin, ymin, xmax, ymax = big.arena
    assert np.all((big.poses[:, 0] > xmin + r) & (big.poses[:, 0] < xmax - r))
    assert np.all((big.poses[:, 1] > ymin + r) & (big.poses[:, 1] < ymax - r))
