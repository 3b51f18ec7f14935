"""control_step of one robot (an agent process) and of a batch (an agent host, the central engine)
give the same bits: a robot's step reads its own row only."""

from __future__ import annotations

import numpy as np
import pytest

from agent.core.params import DIFFDRIVE, HOLONOMIC, RobotParams
from agent.core.step import NeighbourStates, OwnStates, Surroundings, control_step, static_segments

FIELDS = ("velocity", "command", "pref_velocity", "fallback")


def crowd(rng: np.random.Generator, b: int, m: int) -> tuple:
    """B robots with M neighbours each: some overlapping, stale, invalid (NaN), not cooperating; some
    robots barely moving toward a far goal (blocked), some without a goal."""
    position = rng.uniform(-0.8, 0.8, (b, 2))
    ang = rng.uniform(0, 2 * np.pi, (b, m))
    dist = rng.uniform(0.05, 0.5, (b, m))
    at = position[:, None, :] + np.stack([dist * np.cos(ang), dist * np.sin(ang)], axis=-1)
    vel, radius, age = (
        rng.normal(0, 0.06, (b, m, 2)),
        rng.uniform(0.03, 0.05, (b, m)),
        rng.choice([-0.05, 0.05, 0.2, 0.8], (b, m)),
    )
    valid, cooperative = rng.random((b, m)) < 0.85, rng.random((b, m)) < 0.9
    at[~valid & (rng.random((b, m)) < 0.5)] = np.nan
    nb = NeighbourStates.padded(at, vel, radius, age, valid, cooperative)
    velocity = rng.normal(0, 0.05, (b, 2))
    velocity[rng.random(b) < 0.3] *= 0.01
    goal = rng.uniform(-1.5, 1.5, (b, 2))
    goal[rng.random(b) < 0.1] = np.nan
    return rng.integers(0, 1000, b), position, rng.uniform(-np.pi, np.pi, b), velocity, goal, nb


@pytest.mark.parametrize("kinematics", [HOLONOMIC, DIFFDRIVE])
@pytest.mark.parametrize("walls", [False, True])
@pytest.mark.parametrize("given", [False, True])
def test_a_batch_gives_each_robot_the_bits_it_gets_alone(kinematics, walls, given):
    rng = np.random.default_rng([walls, given, kinematics == DIFFDRIVE])
    b, m = 40, 8
    ids, position, heading, velocity, goal, nb = crowd(rng, b, m)
    segments = (
        static_segments((-1.0, -1.0, 1.0, 1.0), [[(0.1, 0.1), (0.3, 0.1), (0.3, 0.3), (0.1, 0.3)]]) if walls else None
    )
    preferred = None
    if given:
        preferred = rng.uniform(-0.12, 0.12, (b, 2))
        preferred[rng.random(b) < 0.5] = np.nan
    params = RobotParams(kinematics=kinematics)
    around = Surroundings(segments, seed=5, tick=11)
    full = control_step(params, OwnStates(ids, position, heading, velocity, goal, preferred), nb, around)
    assert full.fallback.any() and not full.fallback.all()  # both the program and its fallback ran
    for i in range(b):
        row = slice(i, i + 1)
        own = OwnStates(
            ids[row],
            position[row],
            heading[row],
            velocity[row],
            goal[row],
            None if preferred is None else preferred[row],
        )
        one = control_step(params, own, nb.rows(row), around)
        for f in FIELDS:
            assert getattr(one, f)[0].tobytes() == getattr(full, f)[i].tobytes(), (i, f)


@pytest.mark.parametrize("kinematics", [HOLONOMIC, DIFFDRIVE])
def test_threads_sharing_a_batch_give_the_bits_of_one(kinematics):
    """The central engine shares its batch's rows among its cores: the same bits as one thread."""
    rng = np.random.default_rng(kinematics == DIFFDRIVE)
    b, m = 400, 8
    ids, position, heading, velocity, goal, nb = crowd(rng, b, m)
    segments = static_segments((-1.0, -1.0, 1.0, 1.0), [])
    own = OwnStates(ids, position, heading, velocity, goal)
    params = RobotParams(kinematics=kinematics)
    one, shared = (
        control_step(params, own, nb, Surroundings(segments, seed=5, tick=11, threads=threads)) for threads in (1, 4)
    )
    assert one.fallback.any() and not one.fallback.all()
    for f in FIELDS:
        assert getattr(one, f).tobytes() == getattr(shared, f).tobytes(), f
