"""A lock-step agent started again in a run under way answers the tick it joined in at once, over a real zenoh
router on loopback: the tick's clock message (Tick) went out before the agent subscribed, so it never comes.

The world waits for the command of a robot whose agent is alive. An agent that waited for the missed clock
message held every robot's tick for agent.clocks.GOAL_SET_WAIT (10 s), and the rest of the swarm, taking up
the goal set published for its restart meanwhile, ran that set's auction without it."""

from __future__ import annotations

import threading
import time

import numpy as np

from agent.clocks import GOAL_SET_WAIT
from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import Commands, Tick
from transport.session import client_of, loopback_router

TICK = 40  # the tick under way when the agent starts
DT = 0.1


def test_a_lockstep_agent_joining_under_way_answers_the_tick_it_joined_in_without_its_clock_message():
    router = loopback_router()
    with Bus(router, name="world") as world, Bus(client_of(router), name="agent") as agent_bus:
        world.publish(world.keys.clock, Tick(TICK, TICK * DT, DT, 0))  # before the agent subscribed: lost to it
        commands = world.subscribe(world.keys.cmd(0), Commands)
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=RobotParams(dt=DT), lockstep=True))
        thread = threading.Thread(target=lambda: host.start(timeout=10.0) and host.run(), daemon=True)
        started = time.monotonic()
        thread.start()
        try:
            answer = None
            while answer is None and time.monotonic() - started < GOAL_SET_WAIT + 5.0:
                # the tick's pose, as the world sends it to a robot whose agent is not heard yet
                world.publish_poses(TICK, TICK * DT, np.array([0]), np.array([[0.0, 0.0, 0.0]]), frame=False)
                got = commands.get(timeout=0.1)
                answer = None if got is None else got[1]
            took = time.monotonic() - started
        finally:
            host.running = False
            host.auction.stop()
            thread.join(timeout=15.0)
        assert not thread.is_alive()
    assert answer is not None and answer.tick == TICK, "no command for the tick it joined in"
    assert took < GOAL_SET_WAIT / 2, f"its command came {took:.1f} s after it started: it waited for the clock"
