"""The once-a-second progress line of a distributed run (sim.run.launcher.progress_line)."""

from __future__ import annotations

from sim.run.launcher import progress_line


def test_before_the_goal_set_arrives_the_line_says_so_instead_of_counting_zero_of_zero():
    line = progress_line("picture", 0.4, 0, 0, 0.21, 0)
    assert "0/0" not in line and "waiting for the goal set" in line
    assert line == "[picture] t=   0.4 s  waiting for the goal set  min clearance +0.210 m  contacts 0"


def test_once_robots_have_goals_it_counts_those_at_their_goal():
    line = progress_line("paper-sequence", 12.0, 9, 14, 0.042, 0)
    assert line == "[paper-sequence] t=  12.0 s  at goal 9/14  min clearance +0.042 m  contacts 0"
