"""An agent host (agent.runtime.AgentHost) against a world the test drives by hand, over a real zenoh
router on loopback."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from agent.runtime import AgentHost
from transport.bus import Bus, Inbox
from transport.codec import BEFORE_START, Command
from transport.session import client_of, loopback_router, open_session


@contextmanager
def world_and_agent_buses() -> Iterator[tuple[Bus, Bus]]:
    router = loopback_router()
    session = open_session(router)
    try:
        with Bus(client_of(router), "host") as world, Bus(client_of(router), "host") as agent_bus:
            yield world, agent_bus
    finally:
        session.close()


def run_host(world: Bus, host: AgentHost, where: np.ndarray) -> threading.Thread:
    """Start ``host`` on a thread (start, then its loop) and return once its robots, standing at
    ``where`` (a row per robot), are alive."""
    started = threading.Event()

    def run() -> None:
        if host.start(timeout=20.0):
            started.set()
            host.run()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    end = time.monotonic() + 20.0
    while not started.is_set() and time.monotonic() < end:
        world.publish_poses(BEFORE_START, 0.0, np.array(host.config.robots), where, host.config.frames)
        time.sleep(0.1)
    assert started.is_set(), "the host did not start"
    return thread


def stop_host(host: AgentHost, thread: threading.Thread) -> None:
    host.running = False
    thread.join(timeout=5.0)
    assert not thread.is_alive()


def await_commands(commands: Inbox[Command], tick: int, robots: set[int]) -> None:
    heard: set[int] = set()
    deadline = time.monotonic() + 20.0
    while heard != robots and time.monotonic() < deadline:
        got = commands.get(timeout=0.1)
        if got is not None and got[1].tick == tick:
            heard.add(got[1].robot)
    assert heard == robots, f"tick {tick}: commands of {sorted(heard)}"
