"""ORCA on lost and late neighbour states (issue 3), without the bus (sim.central.lossy): every robot hears
each neighbour's state of the tick before unless a seeded draw loses it or makes it a tick late, as
an agent under ``--faults state:drop=...,delay=...`` does. Deterministic and a few seconds per run; the
end-to-end twin over zenoh is in test_collision_avoidance.

The crowd at the circle's centre is where it matters: with the old hard lines, a neighbour heard late
(radius grown by how far it may have strayed) could make them infeasible, and robots touched in the
holonomic cases below (5 of 8 seeds at 30% loss, 50% late).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from agent.core.params import EPUCK
from agent.loop import Sensed
from agent.neighbour_table import Heard
from sim.central.link import InProcessLink
from sim.central.lossy import circle_crossing, run_lossy
from transport.codec import START_TICK


@pytest.mark.parametrize(
    "kinematics, robots, seed",
    [
        ("holonomic", 50, 0),
        ("holonomic", 50, 3),
        ("holonomic", 50, 4),
        ("holonomic", 50, 5),
        ("diffdrive", 30, 0),
    ],
)
@pytest.mark.slow
def test_lost_and_late_states_cause_no_contact(kinematics, robots, seed):
    res = run_lossy(circle_crossing(robots, kinematics, seed), drop=0.3, late=0.5, seed=seed)
    assert 0.15 < res.heard_on_time < 0.25  # the loss really happened
    assert res.contacts == 0 and res.min_clearance > 0, res


@pytest.mark.parametrize("kinematics, robots, seed", [("holonomic", 50, 0), ("holonomic", 50, 1), ("diffdrive", 30, 0)])
def test_with_nine_states_in_ten_lost_robots_stop_rather_than_touch(kinematics, robots, seed):
    """Neighbours mostly stale: a robot stands while one may be where it touches it (agent.core.control),
    which every one of these runs did (by up to 8 cm) while stale neighbours were steered around."""
    res = run_lossy(circle_crossing(robots, kinematics, seed), drop=0.9, late=0.1, seed=seed)
    assert res.heard_on_time == 0.0  # none on time: a tenth a tick late, the rest lost
    assert res.contacts == 0 and res.min_clearance > 0, res
    assert res.progress > 0.1, res  # slower, not frozen


def test_bad_probabilities_are_refused():
    with pytest.raises(ValueError, match="probabilities"):
        run_lossy(circle_crossing(3, "holonomic", 0), drop=0.6, late=0.5)


@pytest.mark.parametrize("drop", [0.0, 0.9])
def test_at_tick_0_every_robot_knows_where_the_others_greeted_from_as_agents_do(drop):
    """Lock-step agents hear their neighbours' hellos before tick 0 and keep them as states of the tick
    before (agent.clocks.LockStep.greet); the in-process link starts the same, lossy or not, so a
    neighbour never heard again goes stale, and a scripted mover, which says no hello, is unknown."""
    positions = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3]])
    start = Heard(
        np.arange(3), positions, np.zeros((3, 2)), np.full(3, 0.05), np.full(3, START_TICK * 0.1), np.arange(3) < 2
    )
    link = InProcessLink(3, drop=drop, late=0.0, seed=1)
    link.start(start, greeted=np.array([True, True, False]))  # robot 2: a mover
    params = replace(EPUCK, neighbour_dist=0.6, max_neighbours=10)
    sensed = Sensed(np.arange(3), positions, np.zeros(3), 0, 0.0, params, np.zeros(3, bool))
    heard = link.neighbours(sensed)
    assert heard.valid.sum(axis=1).tolist() == [1, 1, 2]  # 0 and 1 know each other; the mover knows both
    assert np.allclose(heard.age[heard.valid], 0.1) and np.allclose(heard.velocity[heard.valid], 0.0)


@pytest.mark.parametrize("drop", [0.0, 0.9])
def test_a_robot_never_heard_is_seen_where_the_tracker_sees_it_as_agents_see_it(drop):
    """A robot (not a scripted mover) whose hello and states never came is taken where the tracker sees
    it, standing, not cooperating and stale by one tick, as agents take it from the tracker's frames
    (agent.neighbour_table.with_bodies); a robot heard keeps its state."""
    positions = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3]])
    start = Heard(np.arange(3), positions, np.ones((3, 2)), np.full(3, 0.05), np.full(3, -0.1), np.ones(3, bool))
    link = InProcessLink(3, drop=drop, late=0.0, seed=1)
    link.start(start, greeted=np.array([True, True, False]))  # robot 2: a robot never heard
    params = replace(EPUCK, neighbour_dist=0.6, max_neighbours=10)
    now = positions + 0.01  # where the tracker sees them at tick 0
    heard = link.neighbours(Sensed(np.arange(3), now, np.zeros(3), 0, 0.0, params, np.zeros(3, bool)))
    assert heard.valid.sum(axis=1).tolist() == [2, 2, 2]
    body = heard.valid[:2] & np.isclose(heard.position[:2], now[2]).all(axis=2)  # robot 2, seen by 0 and 1
    assert body.sum(axis=1).tolist() == [1, 1]
    assert np.allclose(heard.age[:2][body], params.stale_after + params.dt) and not heard.cooperative[:2][body].any()
    assert np.allclose(heard.velocity[:2][body], 0.0) and np.allclose(heard.velocity[2][heard.valid[2]], 1.0)
