"""Over a limited communication range a robot drives no faster than lets two robots meeting head-on
still keep apart after they first hear of each other (agent.core.policy.heard_speed_limit): a
longer range or fresher states allow more speed, and impairment costs time, never contact."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from agent.core.params import EPUCK, HOLONOMIC, RobotParams
from agent.core.policy import Decision, Memory, Surroundings, act, heard_speed_limit, intend
from agent.core.step import NeighbourStates
from coordinator.scene import load_scene
from sim.central.engine import simulate
from sim.central.link import InProcessLink

PARAMS = replace(EPUCK, kinematics=HOLONOMIC)


def test_two_robots_at_the_limit_still_have_their_gap_when_they_hear_each_other():
    reach = 0.3
    for latency in (0.1, 0.3, 0.6):
        v = float(heard_speed_limit(PARAMS, reach, np.array([latency]))[0])
        # heard at distance reach (as sent), latency later; a tick more to react, both at v
        closed = 2 * v * (latency + 2 * PARAMS.dt)
        assert reach - closed >= 2 * PARAMS.radius + PARAMS.noise_bound - 1e-12
    assert heard_speed_limit(PARAMS, 0.5, np.array([0.1])) > heard_speed_limit(PARAMS, 0.3, np.array([0.1]))
    assert heard_speed_limit(PARAMS, 0.3, np.array([0.1])) > heard_speed_limit(PARAMS, 0.3, np.array([0.5]))
    assert heard_speed_limit(PARAMS, 2 * PARAMS.radius, np.array([0.1])) == 0.0  # cannot hear in time: stand


def _decide(reach: float, memory: Memory) -> Decision:
    position = np.array([[0.0, 0.0]])
    goal = np.array([[2.0, 0.0]])
    intent = intend(PARAMS, position, 0.0, goal, np.array([[0, -1]]), {}, memory)
    d = act(
        PARAMS,
        np.array([0]),
        position,
        np.zeros(1),
        intent,
        memory,
        NeighbourStates.empty(1),
        Surroundings(None, seed=1, tick=0, watch_deadlocks=False, reach=reach),
    )
    return d


def test_an_unlimited_range_changes_nothing_and_a_short_one_slows_a_robot_that_heard_no_one():
    fresh = Memory.new(1, latency=PARAMS.stale_after)
    free = float(np.hypot(*_decide(np.inf, fresh).step.velocity[0]))
    assert free > 0.9 * PARAMS.v_pref
    d = _decide(0.3, fresh)
    slow, memory = float(np.hypot(*d.step.velocity[0])), d.memory
    limit = float(heard_speed_limit(PARAMS, 0.3, np.array([PARAMS.stale_after]))[0])
    assert slow <= limit + 1e-9
    assert memory.latency[0] == PARAMS.stale_after  # nobody heard: it keeps assuming the worst
    # the preferred velocity keeps to it too, but for the symmetry-breaking perturbation (1e-4 a component)
    assert 0 < float(np.hypot(*d.step.pref_velocity[0])) <= limit + 2e-4


def test_a_crossing_over_a_short_range_with_late_states_has_no_contact():
    """Twenty robots cross a circle hearing each other only within 0.12 or 0.13 m (a hair over two
    bodies and the tracking noise), every state a tick late: slower, and no two bodies touch. Without
    the limit the same runs touch (bench/results/speed_limit.md); with it on the preferred velocity
    alone, seed 5 at 0.12 m did (ORCA, avoiding, chose velocities faster than the limit)."""
    for reach in (0.12, 0.13):
        for seed in (4, 5):
            scene = load_scene("circle", robots=20, seed=seed, duration=60.0)
            out = simulate(scene, link=InProcessLink(20, late=1.0, reach=reach), progress=None)
            assert len(out.contacts) == 0, (reach, seed)
            # every velocity ORCA chose within the limit of the freshest state there can be (before:
            # 0.13 m/s against 0.05)
            params = RobotParams.from_dict(scene.robot)
            fastest = float(np.hypot(*out.arrays["velocity"].transpose(2, 0, 1)).max())
            assert fastest <= float(heard_speed_limit(params, reach, np.zeros(1))[0]) + 1e-12, (reach, seed)
