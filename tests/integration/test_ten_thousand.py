"""Ten thousand robots in the central engine (issue 43), so the scale cannot silently break. With
every block agreed within its tick, the cold start of the paper's first image agrees one to one at
the first tick (the auction ranks each robot's goals by the goal tree, not over every goal); with
the scene's one round a tick, the robots start from the coordinator's warm start at the first tick
and its blocks span ticks. Either way every tick is one to one with no contact."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.central.engine import simulate
from sim.central.link import InProcessLink

TICKS = 30  # of the cold start, at the scene's control period of 0.1 s


@pytest.fixture(scope="module")
def ten_thousand():
    return load_scene("paper-sequence-10000", duration=TICKS * 0.1)  # its goal sets made once


@pytest.mark.slow
@pytest.mark.xdist_group("ten-thousand")
@pytest.mark.parametrize("rounds_per_tick", [0, 1], ids=["agreed-within-the-tick", "the-scene-s-one-round"])
def test_ten_thousand_robots_cold_start_one_to_one_without_contact(ten_thousand, rounds_per_tick: int) -> None:
    assert ten_thousand.robots == 10_000
    scene = replace(ten_thousand, robot={**ten_thousand.robot, "rounds_per_tick": rounds_per_tick})
    out = simulate(scene, link=InProcessLink(scene.robots), progress=None)
    assignment = out.arrays["assignment"]
    assert len(assignment) >= TICKS + 1, "fewer ticks than asked for: the control period changed"
    assert (assignment >= 0).all()  # the first tick's agreement or warm start: every robot has a goal
    for k, row in enumerate(assignment):
        assert len(np.unique(row)) == len(row), f"one goal, two robots, tick {k}"
    assert out.contacts == []
    assert len(np.unique(out.arrays["step"])) == 1  # the first image throughout: a cold start only
