"""An agent host keeps listening around every own robot, even when a tick's poses arrive split.

Regression: at 100 robots in hosts of 10, a tick's poses arrived in two batches under load; the
host re-subscribed only to the cells around the batch, forgot the neighbours around its other
robots, and one robot drove into a neighbour it no longer knew of."""

from __future__ import annotations

import time

import numpy as np

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import Pose, State
from transport.keys import cell_of
from transport.session import client_of, loopback_router, open_session


def test_a_split_tick_keeps_the_neighbours_of_the_robots_not_in_it() -> None:
    params = RobotParams(kinematics="holonomic")
    with Bus(loopback_router(), "cells") as bus:
        host = AgentHost(bus, HostConfig(robots=[0, 1], params=params))
        far = (10.0, 10.0)  # robot 1, many cells away from robot 0
        host._step_tick([Pose(0, 1, 0.1, 0.0, 0.0, 0.0), Pose(1, 1, 0.1, *far, 0.0)])
        neighbour = State(5, 1, 0.1, far[0] + 0.3, far[1], 0.0, 0.0, params.radius, 0.0, 0.0, -1, 0, 0, 0)
        host.table.update(neighbour)
        host._step_tick([Pose(0, 2, 0.2, 0.0, 0.0, 0.0)])  # only robot 0's pose of tick 2 so far
        assert cell_of(*far, host.params.cell_size) in host.inbox.cells.cells
        assert [s.robot for s in host.table.latest_before(3)] == [5], "robot 1's neighbour was forgotten"


def test_a_neighbour_silent_for_seconds_is_forgotten_not_a_phantom_obstacle() -> None:
    """Regression (1000 robots in 4 hosts): a robot of another host left this host's cells, its last
    state stayed in a cell the host still listened to, and 37 s later an own robot arriving there
    stopped 3.8 m short of its goal, avoiding a robot that was long gone. A robot whose agent died
    stays: its body stands where it was last heard (5.1.2)."""
    params = RobotParams(kinematics="holonomic")
    with Bus(loopback_router(), "forget") as bus:
        host = AgentHost(bus, HostConfig(robots=[0], params=params))
        gone = State(5, 1, 0.1, 0.5, 0.0, 0.3, 0.0, params.radius, 0.0, 0.0, -1, 0, 0, 0)
        dead = State(6, 1, 0.1, -0.5, 0.0, 0.0, 0.0, params.radius, 0.0, 0.0, -1, 0, 0, 0)
        host.table.update(gone)
        host.table.update(dead)
        host.inbox.departed.dead.add(6)
        host._step_tick([Pose(0, 2, 0.2, 0.0, 0.0, 0.0)])
        assert 5 in host.table  # silent for 0.1 s: a neighbour (stale after 0.5 s, still avoided)
        ticks = round((params.forget_after + 0.2) / params.dt)
        for k in range(3, 3 + ticks):
            host._step_tick([Pose(0, k, k * params.dt, 0.0, 0.0, 0.0)])
        assert 5 not in host.table, "a robot silent for longer than forget_after is still an obstacle"
        assert 6 in host.table, "a dead robot's body was forgotten"


def _heard_far(arena: tuple[float, float, float, float]) -> tuple[int, list[int]]:
    """A robot alone at the origin in ``arena``; another session says a state in the robot's cells
    and one five cells away, then the near one again: how many samples arrived, and which robots'
    states the robot kept."""
    params = RobotParams(kinematics="holonomic")
    router = loopback_router()
    keep_router = open_session(router)
    try:
        with Bus(client_of(router), "one") as bus, Bus(client_of(router), "one") as other:
            host = AgentHost(bus, HostConfig(robots=[0], params=params, arena=arena))
            host.inbox.cells.update(np.zeros((1, 2)))
            inbox, cell = host.inbox.state, params.cell_size

            def say(robot: int, x: float) -> None:
                state = State(robot, 1, 0.1, x, 0.0, 0.0, 0.0, params.radius, 0.0, 0.0, -1, 0, 0, 0)
                other.publish_states(1, 0.1, [state], cell, None)

            kept: list[int] = []
            deadline = time.monotonic() + 10.0
            while 5 not in kept:  # zenoh tells the publisher of a new subscriber asynchronously
                assert time.monotonic() < deadline, "the near state never arrived"
                say(5, 0.5 * cell)
                time.sleep(0.05)
                kept += [s.robot for s in inbox.take()]
            before, kept = inbox.received, []
            say(6, 5.5 * cell)  # beyond the 5x5 cells around the robot
            say(7, 0.5 * cell)  # after it on the same link: once it is here, so is the far one
            while 7 not in kept:
                assert time.monotonic() < deadline, "the second near state never arrived"
                time.sleep(0.02)
                kept += [s.robot for s in inbox.take()]
            return inbox.received - before, kept
    finally:
        keep_router.close()


def test_a_robot_alone_in_a_small_arena_hears_every_state_on_one_subscription_and_keeps_its_cells() -> None:
    """Its cells cover over a third of the arena's: one subscription to every robot's state instead
    of 25 (agent.runtime.window_covers_a_third); the far state arrives and is not kept. In a large
    arena it listens to its cells only, and the far state never arrives."""
    assert _heard_far((-1.0, -1.0, 1.0, 1.0)) == (2, [7])
    assert _heard_far((-10.0, -10.0, 10.0, 10.0)) == (1, [7])


def test_a_robot_alone_keeps_no_state_of_itself_and_a_host_keeps_its_robots_standing_bodies() -> None:
    """The body node sends a silent robot's body standing (sim.node.body). A robot alone does not hear its
    own states: kept, that body's state grew old, and each lock-step tick waited out its deadline for a
    newer one of itself (a run with most commands lost took four times as long). A host hears its
    robots' states, and one robot's standing body is what another of them must avoid."""
    params = RobotParams(kinematics="holonomic")
    body = State(0, 1, 0.1, 0.0, 0.0, 0.0, 0.0, params.radius, 0.0, 0.0, -1, State.DYNAMIC)
    with Bus(loopback_router(), "self") as bus:
        alone, host = (
            AgentHost(bus, HostConfig(robots=[0], params=params)),
            AgentHost(bus, HostConfig(robots=[0, 1], params=params)),
        )
        alone.on_state(body)
        host.on_state(body)
        assert 0 not in alone.table and 0 in host.table
