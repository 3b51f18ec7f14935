"""Overload degrades to slow, never to contact: late commands stop their bodies, and an agent that
acts late on its pose plans for the distance its body may have strayed meanwhile."""

from __future__ import annotations

import pytest

from agent.clocks import Lateness, strayed
from agent.core.params import EPUCK
from tests.conftest import run_scene


def test_lateness_is_the_pose_age_beyond_the_quickest_seen_and_runs_out_with_the_command():
    late = Lateness(EPUCK.dt, EPUCK.command_margin)
    assert late.at(0.0, 5.0) == 0.0  # nothing seen yet: no reference
    for tick in range(5):  # poses taken 20 ms after their stamp (plus a wall-clock offset of 100 s)
        late.arrived(tick * 0.1, 100.0 + tick * 0.1 + 0.02)
    assert late.at(0.4, 100.42) == pytest.approx(0.0)
    assert late.at(0.4, 100.50) == pytest.approx(0.08)
    # later than one period and the command margin: the command never drives, its body stands
    assert late.at(0.4, 101.0) == pytest.approx(EPUCK.dt + EPUCK.command_margin)
    assert late.worst == pytest.approx(EPUCK.dt + EPUCK.command_margin)
    assert late.mean == pytest.approx((0.0 + 0.08 + EPUCK.dt + EPUCK.command_margin) / 3)
    assert strayed(0.08, EPUCK.v_max) == pytest.approx(2 * EPUCK.v_max * 0.08)


def test_a_quick_pose_lowers_the_reference_and_a_slow_spell_ages_out():
    late = Lateness(0.1, 0.05, window=3)
    for tick, delay in enumerate([0.05, 0.01, 0.05, 0.05, 0.05]):
        late.arrived(tick * 0.1, tick * 0.1 + delay)
    # the quick pose (10 ms) has left the window of 3: 50 ms is the transport's latency now
    assert late.at(0.5, 0.55) == pytest.approx(0.0)


def _run(tmp_path, faults: str, duration: str, name: str) -> dict:
    m, _ = run_scene(
        tmp_path,
        "circle",
        "--robots",
        "20",
        "--clock",
        "realtime",
        "--duration",
        duration,
        "--seed",
        "3",
        "--faults",
        faults,
        name=name,
        timeout=120,
    )
    return m


@pytest.mark.slow
@pytest.mark.serial
def test_commands_late_past_their_period_stop_the_bodies_without_contact(tmp_path):
    m = _run(tmp_path, "cmd:delay=0.15", "3", "late")
    assert m["agent_processes"] == 20 and m["crashes"] == []
    assert m["contacts"] == 0 and m["max_overlap_m"] == 0.0
    # the delay reached the bodies: commands arrived after their period and the margin, and stopped them
    assert m["expired_commands"] > 0 and m["stopped_ticks"] > 0


@pytest.mark.slow
@pytest.mark.serial
def test_poses_and_commands_late_by_chance_drive_some_ticks_and_stop_others_without_contact(tmp_path):
    # poses up to 80 ms late: agents act late and plan for it; commands up to 80 ms late: some drive
    # (late), some arrive after the next one, some run out
    m = _run(tmp_path, "pose:jitter=0.08;cmd:jitter=0.08", "6", "jitter")
    assert m["agent_processes"] == 20 and m["crashes"] == []
    assert m["contacts"] == 0 and m["max_overlap_m"] == 0.0
    assert m["expired_commands"] > 0 and m["commands_applied"] > 20 * 5  # the robots did drive
