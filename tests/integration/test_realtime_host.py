"""A real-time agent host against a world the test drives by hand, over a real zenoh router on loopback.

The world sends a tick's clock message before its poses, on the same link, in real time as in lock-step:
a pose of a tick past the newest clock heard was forged. A real-time host once bounded a pose's tick by
the wall clock alone, which allows 2 ticks ahead: a faulty peer's copy of a robot's pose moved a tick on,
sent before the world's, was taken, and the world's pose of that tick then made the robot brake
(a 20-robot circle in real time under `faulty_peer --mode future-pose` did not form in 40 s)."""

from __future__ import annotations

import time

import numpy as np

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from tests.conftest import wait_for
from tests.support.hosts import await_commands, run_host, stop_host, world_and_agent_buses
from transport.codec import Pose, Poses, Tick
from transport.plausible import CONFLICTING, FUTURE

DT = 0.1
PARAMS = RobotParams(kinematics="holonomic")


def test_a_real_time_pose_past_the_newest_clock_is_refused_and_the_robot_drives_on() -> None:
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS))
        thread = run_host(world, host, np.zeros((1, 3)))
        start = time.monotonic()

        def pose(k: int, x: float) -> Poses:
            return Poses.one(Pose(0, k, k * DT, x, 0.0, 0.0))

        for k in range(6):
            time.sleep(max(0.0, start + k * DT - time.monotonic()))  # the world's pace
            world.publish(world.keys.clock, Tick(k, k * DT, DT, 0))
            world.publish(world.keys.pose(0), pose(k, 0.01 * k))
            await_commands(commands, k, {0})
            if k == 2:  # a copy of this tick's pose as the next tick's, before the world's clock of it
                world.publish(world.keys.pose(0), pose(k + 1, 0.01 * k))
                assert wait_for(lambda: host.inbox.pose.drops[FUTURE] + host.inbox.pose.drops[CONFLICTING], 10)
        stop_host(host, thread)
        dropped = host.stats()["dropped"]
        assert dropped[FUTURE] >= 1 and dropped[CONFLICTING] == 0, dropped
        assert not host.poses.doubted_until, "the robot doubted its poses: it braked"
