"""A command drives its body for one control period and a margin, then the body stops: a robot whose
agent falls silent (overloaded, cut off, blind) must not drive on an old command."""

from __future__ import annotations

import threading

import numpy as np

from agent.core.params import DIFFDRIVE
from coordinator.scene import load_scene
from sim.node.world import world_node
from transport.bus import Bus
from transport.codec import Command, Commands, Tick
from transport.session import client_of, loopback_router

SPEED = 0.05  # m/s, both wheels (or straight ahead for a holonomic body)
SILENT_FROM = 3  # the agent of robot 0 answers ticks 0..2, then stays alive but silent


def _agent(bus: Bus, ticks: int, wheels: bool, done: threading.Event) -> None:
    """Robot 0 drives straight until SILENT_FROM; robot 1 answers every tick with a stop."""
    clock = bus.subscribe(bus.keys.clock, Tick)
    bus.declare_alive("agent", 0)
    bus.declare_alive("agent", 1)
    answered = -1
    while not done.is_set() and answered < ticks - 1:
        got = clock.get(timeout=0.1)
        if got is None:
            continue
        tick = got[1].tick
        if tick <= answered:
            continue
        answered = tick
        for robot in (0, 1):
            if robot == 0 and tick >= SILENT_FROM:
                continue
            mode = Command.WHEELS if wheels else Command.HOLONOMIC
            a, b = (SPEED, SPEED if wheels else 0.0) if robot == 0 else (0.0, 0.0)
            bus.publish(bus.keys.cmd(robot), Commands.one(Command(robot, tick, tick * 0.1, mode, a, b, 0, 0, 0)))


def test_a_body_whose_agent_falls_silent_stops_after_its_last_command_runs_out():
    scene = load_scene("swap", robots=2, seed=0, clock="lockstep", duration=1.0)
    router = loopback_router()
    with Bus(router, name="world") as world_bus, Bus(client_of(router), name="agent") as agent_bus:
        node = world_node(world_bus, scene, deadline=0.3, startup_timeout=10.0)
        start = node.backend.true_poses()[0, :2].copy()
        done = threading.Event()
        agent = threading.Thread(
            target=_agent, args=(agent_bus, round(scene.duration / node.dt), node.params.kinematics == DIFFDRIVE, done)
        )
        agent.start()
        try:
            node.run()
        finally:
            done.set()
            agent.join(5.0)
        travelled = float(np.linalg.norm(node.backend.true_poses()[0, :2] - start))
        stats = node.stats()
    period = node.dt
    # three periods of driving at most; with the old command held it would have driven ten
    assert 0.5 * SILENT_FROM * period * SPEED < travelled <= SILENT_FROM * period * SPEED * 1.05
    assert stats["ticks"] == 10 and stats["missed_ticks"] == 10 - SILENT_FROM
    assert stats["stopped_ticks"] >= 10 - SILENT_FROM
