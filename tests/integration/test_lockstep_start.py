"""The lock-step start-up handshake (agent.runtime.AgentHost.start), two hosts over a real zenoh
router on loopback: a host says its robots are alive only once it has heard the hello of every robot
its config lists as near at the start, and it keeps saying hello until its first tick, so a host that
starts later is not left waiting.

Regression: with a fixed 0.5 s pause before tick 0 instead, a neighbour's tick-0 state could go
unsent (zenoh tells a publisher about a new subscriber asynchronously) and the reproducibility check
of tests/e2e/test_runtime.py failed 2 runs in 5 under load, each at tick 1."""

from __future__ import annotations

import threading
import time

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import BEFORE_START, START_TICK, Pose, Poses, as_sent
from transport.session import client_of, loopback_router, open_session

WHERE = {0: (0.0, 0.0), 1: (0.3, 0.0)}  # within state reach of each other


def tracker(bus: Bus, stop: threading.Event) -> None:
    """The world before the start: every robot hears where it stands until the test ends."""
    while not stop.is_set():
        for r, (x, y) in WHERE.items():
            bus.publish(bus.keys.pose(r), Poses.one(Pose(r, BEFORE_START, 0.0, x, y, 0.0)))
        stop.wait(0.1)


def test_a_host_is_alive_only_after_its_neighbours_hello_and_greets_until_its_first_tick() -> None:
    params = RobotParams(kinematics="holonomic")
    router = loopback_router()
    session = open_session(router)
    stop = threading.Event()
    try:
        with (
            Bus(client_of(router), "greet") as world,
            Bus(client_of(router), "greet") as bus_a,
            Bus(client_of(router), "greet") as bus_b,
        ):
            alive = world.watch_alive("agent")
            threading.Thread(target=tracker, args=(world, stop), daemon=True).start()
            a = AgentHost(bus_a, HostConfig(robots=[0], params=params, lockstep=True, greet=[1]))
            b = AgentHost(bus_b, HostConfig(robots=[1], params=params, lockstep=True, greet=[0]))
            started, at_start = {}, {}

            def host(name: str, h: AgentHost) -> None:  # as agent/__main__.py: start, then run
                started[name] = h.start(timeout=20.0)
                at_start[name] = [(s.robot, s.tick, s.x, s.y, s.vx, s.vy) for s in h.table.latest_before(0)]
                if started[name]:
                    h.run()

            thread_a = threading.Thread(target=host, args=("a", a), daemon=True)
            thread_a.start()
            time.sleep(2.0)  # b has not started: a hears no hello and must not say it is alive
            assert "a" not in started and not [e for e in alive.drain() if e[2]], "a came alive without b's hello"
            thread_b = threading.Thread(target=host, args=("b", b), daemon=True)
            thread_b.start()
            end = time.monotonic() + 20.0
            came: set[str] = set()
            while came != {"0", "1"} and time.monotonic() < end:
                came |= {ident for _, ident, up, _, _ in alive.drain() if up}
                time.sleep(0.05)
            a.running = b.running = False
            thread_a.join(timeout=5.0)
            thread_b.join(timeout=5.0)
            assert came == {"0", "1"}, f"alive: {sorted(came)}"
            assert 1 in a.clock.greeted and 0 in b.clock.greeted
            # each hello is the neighbour's state from before tick 0, standing where it starts: unheard
            # after, it goes stale and the robot stands for it, as the central engine's link starts
            for name, other in (("a", 1), ("b", 0)):
                assert at_start[name] == [(other, START_TICK, *as_sent(WHERE[other]), 0.0, 0.0)], at_start
    finally:
        stop.set()
        session.close()
