"""A lock-step agent started again in a run under way answers at once the ticks whose clock message (Tick)
it missed, over a real zenoh router on loopback: the tick it joined in, whose clock message went out before
it subscribed, and the ticks after it whose clock message went out before its clock subscription took hold
(declared after its pose subscription, it can take hold a few ticks later: seen in CI).

The world waits for the command of a robot whose agent is alive. An agent that waited for a missed clock
message held every robot's tick for agent.clocks.GOAL_SET_WAIT (10 s), and the rest of the swarm, taking up
the goal set published for its restart meanwhile, ran that set's auction without it."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from agent.clocks import GOAL_SET_WAIT
from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import Commands, Tick
from transport.session import client_of, loopback_router

JOINED = 40  # the tick under way when the agent starts
DT = 0.1


def publish_pose(world: Bus, tick: int) -> None:
    world.publish_poses(tick, tick * DT, np.array([0]), np.array([[0.0, 0.0, 0.0]]), frame=False)


@pytest.mark.parametrize("answered", [JOINED, JOINED + 1], ids=["the-tick-it-joined-in", "the-next-tick"])
def test_a_lockstep_agent_joining_under_way_answers_a_tick_whose_clock_message_it_missed_at_once(answered):
    router = loopback_router()
    with Bus(router, name="world") as world, Bus(client_of(router), name="agent") as agent_bus:
        for tick in range(JOINED, answered + 1):  # before the agent subscribed: lost to it
            world.publish(world.keys.clock, Tick(tick, tick * DT, DT, 0))
        commands = world.subscribe(world.keys.cmd(0), Commands)
        alive = world.watch_alive("agent")
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=RobotParams(dt=DT), lockstep=True))
        thread = threading.Thread(target=lambda: host.start(timeout=10.0) and host.run(), daemon=True)
        started = time.monotonic()
        thread.start()
        try:
            # the tick it joined in as the world sends it to a robot whose agent is not heard yet, until it is
            while not any(a for _, _, a, _, _ in alive.drain()) and time.monotonic() - started < 10.0:
                publish_pose(world, JOINED)
                time.sleep(0.05)
            answer = None
            while answer is None and time.monotonic() - started < GOAL_SET_WAIT + 5.0:
                publish_pose(world, answered)
                got = commands.get(timeout=0.1)
                answer = None if got is None or got[1].tick < answered else got[1]
            took = time.monotonic() - started
        finally:
            host.running = False
            host.auction.stop()
            thread.join(timeout=15.0)
        assert not thread.is_alive()
    assert answer is not None and answer.tick == answered, f"no command for tick {answered}"
    assert took < GOAL_SET_WAIT / 2, f"its command came {took:.1f} s after it started: it waited for the clock"
