"""What a run on real robots reads from its tracker (sim.node.hardware): the contacts it sees (real robots report
none), and whether it is stuck."""

from __future__ import annotations

import numpy as np

from agent.core.params import EPUCK
from hardware.poses import PoseSample
from sim.node.hardware import FROZEN_AFTER, HardwareBodies


class Poses:
    """A pose source that hands out what the test puts in ``now``, each time a new measurement."""

    def __init__(self) -> None:
        self.now: dict[int, tuple[float, float]] = {}
        self.stamp = 0.0

    def latest(self) -> dict[int, PoseSample]:
        self.stamp += 0.1
        return {r: PoseSample(x, y, 0.0, self.stamp, 0.0) for r, (x, y) in self.now.items()}


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


def test_a_tracker_that_repeats_a_driven_robots_pose_bit_for_bit_stops_it_until_the_pose_moves():
    """A frozen stream (a held marker, a bridge repeating its last message) stamped anew would make a robot
    drive blind: believing it stands, it keeps driving, and the others avoid where it is not."""
    poses = Poses()
    bodies = HardwareBodies(drive=None, poses=poses, params=EPUCK, n=2, timeout=1.0)  # type: ignore[arg-type]
    poses.now = {0: (0.1, 0.2), 1: (0.5, 0.5)}
    for _ in range(2 * FROZEN_AFTER):  # standing robots' poses may repeat
        bodies.sense(0.0)
    assert bodies.tracked.all()
    bodies.wheels[:] = (0.5 * EPUCK.v_max, 0.5 * EPUCK.v_max)  # both driven; robot 1 moves, 0's pose is stuck
    for k in range(FROZEN_AFTER):
        assert bodies.tracked[0]
        poses.now[1] = (0.5 + 0.001 * k, 0.5)
        bodies.sense(0.0)
    assert not bodies.tracked[0] and bodies.tracked[1]
    bodies.wheels[0] = 0.0  # stopped as lost: still stuck while the pose does not move
    bodies.sense(0.0)
    assert not bodies.tracked[0]
    poses.now[0] = (0.1001, 0.2)  # the tracker sees it again
    bodies.sense(0.0)
    assert bodies.tracked.all()
