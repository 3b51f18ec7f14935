"""A lock-step host takes a goal set up at the tick that names it (agent.runtime.AgentHost,
_take_up_goal_sets), over a real zenoh router on loopback: a goal set that no scene step announced
(an agent died) waits, heard, until the world's clock names it, so every host takes it up at the
same tick. Before, each host took it up on arrival; hosts that heard it at different ticks then
waited for each other's auction rounds at every tick, and the run hung."""

from __future__ import annotations

import threading
import time

import numpy as np

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import BEFORE_START, Goals, Pose, Poses, Tick, Timing
from transport.session import client_of, loopback_router, open_session

DT = 0.1


def goal_set(epoch: int, x: float) -> Goals:
    """A one-robot goal set of scene step 0 (robot 0, one goal at (x, 0))."""
    return Goals(epoch, 0, np.array([[x, 0.0]]), np.array([[255, 0, 0]], np.uint8), np.array([0]), Timing(0.0, 0, 60.0))


def test_a_goal_set_heard_before_its_tick_waits_for_the_tick_that_names_it() -> None:
    router = loopback_router()
    session = open_session(router)
    started = threading.Event()
    try:
        with Bus(client_of(router), "named") as world, Bus(client_of(router), "named") as agent_bus:
            commands = world.commands_inbox()
            host = AgentHost(
                agent_bus,
                HostConfig(robots=[0], params=RobotParams(kinematics="holonomic"), lockstep=True, steps=[0.0]),
            )

            def run() -> None:
                if host.start(timeout=20.0):
                    started.set()
                    host.run()

            thread = threading.Thread(target=run, daemon=True)
            thread.start()
            end = time.monotonic() + 20.0
            while not started.is_set() and time.monotonic() < end:
                world.publish(world.keys.pose(0), Poses.one(Pose(0, BEFORE_START, 0.0, 0.0, 0.0, 0.0)))
                time.sleep(0.1)
            assert started.is_set(), "the host did not start"

            def tick(k: int, named: int) -> None:
                """Publish tick k naming goal set ``named``, and wait for the robot's command of it."""
                world.publish(world.keys.clock, Tick(k, k * DT, DT, named))
                world.publish(world.keys.pose(0), Poses.one(Pose(0, k, k * DT, 0.0, 0.0, 0.0)))
                deadline = time.monotonic() + 20.0
                while time.monotonic() < deadline:
                    got = commands.get(timeout=0.1)
                    if got is not None and got[1].tick == k:
                        return
                raise AssertionError(f"no command for tick {k}")

            world.publish(world.keys.goals(1), goal_set(1, 0.5))  # scene step 0's goal set
            tick(0, 0)  # named by no tick yet: taken up as the step due at tick 0
            assert set(host.goal_sets) == {1}

            world.publish(world.keys.goals(2), goal_set(2, 0.6))  # an agent died: no step announced it
            time.sleep(0.5)
            tick(1, 1)
            assert host.newest_heard == 2, "goal set 2 was not heard before tick 1"
            assert 2 not in host.goal_sets, "goal set 2 was taken up at a tick that did not name it"

            tick(2, 2)
            assert 2 in host.goal_sets and not host.held
            host.running = False
            thread.join(timeout=5.0)
            assert not thread.is_alive()
    finally:
        session.close()
