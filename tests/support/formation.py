"""When is an image formed? From a distributed run's trajectory.npz: at each tick, every robot of the
newest goal set is within a tolerance of the goal it announced from that set (the rule of
metrics.json's `steps[].converged_at`, tick by tick, so recoveries after a perturbation can be timed)."""

from __future__ import annotations

import numpy as np

from sim.outputs.write import newest_goal_set


def members_and_current(traj: dict) -> tuple[np.ndarray, np.ndarray]:
    """(T, N) robots of the newest goal set at each tick, and whose announced goal comes from it."""
    sets = newest_goal_set(traj)
    assert sets is not None, "not a distributed image run: no goal sets recorded"
    members, current = sets
    return members.astype(bool), current


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


def assert_every_hold_formed(m: dict, tolerance: float = 0.01, traj: dict | None = None) -> None:
    assert m["contacts"] == 0, m["contact_events"][:5]
    for step in m["steps"]:
        why = f"{step}; {why_not_formed(m, traj, tolerance)}" if traj is not None else step
        assert step["converged_at"] is not None, why
        assert step["max_goal_error_at_end"] <= tolerance, why


def why_not_formed(m: dict, traj: dict, tolerance: float) -> str:
    """What a failed hold looked like at the run's last sample (CI prints only the message): the
    robots off their goals, whose assignment gave each goal and when it last changed, and the run's
    goal sets, agreements, lost liveliness and end."""
    t, err = traj["t"], np.hypot(*(traj["pose"][:, :, :2] - traj["goal"]).transpose(2, 0, 1))
    off = [int(r) for r in np.flatnonzero(err[-1] > tolerance)]
    rows = []
    for r in off[:5]:
        key = np.stack([traj["assignment_epoch"][:, r], traj["assignment_instance"][:, r], traj["assignment"][:, r]], 1)
        changes = np.flatnonzero((key[1:] != key[:-1]).any(axis=1)) + 1
        goal_changes = np.flatnonzero(traj["assignment"][1:, r] != traj["assignment"][:-1, r]) + 1
        rows.append(
            f"robot {r}: {err[-1, r]:.3f} m off goal {key[-1, 2]} (epoch {key[-1, 0]}, instance {key[-1, 1]}),"
            f" goal changed at t={[round(float(t[i]), 1) for i in goal_changes[-4:]]},"
            f" assignment at t={[round(float(t[i]), 1) for i in changes[-3:]]}"
        )
    return (
        f"end {m.get('end_reason')} at t={float(t[-1]):.1f}; goal sets {[int(e) for e in traj['goal_set_epochs']]};"
        f" agreements {len(traj['agreements'])}; liveliness lost {m.get('liveliness_lost')};"
        f" off goal at the end: {rows or 'none'}"
    )
