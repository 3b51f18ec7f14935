"""Ten thousand robots in the central engine (issue 43), so the scale cannot silently break: the
cold start of the paper's first image agrees one to one at the first tick (the auction ranks each
robot's goals by the goal tree, not over every goal), and every tick after stays one to one with
no contact."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.central.engine import simulate
from sim.central.link import InProcessLink

TICKS = 30  # of the cold start, at the scene's control period of 0.1 s


@pytest.mark.slow
def test_ten_thousand_robots_cold_start_one_to_one_without_contact() -> None:
    scene = load_scene("paper-sequence-10000", duration=TICKS * 0.1)
    assert scene.robots == 10_000
    out = simulate(scene, link=InProcessLink(scene.robots), progress=None)
    assignment = out.arrays["assignment"]
    assert len(assignment) >= TICKS + 1, "fewer ticks than asked for: the control period changed"
    assert (assignment >= 0).all()  # the cold start agreed at the first tick: every robot has a goal
    for k, row in enumerate(assignment):
        assert len(np.unique(row)) == len(row), f"one goal, two robots, tick {k}"
    assert out.contacts == []
    assert len(np.unique(out.arrays["step"])) == 1  # the first image throughout: a cold start only
