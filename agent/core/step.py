"""One control step for a batch of robots: preferred velocity, collision avoidance, wheel commands.

Pure: arrays in, arrays out. The same function serves one robot in its own process, K robots in an
agent host, and the central engine that steps every robot with perfect information.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import DIFFDRIVE, RobotParams


@dataclass
class Neighbours:
    """What a batch of B robots knows of up to M neighbours each (padded; ``valid`` marks real ones)."""

    position: np.ndarray  # (B,M,2) as last broadcast
    velocity: np.ndarray  # (B,M,2) their collision-free velocity
    radius: np.ndarray  # (B,M)
    age: np.ndarray  # (B,M) seconds since the state was stamped (from message stamps, never a wall clock)
    valid: np.ndarray  # (B,M) bool

    @classmethod
    def empty(cls, batch: int, m: int = 0) -> "Neighbours":
        return cls(np.zeros((batch, m, 2)), np.zeros((batch, m, 2)), np.ones((batch, m)), np.zeros((batch, m)),
                   np.zeros((batch, m), bool))


@dataclass
class StepResult:
    velocity: np.ndarray  # (B,2) collision-free holonomic velocity v_cf (broadcast to neighbours)
    command: np.ndarray  # (B,2) holonomic (vx, vy) or wheel speeds (v_left, v_right)
    pref_velocity: np.ndarray  # (B,2) eq. 9
    fallback: np.ndarray  # (B,) bool: the LP was infeasible and the fallback ran
    radius: np.ndarray  # (B,) radius announced to neighbours (r + tracking error for differential drive)


def preferred_velocity(position: np.ndarray, goal: np.ndarray, v_pref: float, k_a: float) -> np.ndarray:
    """Paper eq. 9: V_p min(1, |g - p| / K_a) (g - p)/|g - p|; zero where there is no goal (NaN)."""
    delta = goal - position
    dist = np.hypot(delta[:, 0], delta[:, 1])
    has = np.isfinite(dist) & (dist > 0)
    scale = np.where(has, v_pref * np.minimum(1.0, np.where(has, dist, 0) / k_a) / np.where(has, dist, 1), 0.0)
    return np.where(has[:, None], delta * scale[:, None], 0.0)


def control_step(params: RobotParams, position: np.ndarray, heading: np.ndarray, velocity: np.ndarray,
                 goal: np.ndarray, neighbours: Neighbours) -> StepResult:
    """Preferred velocity toward the goal, then the kinematic mapping (collision avoidance: issue 3)."""
    pref = preferred_velocity(position, goal, params.v_pref, params.k_a)
    speed = np.hypot(pref[:, 0], pref[:, 1])
    v_cf = pref * np.minimum(1.0, params.v_max / np.maximum(speed, 1e-12))[:, None]
    fallback = np.zeros(len(position), bool)
    radius = np.full(len(position), params.radius)
    if params.kinematics == DIFFDRIVE:
        command = wheel_speeds(v_cf, heading, params)
    else:
        command = v_cf
    return StepResult(v_cf, command, pref, fallback, radius)


def wheel_speeds(v_h: np.ndarray, heading: np.ndarray, params: RobotParams) -> np.ndarray:
    """NH-ORCA controls (paper 5.4): omega = sign(theta) min(|theta|/T, omega_max),
    v = min(v*_E, v_max - |omega| l_w / 2), as linear wheel speeds (v_left, v_right)."""
    speed = np.hypot(v_h[:, 0], v_h[:, 1])
    moving = speed > 1e-9
    theta = np.where(moving, np.arctan2(v_h[:, 1], v_h[:, 0]) - heading, 0.0)
    theta = (theta + np.pi) % (2 * np.pi) - np.pi
    omega = np.sign(theta) * np.minimum(np.abs(theta) / params.t_orient, params.omega_max)
    # error-minimising speed v*_E = v_H theta sin(theta) / (2 (1 - cos theta)), -> v_H as theta -> 0
    small = np.abs(theta) < 1e-6
    safe = np.where(small, 1.0, theta)
    v_star = np.where(small, speed, speed * safe * np.sin(safe) / (2 * (1 - np.cos(safe))))
    v = np.minimum(v_star, params.v_max - np.abs(omega) * params.wheel_base / 2)
    v = np.maximum(v, 0.0)
    half = omega * params.wheel_base / 2
    return np.stack([v - half, v + half], axis=1)
