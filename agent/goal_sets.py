"""A goal set's message as the robot policy takes it: its timing and its motion (paper 6.2, 7.4.1)."""

from __future__ import annotations

from transport.codec import Goals

from .core.goal_motion import GoalMotion
from .core.policy import GoalTiming


def motion_of(goals: Goals) -> GoalMotion | None:
    """The motion of a goal set (eq. 28) from its message; None for a still one."""
    if not goals.moves:
        return None
    return GoalMotion(
        (goals.v_gx, goals.v_gy), goals.omega_g, (goals.p_ogx, goals.p_ogy), goals.k_eg, bool(goals.geometric)
    )


def timing_of(goals: Goals) -> GoalTiming:
    """When a goal set's step began, its keyframe period and its motion."""
    return GoalTiming(goals.t_start, goals.frame_period, motion_of(goals))
