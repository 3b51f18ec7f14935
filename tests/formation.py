"""When is an image formed? From a distributed run's trajectory.npz: at each tick, every robot of the
newest goal set is within a tolerance of the goal it announced from that set (the rule of
metrics.json's `steps[].converged_at`, tick by tick, so recoveries after a perturbation can be timed)."""

from __future__ import annotations

import numpy as np

from sim.outputs.write import newest_goal_set


def members_and_current(traj: dict) -> tuple[np.ndarray, np.ndarray]:
    """(T, N) robots of the newest goal set at each tick, and whose announced goal comes from it."""
    sets = newest_goal_set(traj)
    return sets["step_members"].astype(bool), sets["step_current"]


def goal_error(traj: dict) -> np.ndarray:
    """(T, N) distance of every robot from its announced goal (NaN where it has none)."""
    d = traj["pose"][:, :, :2] - traj["goal"]
    return np.hypot(d[..., 0], d[..., 1])


def formed(traj: dict, tolerance: float = 0.01) -> np.ndarray:
    """(T,) True where every robot of the newest goal set is within `tolerance` of its goal from it."""
    members, current = members_and_current(traj)
    arrived = (goal_error(traj) <= tolerance) & current  # NaN compares False
    return np.where(members, arrived, True).all(axis=1) & members.any(axis=1)


def first_formed_after(traj: dict, t0: float, tolerance: float = 0.01) -> float | None:
    """Seconds from t0 until the image is formed again (the first formed tick at or after t0)."""
    t = traj["t"]
    ok = formed(traj, tolerance)
    after = np.flatnonzero((t >= t0 - 1e-9) & ok)
    return float(t[after[0]] - t0) if len(after) else None


def stays_formed_from(traj: dict, t0: float, tolerance: float = 0.01) -> bool:
    """The image is formed at every tick from t0 to the end of the run."""
    t = traj["t"]
    return bool(formed(traj, tolerance)[t >= t0 - 1e-9].all())
