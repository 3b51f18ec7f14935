"""The central engine runs a warm auction on a second thread while it steps the control core on the
goals the robots hold, and steps again only the robots whose goal the auction changed (agent.loop.tick,
``overlap``). That is a speed-up, not a different engine: a run must be the same to the bit as one
that waits for the auction before any control, on scenes where the auction does change goals (an
image sequence, animation keyframes with eq. 27's hold, a moving goal set)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import sim.central.engine as central
from agent import loop
from coordinator.scene import load_scene
from sim.central.stepclock import StepClock


def fast_turning_triangle(duration: float):
    """rotating-triangle turning eight times as fast as its robots can follow: goals are reassigned."""
    scene = load_scene("rotating-triangle", duration=duration)
    step = scene.steps[0]
    scene.steps[0] = dataclasses.replace(step, motion=dataclasses.replace(step.motion, angular_velocity=0.4))
    return scene


SCENES = {
    "image sequence, 100 robots": lambda: load_scene("paper-sequence-100", duration=27.0),  # changes at 25-26 s
    "keyframes held by eq. 27": lambda: load_scene("leaf", duration=5.0),
    "moving goal set (eq. 28), diffdrive": lambda: fast_turning_triangle(15.0),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if "100 robots" in n else n for n in SCENES])
def test_a_run_with_the_auction_beside_the_control_core_is_the_same_to_the_bit(tmp_path, monkeypatch, name):
    stepped_again: list[int] = []
    real = loop.step_again

    def spy(res, rows, *args):
        stepped_again.append(rows.size)
        return real(res, rows, *args)

    monkeypatch.setattr(loop, "step_again", spy)
    runs, clock = {}, StepClock()
    for overlap in (False, True):
        scene = SCENES[name]()
        runs[overlap] = central.run_central(
            scene,
            tmp_path / f"run-{overlap}",
            video=False,
            progress=None,
            overlap=overlap,
            clock=clock if overlap else None,
        )
    assert sum(stepped_again) > 0  # the auction did change goals while the control core ran on the old
    # the clock kept the auction's own time on the second thread and its bids: none at the cold start, some after
    assert clock.beside[0] == 0.0 and sum(clock.beside[1:]) > 0.0
    assert clock.bids[0] == 0 and sum(clock.bids[1:]) > 0 and sum(clock.reassigned) > 0
    waited, beside = (np.load(runs[o] / "trajectory.npz") for o in (False, True))
    assert sorted(waited.files) == sorted(beside.files)
    for key in waited.files:
        np.testing.assert_array_equal(waited[key], beside[key], err_msg=key)
    metrics = [json.loads((runs[o] / "metrics.json").read_text()) for o in (False, True)]
    for m in metrics:
        for timing in ("wall_s", "realtime_factor", "stepping_wall_s", "stepping_realtime_factor"):
            m.pop(timing)
    assert metrics[0] == metrics[1]
