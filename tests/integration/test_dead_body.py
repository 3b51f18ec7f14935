"""A robot whose agent died before it ever spoke is avoided, over a real zenoh router on loopback: the world
node, a lock-step agent host for robot 0, and robot 1's agent, which says it is alive, answers two ticks with
a standing command and dies without one state. Robot 0's goal is where robot 1's body stands (a swap).

The agents knew only that robot 1's agent died, not where its body was: robot 0 drove into it. The body
node now sends the body as a standing obstacle where the tracker sees it (sim.node.body); so it does for an
agent that lives on but hangs, whose body the watchdog stopped. And the tracker's frame of the bodies near
robot 0 shows it too (agent.neighbour_table.with_bodies): each way keeps robot 0 clear on its own."""

from __future__ import annotations

import threading

import pytest

from agent.runtime import AgentHost, HostConfig
from coordinator.scene import load_scene
from coordinator.service import scene_goal_message
from sim.node.body import BodyNode
from sim.node.world import world_node
from transport.bus import Bus
from transport.codec import Command, Commands, Tick
from transport.session import client_of, loopback_router

DIES_AT = 2  # the tick robot 1's agent dies at, never having sent a state


def robot_one(bus: Bus, done: threading.Event, hangs: bool) -> None:
    """Robot 1's agent: alive, a standing command for each tick before DIES_AT, then gone (or, if it
    ``hangs``, alive and silent until the end)."""
    clock = bus.subscribe(bus.keys.clock, Tick)
    token = bus.declare_alive("agent", 1)
    while not done.is_set():
        got = clock.get(timeout=0.05)
        if got is None:
            continue
        tick = got[1]
        if tick.tick >= DIES_AT:
            if hangs:
                done.wait()
            token.undeclare()
            return
        cmd = Command(1, tick.tick, tick.stamp, Command.WHEELS, 0.0, 0.0, 0, 0, 0)
        bus.publish(bus.keys.cmd(1), Commands.one(cmd))


def swap_past_a_dead_body(monkeypatch: pytest.MonkeyPatch, broadcast: bool, near: bool, hangs: bool = False) -> dict:
    """The world's statistics of the run (``min_clearance``: robot 0's closest approach to robot 1's body);
    without the ``broadcast`` of standing bodies, or without the tracker's frames of the bodies ``near``."""
    if not broadcast:
        monkeypatch.setattr(BodyNode, "_standing_bodies", lambda self, measured, t: [])
    if not near:
        monkeypatch.setattr(BodyNode, "_near", lambda self, robots, poses: [robots[:0]] * len(robots))
    scene = load_scene("swap", robots=2, seed=0, clock="lockstep", duration=12.0)
    router = loopback_router()
    with (
        Bus(router, name="world") as world_bus,
        Bus(client_of(router), name="robot-0") as bus_0,
        Bus(client_of(router), name="robot-1") as bus_1,
        Bus(client_of(router), name="coordinator") as coordinator_bus,
    ):
        goals = scene_goal_message(scene)  # the scene's own goals, as the coordinator answers an agent's query
        assert goals is not None
        coordinator_bus.serve(
            coordinator_bus.keys.all_of("goals"), lambda: [(coordinator_bus.keys.goals(1), goals.encode())]
        )
        # a hung agent lives: the lock-step world waits for its command each tick until the deadline
        node = world_node(world_bus, scene, deadline=0.1 if hangs else 2.0, startup_timeout=20.0)
        config = HostConfig(robots=[0], params=node.params, seed=scene.seed, arena=scene.arena, lockstep=True)
        host = AgentHost(bus_0, config)
        done = threading.Event()
        threads = [
            threading.Thread(target=robot_one, args=(bus_1, done, hangs), daemon=True),
            threading.Thread(target=lambda: host.start(timeout=20.0) and host.run(), daemon=True),
        ]
        for thread in threads:
            thread.start()
        try:
            node.run()  # until the scene's duration
        finally:
            done.set()
            host.running = False
            host.auction.stop()
            for thread in threads:
                thread.join(timeout=15.0)
        assert not any(thread.is_alive() for thread in threads)
        stats = node.stats()
    return stats


@pytest.mark.parametrize("broadcast, near, came", [(True, False, 0.05), (False, True, 0.15)], ids=["broadcast", "near"])
def test_a_robot_drives_around_the_body_of_an_agent_that_died_before_it_spoke(monkeypatch, broadcast, near, came):
    """Either way of knowing the body keeps the robot clear: the body node's broadcast of it (a standing
    obstacle), or the tracker's frame of the bodies near the robot (seen, its motion unknown, so the
    robot keeps further off)."""
    stats = swap_past_a_dead_body(monkeypatch, broadcast, near)
    assert stats["reason"] == "duration" and stats["contacts"] == [], stats
    assert 0 < stats["min_clearance"] < came, stats  # it came to the body (its goal is there), and kept clear


def test_without_either_it_drives_into_the_body(monkeypatch):
    """The check above can fail: the same run without the broadcast and the tracker's frame has a contact."""
    stats = swap_past_a_dead_body(monkeypatch, broadcast=False, near=False)
    assert stats["contacts"], stats


@pytest.mark.slow  # 120 ticks, each waiting its deadline for the hung agent's command
def test_a_robot_drives_around_the_body_of_an_agent_that_hung_before_it_spoke(monkeypatch):
    """Alive but silent, robot 1's agent is never heard; its body, which the watchdog stopped, is (the
    broadcast alone: the tracker's frame of the bodies near robot 0 would show it too)."""
    stats = swap_past_a_dead_body(monkeypatch, broadcast=True, near=False, hangs=True)
    assert stats["reason"] == "duration" and stats["contacts"] == [], stats
    assert 0 < stats["min_clearance"] < 0.05, stats
