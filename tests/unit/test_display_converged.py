"""When the recorder calls the display converged (sim.outputs.recorder.display_converged): the rule that ends a
run on convergence and times `time_to_converge_s`."""

from __future__ import annotations

import numpy as np

from sim.outputs.recorder import Convergence, display_converged
from transport.codec import Goals, Timing

TOL = 0.01


def goal_set(epoch: int, robots: list[int]) -> Goals:
    n = len(robots)
    return Goals(epoch, 0, np.zeros((n, 2)), np.zeros((n, 3), np.uint8), np.array(robots), Timing(0.0, 0, 10.0))


def on_goals(n: int) -> tuple[np.ndarray, np.ndarray]:
    goal = np.stack([np.arange(n, dtype=float), np.zeros(n)], axis=1)
    pose = np.concatenate([goal + 0.005, np.zeros((n, 1))], axis=1)  # 7 mm off: within tolerance
    return pose, goal


def test_every_live_robot_on_a_goal_of_the_newest_set_is_converged():
    pose, goal = on_goals(4)
    alive = np.ones(4, bool)
    assert display_converged(pose, goal, np.full(4, 2), alive, goal_set(2, [0, 1, 2, 3]), TOL)
    assert display_converged(pose, goal, np.zeros(4, int), alive, None, TOL)  # per-robot goals: no goal sets


def test_a_robot_off_its_goal_or_on_an_older_set_is_not_converged():
    pose, goal = on_goals(4)
    alive = np.ones(4, bool)
    far = pose.copy()
    far[2, 0] += 0.02
    assert not display_converged(far, goal, np.full(4, 2), alive, goal_set(2, [0, 1, 2, 3]), TOL)
    assert not display_converged(pose, goal, np.array([2, 2, 1, 2]), alive, goal_set(2, [0, 1, 2, 3]), TOL)
    no_goal = goal.copy()
    no_goal[1] = np.nan
    assert not display_converged(pose, no_goal, np.full(4, 2), alive, goal_set(2, [0, 1, 2, 3]), TOL)


def test_a_goal_set_that_still_holds_a_dead_robot_is_not_the_display_for_the_robots_left():
    # robot 3 died: the survivors still sit on the goals of the set for four, so the display waits for
    # the coordinator's set for three (paper 5.1.2) instead of ending on the old picture
    pose, goal = on_goals(4)
    alive = np.array([True, True, True, False])
    assert not display_converged(pose, goal, np.full(4, 1), alive, goal_set(1, [0, 1, 2, 3]), TOL)
    assert display_converged(pose, goal, np.array([2, 2, 2, 1]), alive, goal_set(2, [0, 1, 2]), TOL)


def test_a_run_recorded_as_converged_ends_converged_whatever_the_world_ran_on_to():
    """A recorder behind the world (a loaded machine) sees the hold end after the world ran to its
    duration: the recording ends at the converged tick, and so does the run's reason."""
    progress = Convergence(TOL, np.ones(4, bool))
    assert progress.end_reason("duration") == "duration"  # never held converged
    progress.ended_at = 168
    assert progress.end_reason("duration") == "converged"
    assert progress.end_reason("world exited with code 1") == "world exited with code 1"
