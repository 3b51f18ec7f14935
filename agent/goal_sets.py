"""A goal set's message as the robot policy takes it: its timing and its motion (paper 6.2, 7.4.1)."""

from __future__ import annotations

from transport.codec import Goals

from .core.goal_motion import GoalMotion
from .core.policy import GoalTiming


def motion_of(goals: Goals) -> GoalMotion | None:
    """The motion of a goal set (eq. 28) from its message; None for a still one."""
    m = goals.motion
    if m is None or not m.moves:
        return None
    return GoalMotion((m.v_gx, m.v_gy), m.omega_g, (m.p_ogx, m.p_ogy), m.k_eg, bool(m.geometric))


def timing_of(goals: Goals) -> GoalTiming:
    """When a goal set's step began, its keyframe period and its motion."""
    return GoalTiming(goals.timing.t_start, goals.timing.frame_period, motion_of(goals))
