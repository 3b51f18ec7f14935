"""Real robots report no contact: a run on hardware counts those its tracker sees (sim.node.hardware)."""

from __future__ import annotations

import numpy as np

from agent.core.params import EPUCK
from hardware.poses import PoseSample
from sim.node.hardware import HardwareBodies


class Poses:
    """A pose source that hands out what the test puts in ``now``."""

    def __init__(self) -> None:
        self.now: dict[int, tuple[float, float]] = {}

    def latest(self) -> dict[int, PoseSample]:
        return {r: PoseSample(x, y, 0.0, 0.0, 0.0) for r, (x, y) in self.now.items()}


def test_two_tracked_discs_overlapping_beyond_the_tracking_noise_are_one_contact_until_they_part():
    poses, r, noise = Poses(), EPUCK.radius, EPUCK.noise_bound
    bodies = HardwareBodies(drive=None, poses=poses, params=EPUCK, n=3, timeout=1.0)  # type: ignore[arg-type]

    def at(t: float, gap: float) -> list:  # robots 0 and 2 ``gap`` apart (negative: overlapping); 1 far off
        poses.now = {0: (0.0, 0.0), 1: (5.0, 5.0), 2: (2 * r + gap, 0.0)}
        bodies.sense(t)
        return bodies.step(0.1)

    assert at(0.0, 0.02) == [] and at(0.1, -0.5 * noise) == []  # as close as tracking noise explains
    (began,) = at(0.2, -2 * noise)
    assert (began.kind, began.i, began.j, began.t_start, began.t_end) == ("robot", 0, 2, 0.2, None)
    assert at(0.3, -3 * noise) == [] and np.isclose(began.max_depth, 3 * noise)  # the same contact, deeper
    assert at(0.4, 0.01) == [] and began.t_end == 0.4
    assert len(at(0.5, -2 * noise)) == 1 and len(bodies.contacts) == 2  # a second one
    poses.now.pop(2)  # a robot no longer tracked is in no contact
    bodies.sense(0.6)
    assert bodies.step(0.1) == [] and bodies.contacts[1].t_end == 0.6
