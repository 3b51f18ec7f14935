"""An agent host keeps listening around every own robot, even when a tick's poses arrive split.

Regression: at 100 robots in hosts of 10, a tick's poses arrived in two batches under load; the
host re-subscribed only to the cells around the batch, forgot the neighbours around its other
robots, and one robot drove into a neighbour it no longer knew of."""
from __future__ import annotations

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import Pose, State
from transport.keys import cell_of
from transport.session import loopback_router


def test_a_split_tick_keeps_the_neighbours_of_the_robots_not_in_it() -> None:
    params = RobotParams(kinematics="holonomic")
    with Bus(loopback_router(), "cells") as bus:
        host = AgentHost(bus, HostConfig(robots=[0, 1], params=params))
        far = (10.0, 10.0)  # robot 1, many cells away from robot 0
        host._step_tick([Pose(0, 1, 0.1, 0.0, 0.0, 0.0), Pose(1, 1, 0.1, *far, 0.0)])
        neighbour = State(5, 1, 0.1, far[0] + 0.3, far[1], 0.0, 0.0, params.radius, 0.0, 0.0, -1, 0, 0, 0)
        host.table.update(neighbour)
        host._step_tick([Pose(0, 2, 0.2, 0.0, 0.0, 0.0)])  # only robot 0's pose of tick 2 so far
        assert cell_of(*far, host.cell_size) in host.cells.cells
        assert [s.robot for s in host.table.latest_before(3)] == [5], "robot 1's neighbour was forgotten"
