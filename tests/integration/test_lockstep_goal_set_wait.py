"""The lock-step world waits for the goal set of a scene step that begins at a tick, over a real zenoh
router on loopback: the world node and a lock-step agent host, with a coordinator that publishes each
step's goal set only some seconds after it hears the step's first tick (as a loaded machine's did).

The agents wait for that goal set before they answer the tick (agent.clocks.LockStep.take_up_goal_sets). The
world's deadline used to run only from the last auction message, and there is none while the
coordinator works out a goal set, so the world declared the tick missed: two CI runs of the story
animation in agent hosts missed ticks 120-121, where its next keyframe begins.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from agent import clocks
from agent.runtime import AgentHost, HostConfig
from coordinator.scene import Scene, scene_from_dict, scene_goal_set
from sim.node import body
from sim.node.body import BodyNode
from sim.node.world import world_node
from transport.bus import Bus
from transport.codec import Goals, Tick, Timing
from transport.session import client_of, loopback_router, open_session

DEADLINE = 2.0  # s the world waits for a late command, the default
LATE = 3.0  # s from a step's first tick to its goal set: longer than the deadline


def two_steps() -> Scene:
    """Two robots, two pictures: step 1 begins at tick 5 of 10."""
    steps = [{"shape": "disk", "hold": 0.5}, {"shape": "triangle", "hold": 0.5}]
    data = {
        "name": "two-steps",
        "robots": 2,
        "seed": 3,
        "clock": "lockstep",
        "duration": 1.0,
        "robot": {"kinematics": "holonomic"},
        "layout": {"kind": "grid", "spacing": 0.3},
        "steps": steps,
    }
    return scene_from_dict(data)


def late_coordinator(bus: Bus, scene: Scene, done: threading.Event) -> None:
    """Publish each step's goal set LATE s after the world's first tick of the step."""
    clock = bus.subscribe(bus.keys.clock, Tick)
    published = -1
    while not done.is_set():
        got = clock.get(timeout=0.1)
        if got is None:
            continue
        tick = got[1]
        step = scene.step_at(tick.stamp)
        if step <= published:
            continue
        if done.wait(LATE):
            return
        goals, colors = scene_goal_set(scene, step, scene.robots)
        timing = Timing(tick.stamp, step, scene.steps[step].hold, scene.step_starts[step])
        bus.publish(bus.keys.goals(step + 1), Goals(step + 1, 0, goals, colors, np.arange(scene.robots), timing))
        published = step


@contextmanager
def running(target: Callable[..., None], *args: object) -> Iterator[threading.Event]:
    """``target(*args, done)`` on a thread until the block ends."""
    done = threading.Event()
    thread = threading.Thread(target=target, args=(*args, done), daemon=True)
    thread.start()
    try:
        yield done
    finally:
        done.set()
        thread.join(timeout=15.0)
        assert not thread.is_alive()


def host_loop(host: AgentHost, done: threading.Event) -> None:
    if host.start(timeout=20.0):
        host.run()


def run_with_a_late_coordinator() -> tuple[dict, AgentHost]:
    """The world's statistics and the host, after the two steps' run."""
    scene = two_steps()
    assert scene.step_starts == [0.0, 0.5]
    router = loopback_router()
    session = open_session(router)
    try:
        with (
            Bus(client_of(router), name="world") as world_bus,
            Bus(client_of(router), name="agents") as agent_bus,
            Bus(client_of(router), name="coordinator") as coordinator_bus,
        ):
            node: BodyNode = world_node(world_bus, scene, deadline=DEADLINE, startup_timeout=20.0)
            config = HostConfig(
                robots=[0, 1],
                params=node.params,
                seed=scene.seed,
                arena=scene.arena,
                lockstep=True,
                steps=scene.step_starts,
            )
            host = AgentHost(agent_bus, config)
            with running(late_coordinator, coordinator_bus, scene), running(host_loop, host) as host_done:
                try:
                    node.run()
                finally:
                    host.running = False
                    host_done.set()
            stats = node.stats()
    finally:
        session.close()
    return stats, host


def test_the_world_waits_for_the_goal_set_of_a_step_due_at_its_tick() -> None:
    stats, host = run_with_a_late_coordinator()
    assert stats["reason"] == "duration" and stats["ticks"] == 10, stats
    assert set(host.goal_sets.by_epoch) == {1, 2}, "a goal set was not taken up"
    assert stats["missed_ticks"] == 0, stats
    assert stats["goal_sets_not_awaited"] == 0 and host.stats()["lockstep_gave_up"]["goal_sets"] == 0


def test_a_goal_set_waited_for_past_its_patience_is_counted_by_the_world_and_the_host(monkeypatch) -> None:
    """Patience shorter than the coordinator is late: the world and the host go on without the step's goal set
    (the run is the load's, not the seed's), and each says so in its statistics."""
    monkeypatch.setattr(body, "GOAL_SET_PATIENCE", LATE / 3)
    monkeypatch.setattr(clocks, "GOAL_SET_WAIT", LATE / 3)
    stats, host = run_with_a_late_coordinator()
    assert stats["reason"] == "duration" and stats["goal_sets_not_awaited"] == 2, stats  # each step's first tick
    assert host.stats()["lockstep_gave_up"]["goal_sets"] >= 1
