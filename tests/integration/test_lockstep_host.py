"""A lock-step agent host (agent.runtime.AgentHost) against a hand-driven world, over a real zenoh
router on loopback: the test publishes each tick's clock message, poses and goal sets, and waits for
the robots' commands.

- A goal set that no scene step announced (an agent died) waits, heard, until the world's clock
  names it, so every host takes it up at the same tick. Before, each host took it up on arrival;
  hosts that heard it at different ticks waited for each other's auction rounds at every tick, and
  the run hung.
- A tick's poses frame is stepped whole. The inbox hands a frame's records over one by one, and on a
  loaded machine the thread handing them over can stall between two records. A real-time host then
  steps the robots it has; a lock-step host that did so froze its auction block on the other
  robots' poses of the tick before, and the run was no longer the run of its seed.
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import zenoh

from agent import assignment
from agent.clocks import HELLO_EVERY, HELLO_SWARM
from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from tests.conftest import deafen, wait_for
from tests.support.hosts import await_commands, run_host, stop_host, world_and_agent_buses
from transport.bus import Bus, Inbox
from transport.codec import BLOCK_ABANDONED, Event, Goals, Pose, Poses, State, Tick, Timing

DT = 0.1
PARAMS = RobotParams(kinematics="holonomic")


def goal_set(epoch: int, x: float) -> Goals:
    """A one-robot goal set of scene step 0 (robot 0, one goal at (x, 0))."""
    return Goals(epoch, 0, np.array([[x, 0.0]]), np.array([[255, 0, 0]], np.uint8), np.array([0]), Timing(0.0, 0, 60.0))


def say_tick(world: Bus, k: int, named: int = 0) -> None:
    """The world's tick k for robot 0: its clock message (naming goal set ``named``), then the robot's pose."""
    world.publish(world.keys.clock, Tick(k, k * DT, DT, named))
    world.publish(world.keys.pose(0), Poses.one(Pose(0, k, k * DT, 0.0, 0.0, 0.0)))


def test_a_goal_set_heard_before_its_tick_waits_for_the_tick_that_names_it() -> None:
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS, lockstep=True, steps=[0.0]))
        thread = run_host(world, host, np.zeros((1, 3)))

        def tick(k: int, named: int) -> None:
            say_tick(world, k, named)
            await_commands(commands, k, {0})

        world.publish(world.keys.goals(1), goal_set(1, 0.5))  # scene step 0's goal set
        tick(0, 0)  # named by no tick yet: taken up as the step due at tick 0
        assert set(host.goal_sets.by_epoch) == {1}

        world.publish(world.keys.goals(2), goal_set(2, 0.6))  # an agent died: no step announced it
        time.sleep(0.5)
        tick(1, 1)
        assert host.goal_sets.newest_heard == 2, "goal set 2 was not heard before tick 1"
        assert 2 not in host.goal_sets.by_epoch, "goal set 2 was taken up at a tick that did not name it"

        tick(2, 2)
        assert 2 in host.goal_sets.by_epoch and not host.clock.unnamed
        stop_host(host, thread)


def test_a_tick_whose_poses_frame_comes_in_pieces_is_stepped_whole() -> None:
    where = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])  # two robots of one host, apart
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        host = AgentHost(agent_bus, HostConfig(robots=[0, 1], params=PARAMS, lockstep=True, frames=True))
        deliver = host.inbox.pose._deliver

        def in_pieces(key: str, msgs: list) -> None:  # 0.2 s between records: 4 times the real-time batch wait
            for m in msgs:
                deliver(key, [m])
                time.sleep(0.2)

        host.inbox.pose._deliver = in_pieces  # type: ignore[method-assign]
        batches: list[list[int]] = []
        step_tick = host._step_tick

        def counted(poses: list[Pose]) -> None:
            batches.append([q.robot for q in poses])
            step_tick(poses)

        host._step_tick = counted  # type: ignore[method-assign]
        thread = run_host(world, host, where)
        for k in range(3):
            world.publish(world.keys.clock, Tick(k, k * DT, DT, 0))
            world.publish(world.keys.poses, Poses.of(k, k * DT, [Pose(r, k, k * DT, *where[r]) for r in (0, 1)]))
            await_commands(commands, k, {0, 1})
        stop_host(host, thread)
        assert batches == [[0, 1]] * 3, f"the ticks were stepped in batches {batches}"


def test_a_host_in_a_large_swarm_says_hello_less_often() -> None:
    """Every host hears every host's hellos before the first tick: beyond HELLO_SWARM robots in the
    run (the launcher's HostConfig.swarm, through the host's config file) they come proportionally
    less often, so that 10,000 robots' hellos do not swamp the machine."""
    with world_and_agent_buses() as (_, agent_bus):
        for swarm, every in [(40, HELLO_EVERY), (HELLO_SWARM, HELLO_EVERY), (5 * HELLO_SWARM, 5 * HELLO_EVERY)]:
            config = HostConfig.from_json(HostConfig(robots=[0], params=PARAMS, lockstep=True, swarm=swarm).to_json())
            assert config.swarm == swarm
            assert AgentHost(agent_bus, config).clock.hello_every == every


def test_a_host_of_many_robots_holds_as_many_subscriptions_as_a_host_of_two() -> None:
    """A host of several robots hears poses and states as frames: a subscription per robot is a
    thread per robot in zenoh-python, and a cell subscription a declaration passed to every session
    (at 10 hosts of 1000 they took the machine's load to 1790). Robots alone keep theirs."""
    with world_and_agent_buses() as (world, agent_bus):
        held = {}
        for n in (2, 200):
            before = len(agent_bus._subscriptions)
            host = AgentHost(agent_bus, HostConfig(robots=list(range(n)), params=PARAMS, lockstep=True, frames=True))
            where = np.column_stack([np.arange(n) * 0.3, np.zeros(n), np.zeros(n)])
            stop_host(host, run_host(world, host, where))
            held[n] = len(agent_bus._subscriptions) - before
        assert held[200] == held[2]
        before = len(agent_bus._subscriptions)
        AgentHost(agent_bus, HostConfig(robots=list(range(200, 210)), params=PARAMS, lockstep=True))
        assert len(agent_bus._subscriptions) - before >= 10  # robots alone: one pose key each


def answered_tick_0(world: Bus, agent_bus: Bus) -> tuple[AgentHost, threading.Thread, Inbox]:
    """A lock-step host of robot 0, started, that answered tick 0: it, its thread, and the commands' inbox."""
    commands = world.commands_inbox()
    host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS, lockstep=True))
    thread = run_host(world, host, np.zeros((1, 3)))
    say_tick(world, 0)
    await_commands(commands, 0, {0})
    return host, thread, commands


def link_lost_and_back(bus: Bus) -> None:
    """The bus's link to the router goes and comes back, as zenoh tells it."""
    bus._on_link(SimpleNamespace(kind=zenoh.SampleKind.DELETE))
    bus._on_link(SimpleNamespace(kind=zenoh.SampleKind.PUT))


@pytest.mark.slow
def test_a_host_whose_link_came_back_declares_its_subscriptions_again_until_a_pose_comes() -> None:
    """A client's subscriptions can go deaf when its link drops and returns on a starved machine
    (transport.bus.Bus.renew_if_due): the host declares them again, and again until a pose comes
    (one renewal left a few agents deaf). Here the link's events are told to the bus, and its
    subscriptions are made deaf under it, twice."""
    with world_and_agent_buses() as (world, agent_bus):
        host, thread, commands = answered_tick_0(world, agent_bus)
        deafen(agent_bus)
        link_lost_and_back(agent_bus)
        assert wait_for(lambda: agent_bus.renewals == 1, timeout=10.0)
        deafen(agent_bus)
        say_tick(world, 1)  # unheard
        assert wait_for(lambda: agent_bus.renewals == 2, timeout=10.0)
        say_tick(world, 2)
        await_commands(commands, 2, {0})
        stop_host(host, thread)


def test_a_host_whose_link_came_back_answers_the_worlds_clock_however_far_it_went_on() -> None:
    """A world in lock-step goes on without robots heard dead (a host stalled past its link's lease), and the
    ticks it sent meanwhile never reached the host. Back, the host took the next tick for one from the future
    (more than AHEAD past the newest it knew), refused it and its poses, and the world waited for it in vain."""
    with world_and_agent_buses() as (world, agent_bus):
        host, thread, commands = answered_tick_0(world, agent_bus)
        link_lost_and_back(agent_bus)
        for k in (12, 13):
            say_tick(world, k)
            await_commands(commands, k, {0})
        assert not host.inbox.pose.drops and not host.clock.inbox.drops
        stop_host(host, thread)


def test_a_host_back_mid_step_takes_a_later_set_of_the_step_only_at_the_tick_that_names_it() -> None:
    """A host stalled over a step's first tick misses the step's set, which every other host took up there. The
    coordinator sends one more set of the step for its robots, which the world names a tick or two later. Taken
    up at once as the step's set, it began this host's auction ticks before the others': each waited for the
    other's rounds for ROUND_CAP."""
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS, lockstep=True, steps=[0.0, 1.0]))
        thread = run_host(world, host, np.zeros((1, 3)))
        world.publish(world.keys.goals(1), goal_set(1, 0.5))
        say_tick(world, 0)
        await_commands(commands, 0, {0})
        link_lost_and_back(agent_bus)  # stalled over tick 10, step 1's first, and missed step 1's set (epoch 2)
        again = Goals(
            3, 0, np.array([[0.7, 0.0]]), np.zeros((1, 3), np.uint8), np.array([0]), Timing(1.0, 1, 60.0, 1.0)
        )
        world.publish(world.keys.goals(3), again)
        time.sleep(0.3)
        say_tick(world, 12, named=2)  # what the other hosts took up
        await_commands(commands, 12, {0})
        assert 3 not in host.goal_sets.by_epoch, "a later set of the step was taken up at a tick that did not name it"
        say_tick(world, 13, named=3)
        await_commands(commands, 13, {0})
        assert 3 in host.goal_sets.by_epoch
        stop_host(host, thread)


def pair_set(epoch: int) -> Goals:
    """Robots 0 and 1, two goals; cold (no warm start), as after a restart."""
    return Goals(
        epoch,
        0,
        np.array([[0.5, 0.0], [0.5, 0.1 * epoch]]),
        np.zeros((2, 3), np.uint8),
        np.array([0, 1]),
        Timing(0, 0, 60),
    )  # another set of goals each epoch: a copy under a new epoch is refused as replayed


@pytest.mark.parametrize("ends", ["ROUND_CAP passes", "a cold set is held"])
def test_a_host_that_gives_a_round_up_asks_for_a_new_set_unless_one_that_begins_again_is_held(
    ends: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Robot 1's host never says a round (it stalled, or is in another block). A host gives the block up after
    ROUND_CAP and tells the coordinator, which sends a new set, cold (coordinator.service.Roster.gave_up): the
    hosts' blocks may have parted for good. Once a newer set that begins every host's auction again is held,
    the round is moot: the host gives it up at once, and asks for nothing."""
    monkeypatch.setattr(assignment, "ROUND_CAP", 1.0)
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        said = world.subscribe(world.keys.agents_events, Event)
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS, lockstep=True, steps=[0.0]))
        thread = run_host(world, host, np.zeros((1, 3)))
        world.publish(world.keys.goals(1), pair_set(1))
        say_tick(world, 0, named=1)
        assert wait_for(lambda: host.auction.exchange.waiting_for is not None, timeout=10.0)
        if ends == "a cold set is held":
            monkeypatch.setattr(assignment, "ROUND_CAP", 600.0)
            world.publish(world.keys.goals(2), pair_set(2))
        await_commands(commands, 0, {0})
        assert host.auction.counts.abandoned == 1
        time.sleep(0.3)
        events = [e.data for _, e in said.drain() if e.data.get("kind") == BLOCK_ABANDONED]
        assert events == ([{"kind": BLOCK_ABANDONED, "epoch": 1, "robots": [0]}] if ends == "ROUND_CAP passes" else [])
        host.auction.stop()
        stop_host(host, thread)


def test_a_goal_set_refused_as_from_the_future_is_heard_again_once_the_clock_has_gone_on() -> None:
    """Back from a stall, a host knows an old display time: the coordinator's newest sets look as from the future
    (stamped more than RESYNC beyond it), and the coordinator repeats only its newest. A set refused for good
    left the tick that named it without its set, and the host took up another set than the other hosts."""
    with world_and_agent_buses() as (world, agent_bus):
        host, thread, commands = answered_tick_0(world, agent_bus)
        early = Goals(1, 0, np.array([[0.5, 0.0]]), np.zeros((1, 3), np.uint8), np.array([0]), Timing(3.0, 0, 60.0))
        world.publish(world.keys.goals(1), early)
        time.sleep(0.3)  # heard at the next tick, at most 1.5 s of display time: refused
        for k in range(1, 31):
            say_tick(world, k, named=1 if k == 30 else 0)
            await_commands(commands, k, {0})
        assert 1 in host.goal_sets.by_epoch
        assert dict(host.inbox.goals.drops) == {"future": 1}  # counted once, however often heard again
        stop_host(host, thread)


def test_a_host_counts_the_neighbours_it_stopped_waiting_for_once_each() -> None:
    """A neighbour's state of the last tick that does not come within ``state_wait``: the host goes on without it
    (the run is no longer its seed's alone) and says so in its statistics, once; silent, it is not waited for."""
    with world_and_agent_buses() as (world, agent_bus):
        commands = world.commands_inbox()
        host = AgentHost(agent_bus, HostConfig(robots=[0], params=PARAMS, lockstep=True, state_wait=0.3))
        thread = run_host(world, host, np.zeros((1, 3)))
        for k in range(5):  # tick 3 waits for robot 1's state of tick 2 in vain; tick 4 waits for nothing
            if k < 2:  # robot 1, 0.5 m off, speaks at ticks 0 and 1 only
                state = State(1, k, k * DT, 0.5, 0.0, 0.0, 0.0, PARAMS.radius, 0.0, 0.0, -1, 0, 0, 0)
                world.publish_states(k, k * DT, [state], PARAMS.cell_size, None)
                time.sleep(0.2)
            say_tick(world, k)
            await_commands(commands, k, {0})
        gave_up = host.stats()["lockstep_gave_up"]
        stop_host(host, thread)
    assert gave_up == {"neighbour_states": 1, "goal_sets": 0}
