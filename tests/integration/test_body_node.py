"""One body node: the simulated world and an emulated e-puck2 (real TCP on 127.0.0.1) are backends of
the same node, driven by its one loop (sim.node.body.BodyNode.step_tick). A backend or node that grew
a loop of its own would move bodies or publish the clock outside that method, or run a tick without it."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from agent.core.params import DIFFDRIVE, RobotParams
from coordinator.scene import load_scene
from hardware.config import load_hardware
from hardware.poses import PoseSample
from sim.emulators.epuck2 import Epuck2Emulator
from sim.node.body import BodyNode, Tally
from sim.node.hardware import WheelDrive, hardware_node, wait_for_hardware
from sim.node.world import world_node
from tests.conftest import wait_for
from tests.support.hardware import moving_commands, scene_file
from transport.bus import Bus
from transport.codec import Command, Commands, State, Tick
from transport.session import client_of, loopback_router

SPEED = 0.05  # m/s on both wheels: straight ahead


class OneLoopSpy:
    """Counts the node's ticks and notes every backend call that moves bodies outside one of them."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, node: BodyNode) -> None:
        self.ticks, self.inside, self.outside, self.moved = 0, False, [], 0
        tick = BodyNode.step_tick

        def step_tick(this: BodyNode) -> None:
            self.ticks += 1
            self.inside = True
            try:
                tick(this)
            finally:
                self.inside = False

        monkeypatch.setattr(BodyNode, "step_tick", step_tick)
        for name in ("apply", "step"):
            monkeypatch.setattr(node.backend, name, self._watched(name, getattr(node.backend, name)))

    def _watched(self, name: str, method):  # noqa: ANN001, ANN202
        def call(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            if not self.inside:
                self.outside.append(name)
            self.moved += name == "apply"
            return method(*args, **kwargs)

        return call


@contextmanager
def agents_answering(bus: Bus, robots: int) -> Iterator[None]:
    """Every robot's agent alive, answering each tick with straight ahead at SPEED."""
    clock = bus.subscribe(bus.keys.clock, Tick)
    for robot in range(robots):
        bus.declare_alive("agent", robot)
    done = threading.Event()

    def answer() -> None:
        while not done.is_set():
            got = clock.get(timeout=0.05)
            for robot in range(robots) if got is not None else ():
                tick = got[1]
                cmd = Command(robot, tick.tick, tick.stamp, Command.WHEELS, SPEED, SPEED, 0, 0, 0)
                bus.publish(bus.keys.cmd(robot), Commands.one(cmd))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(5.0)


def run_bounded(node: BodyNode, seconds: float) -> None:
    runner = threading.Thread(target=node.run, daemon=True)
    runner.start()
    runner.join(seconds)
    node.running = False
    runner.join(10.0)
    assert not runner.is_alive()


def test_the_simulated_world_is_driven_by_the_node_s_one_loop(monkeypatch):
    scene = load_scene("swap", robots=2, seed=3, clock="lockstep", duration=0.8)
    router = loopback_router()
    with Bus(router, name="world") as world_bus, Bus(client_of(router), name="agents") as agent_bus:
        node = world_node(world_bus, scene, deadline=2.0, startup_timeout=10.0)
        spy = OneLoopSpy(monkeypatch, node)
        start = node.backend.true_poses().copy()
        assert node.params.kinematics == DIFFDRIVE
        with agents_answering(agent_bus, scene.robots):
            run_bounded(node, 60.0)
        moved = np.linalg.norm(node.backend.true_poses()[:, :2] - start[:, :2], axis=1)
        stats = node.stats()
    assert stats["reason"] == "duration" and stats["ticks"] == 8
    assert spy.ticks == stats["ticks"]  # every tick, and only ticks, through BodyNode.step_tick
    assert spy.outside == [] and spy.moved > 0
    assert np.all(moved > 0.5 * SPEED * scene.duration)


class EmulatorPoses:
    """The emulator's true poses as the pose source (the test stands in for the motion capture)."""

    def __init__(self, emulator: Epuck2Emulator, n: int) -> None:
        self.emulator, self.n = emulator, n

    def start(self) -> None: ...
    def latest(self) -> dict[int, PoseSample]:
        return {r: PoseSample(*self.emulator.pose(r), time.time(), 0.0) for r in range(self.n)}

    def stats(self) -> dict[str, int]:
        return {"stale": 0, "future": 0, "restarts": 0}

    def robot_stats(self, robot: int) -> dict[str, int]:
        return self.stats()

    def close(self) -> None: ...


def test_an_emulated_epuck2_is_driven_by_the_same_loop(tmp_path, monkeypatch):
    scene = load_scene(str(scene_file(tmp_path, robots=2, duration=1.0)), clock="realtime")
    router = loopback_router()
    with Epuck2Emulator(2, poses=[(0, 0, 0), (0, 0.5, 0)]) as emulator:
        hw = tmp_path / "hw.toml"
        hw.write_text(emulator.hardware_toml())
        drive = WheelDrive(load_hardware(hw).backend, RobotParams.from_dict(scene.robot))
        with Bus(router, name="hardware") as node_bus, Bus(client_of(router), name="agents") as agent_bus:
            node = hardware_node(node_bus, scene, drive, EmulatorPoses(emulator, 2), timeout=0.5)
            spy = OneLoopSpy(monkeypatch, node)
            drive.start()
            try:
                assert wait_for_hardware(node, 10.0) is None
                with agents_answering(agent_bus, scene.robots):
                    run_bounded(node, 30.0)
            finally:
                unreached = drive.close()
            stats = node.stats()
        # close returns once the stops have left; the emulator's reader may log them a moment later
        wait_for(lambda: all(emulator.log(r)[-1][1:] == (0, 0) for r in range(2)), 5)
        logs = [emulator.log(r) for r in range(2)]
    assert unreached == [] and stats["reason"] == "duration" and stats["ticks"] == 10
    assert spy.ticks == stats["ticks"]
    assert spy.outside == [] and spy.moved > 0
    for log in logs:  # the robots were driven over TCP, then told to stop when the run ended
        assert len(moving_commands(log)) > 0 and log[-1][1:] == (0, 0)


class _SlowFirstAnswers:
    """What LockStep.spans reads of a body node whose two agents answer each tick ``after`` seconds
    after the world begins to wait for them."""

    dt, withheld = 0.1, False
    seen = None  # its command inbox notes no arrivals (no fault plan)

    def __init__(self, tick: int, after: float) -> None:
        self.tick, self.live = tick, np.ones(2, bool)
        self.last_cmd_tick = np.full(2, tick - 1)
        self.answer_at = time.monotonic() + after
        self.cmd_inbox, self.tally = self, Tally(2)

    def get(self, timeout: float) -> None:
        time.sleep(timeout)

    def take_commands(self, first: object) -> None:
        if time.monotonic() >= self.answer_at:
            self.last_cmd_tick[:] = self.tick

    def hear_goals(self) -> None:
        pass

    def awaits_goal_set(self, killed: list[int]) -> bool:
        return False

    def update_liveness(self) -> None:
        pass

    def killed_now(self) -> list[int]:
        return []


def test_the_first_lockstep_tick_waits_past_the_deadline_for_every_agent(monkeypatch):
    """Every agent process takes its first step at once: a first tick answered past the deadline is
    waited for (up to FIRST_TICK_PATIENCE), where any later tick is missed."""
    from sim.node import body
    from tests.support.fake_bus import RecorderBus

    monkeypatch.setattr(body, "FIRST_TICK_PATIENCE", 5.0)
    clock = body.LockStep(RecorderBus(), deadline=0.3)  # type: ignore[arg-type]
    for tick, answered in [(0, True), (1, False)]:
        node = _SlowFirstAnswers(tick, after=1.0)
        next(clock.spans(node))  # type: ignore[arg-type]
        assert (node.last_cmd_tick == tick).all() == answered


class _KilledLate(_SlowFirstAnswers):
    """Both agents answer at once; the scene kills robot 1 at tick 5, and its agent is gone ``after``
    seconds later (the launcher kills it once its recorder has seen the tick)."""

    def __init__(self, tick: int, after: float) -> None:
        super().__init__(tick, after=0.0)
        self.gone_at = time.monotonic() + after

    def update_liveness(self) -> None:
        self.live[1] = time.monotonic() < self.gone_at

    def killed_now(self) -> list[int]:
        return [1] if self.tick == 5 else []


class _SurvivorsSetLate(_KilledLate):
    """Robot 1's agent is gone at once when the scene kills it at tick 5; the coordinator's goal set for robot
    0 alone is heard ``after`` seconds later. The node's own rule says whether a goal set is due."""

    step_starts, step_heard = [0.0], 0
    awaits_goal_set, step_due = BodyNode.awaits_goal_set, BodyNode.step_due

    def __init__(self, tick: int, after: float) -> None:
        super().__init__(tick, after=0.0)
        self.heard_at, self.listed, self.told = time.monotonic() + after, frozenset({0, 1}), 0

    def hear_goals(self) -> None:
        if time.monotonic() >= self.heard_at:
            self.listed = frozenset({0})

    def publish_before_start(self) -> None:
        self.told += 1


class _CameAliveDuring(_SlowFirstAnswers):
    """Robot 0's agent answers at once; robot 1's is heard alive only while the world waits (an agent started
    again) and never answers this tick, whose pose it may not have had. Counts the world's waits."""

    def __init__(self, tick: int) -> None:
        super().__init__(tick, after=0.0)
        self.live[1], self.last_cmd_tick[1], self.waits = False, -1, 0

    def get(self, timeout: float) -> None:
        self.waits += 1

    def take_commands(self, first: object) -> None:
        self.last_cmd_tick[0] = self.tick

    def update_liveness(self) -> None:
        self.live[1] = True


def test_a_lockstep_tick_does_not_wait_for_an_agent_heard_alive_after_it_went_out():
    """Waiting for it held the whole run for the deadline (2 s) at the tick an agent was started again in."""
    from sim.node import body
    from tests.support.fake_bus import RecorderBus

    clock = body.LockStep(RecorderBus(), deadline=30.0)  # type: ignore[arg-type]
    node = _CameAliveDuring(7)
    next(clock.spans(node))  # type: ignore[arg-type]
    assert node.waits == 1 and node.live[1]  # one look at the commands: robot 0's was in


def test_a_lockstep_tick_at_which_the_scene_kills_a_robot_waits_until_its_agent_is_gone():
    """A loaded launcher kills a robot seconds of display after the scene's time, unless the world
    waits for it at that tick; no other tick waits for a death."""
    from sim.node import body
    from tests.support.fake_bus import RecorderBus

    clock = body.LockStep(RecorderBus(), deadline=0.3)  # type: ignore[arg-type]
    for tick, dead in [(5, True), (6, False)]:
        node = _KilledLate(tick, after=1.0)
        next(clock.spans(node))  # type: ignore[arg-type]
        assert node.live[1] == (not dead)


def test_a_lockstep_tick_at_which_the_scene_kills_a_robot_waits_for_the_survivors_goal_set():
    """The coordinator hears of a death in wall time and takes its time over the survivors' goal set: the
    tick after the kill names it however late it comes, so every run takes it up at that tick. Meanwhile the
    dead robot's body is told where it stands, for the coordinator to keep the goals clear of it."""
    from sim.node import body
    from tests.support.fake_bus import RecorderBus

    clock = body.LockStep(RecorderBus(), deadline=0.3)  # type: ignore[arg-type]
    for tick, waited in [(5, True), (6, False)]:
        node = _SurvivorsSetLate(tick, after=1.0)
        next(clock.spans(node))  # type: ignore[arg-type]
        assert (node.listed == {0}) == waited and (node.told > 0) == waited
        assert node.tally.goal_sets_not_awaited == 0  # waited for in time: nothing given up


def test_a_dead_agents_body_is_broadcast_as_a_standing_obstacle_where_the_tracker_sees_it():
    """A robot whose agent died before it ever broadcast a state is otherwise unknown to its neighbours,
    which would drive into its body: the node broadcasts the body each tick as a state that stands and
    avoids nobody, at its tracked position, and stops once the agent is alive again."""
    scene = load_scene("circle", robots=3, seed=3, clock="lockstep", duration=2.0)
    router = loopback_router()
    with Bus(router, name="world") as world_bus, Bus(client_of(router), name="agents") as agent_bus:
        node = world_node(world_bus, scene, deadline=2.0, startup_timeout=10.0)
        states = agent_bus.subscribe(agent_bus.keys.all_of("state"), State)
        clock = agent_bus.subscribe(agent_bus.keys.clock, Tick)
        tokens = {robot: agent_bus.declare_alive("agent", robot) for robot in range(scene.robots)}
        done = threading.Event()

        def answer() -> None:  # robot 1's agent dies at tick 5 and comes back at tick 12
            while not done.is_set():
                got = clock.get(timeout=0.05)
                if got is None:
                    continue
                tick = got[1]
                # the tick's commands wait until the world has heard the token go or come: lock-step ticks
                # can outrun the liveliness news on a loaded machine, which made the ticks of the body vary
                if tick.tick == 5:
                    tokens.pop(1).undeclare()
                    wait_for(lambda: not node.live[1], 10.0, 0.005)
                if tick.tick == 12:
                    tokens[1] = agent_bus.declare_alive("agent", 1)
                    wait_for(lambda: node.live[1], 10.0, 0.005)
                for robot in sorted(tokens):  # robot 1 before 2: its command is in before the tick can end
                    cmd = Command(robot, tick.tick, tick.stamp, Command.HOLONOMIC, 0.0, 0.0, 0, 0, 0)
                    agent_bus.publish(agent_bus.keys.cmd(robot), Commands.one(cmd))

        thread = threading.Thread(target=answer, daemon=True)
        thread.start()
        try:
            run_bounded(node, 60.0)
        finally:
            done.set()
            thread.join(5.0)
        body = node.backend.true_poses()[1, :2]
        heard = [s for _, s in states.drain()]
    assert {s.robot for s in heard} == {1}  # live robots speak for themselves (here: nobody does)
    ticks = sorted(s.tick for s in heard)
    assert ticks == list(range(6, 13))  # from the tick after the death is heard to the tick of the return
    for s in heard:
        assert (
            s.flags == State.DYNAMIC and s.vx == s.vy == 0.0 and s.radius == np.float32(node.params.radius)
        )  # as the wire carries it
        assert np.hypot(s.x - body[0], s.y - body[1]) < 0.02  # the tracker's measurement of the body
