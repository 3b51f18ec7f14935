"""The recorder takes each robot's goal from its own states, whatever a faulty peer sends: a copy of an
old state moved to a later tick (the faulty peer's ``future-state``) is not taken as the robot's newest,
which would hide its real states until that tick and hold the run's convergence back for seconds."""

from __future__ import annotations

import numpy as np

from sim.outputs.recorder import Recorder
from tests.support.fake_bus import RecorderBus
from transport.codec import State, States, Truth

DT = 0.1
AT = np.array([[0.0, 0.0], [1.0, 1.0]])  # where the two robots stand, on their goals


def truth(tick: int) -> Truth:
    pose = np.column_stack([AT, np.zeros(2)])
    return Truth(tick, tick * DT, 1.0, 2, pose, np.zeros((2, 2)), np.zeros((2, 3), np.uint8), np.zeros(2, np.uint32))


def state(robot: int, tick: int, goal: tuple[float, float]) -> States:
    x, y = AT[robot]
    one = State(robot, tick, tick * DT, x, y, 0.0, 0.0, 0.045, *goal, robot, State.HAS_GOAL, 1, 1)
    return States.one(one)


def heard(bus: RecorderBus, rec: Recorder, *messages) -> None:
    bus.raw.items = [
        (bus.keys.truth if isinstance(m, Truth) else bus.keys.states(0), m.encode(), 0.0) for m in messages
    ]
    rec.poll()


def recorder() -> tuple[RecorderBus, Recorder]:
    bus = RecorderBus()
    rec = Recorder(bus, robots=2, tolerance=0.01)
    rec.progress.agent_alive[:] = True
    return bus, rec


def own(robot: int) -> tuple[float, float]:
    return float(AT[robot, 0]), float(AT[robot, 1])


def test_a_copy_moved_to_a_later_tick_does_not_hide_a_robots_states():
    bus, rec = recorder()
    forged = state(0, 12, (3.0, 3.0))  # robot 0's goal before the run's auction agreed, re-sent as tick 12
    for tick in range(16):
        heard(bus, rec, truth(tick), state(0, tick, own(0)), state(1, tick, own(1)), *([forged] if tick == 2 else []))
        np.testing.assert_array_equal(rec.said.goal, AT, err_msg=f"tick {tick}")
    # converged from the first tick that knew the robots' goals on, never interrupted by the copy
    assert rec.progress.converged_since == DT
    np.testing.assert_array_equal(np.array(rec.traj.goal), np.broadcast_to(AT, (16, 2, 2)))


def test_a_state_heard_before_its_ticks_truth_is_recorded_in_its_row():
    bus, rec = recorder()
    moved = (0.5, 0.5)
    heard(bus, rec, truth(0), state(0, 0, own(0)), state(1, 0, own(1)))
    heard(bus, rec, state(1, 1, moved), truth(1), state(0, 1, own(0)))  # robot 1's state came first
    heard(bus, rec, truth(2), state(0, 2, own(0)))
    goals = np.array(rec.traj.goal)
    np.testing.assert_array_equal(goals[:, 1], [own(1), moved, moved])
    np.testing.assert_array_equal(rec.said.goal[1], moved)
