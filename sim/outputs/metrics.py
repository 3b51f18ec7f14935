"""Run metrics from true world poses: ``t`` (T,), ``pose`` (T,N,3), ``radius`` (N,), ``goal`` (T,N,2) (NaN:
none); a robot without a finite position at a sample is ignored there."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.bodies.proximity import close_pairs


def _radius(radius: Any, n: int) -> np.ndarray:
    r = np.asarray(radius, dtype=float)
    return np.broadcast_to(r, (n,)).astype(float) if r.ndim == 0 else r.reshape(n)


# elements of a (ticks x robots) temporary built at once: a long run's stay small, results the same to the bit
CHUNK = 1 << 20


def _pose_shape(pose: Any) -> tuple[int, int]:
    """(T, N) of a (T, N, >=2) pose array, without a float64 copy of all of it."""
    shape = np.shape(pose)
    if len(shape) != 3 or shape[2] < 2:
        raise ValueError(f"pose must have shape (T, N, 3), got {shape}")
    return shape[0], shape[1]


def tick_chunks(ticks: int, robots: int) -> list[slice]:
    """Ticks in slices of at most :data:`CHUNK` tick-robot elements (one tick at least)."""
    step = max(1, CHUNK // max(robots, 1))
    return [slice(a, min(a + step, ticks)) for a in range(0, ticks, step)]


def _xy(pose: Any, ticks: int | slice | np.ndarray) -> np.ndarray:
    return np.asarray(pose[ticks, :, :2], dtype=float)


def _moved(pose: Any, rows: np.ndarray) -> np.ndarray:
    """(len(rows), N): each robot's xy step from tick r to r + 1, for each r of ``rows``."""
    return np.sqrt(((_xy(pose, rows + 1) - _xy(pose, rows)) ** 2).sum(-1))


def _pairwise_nansum(rows: np.ndarray, n: int, values: Any) -> float:
    """``np.nansum`` of ``values(rows)`` (len(rows), n) to the bit, built :data:`CHUNK` elements at a time: halved
    as numpy's pairwise sum halves it (at a multiple of 8, down to blocks of 128)."""

    def part(lo: int, hi: int) -> float:
        if hi - lo > max(CHUNK, 128):  # numpy's blocks of 128 are not halved
            half = (hi - lo) // 2
            half -= half % 8
            return part(lo, lo + half) + part(lo + half, hi)
        first, last = lo // n, (hi - 1) // n
        flat = values(rows[first : last + 1]).reshape(-1)[lo - first * n : hi - first * n]
        return np.nansum(flat)

    return float(part(0, len(rows) * n)) if len(rows) and n else 0.0


NEAR = 0.1  # m: clearance_at looks first at the pairs within this of touching


def clearance_at(xy: np.ndarray, radius: np.ndarray) -> float:
    """Minimum over pairs of ``|p_i - p_j| - r_i - r_j`` (+inf: fewer than 2 robots), exact: close pairs within a
    reach that grows until no pair beyond it could beat the smallest found."""
    xy = np.asarray(xy, dtype=float)[:, :2]
    radius = np.asarray(radius, dtype=float)
    ok = np.isfinite(xy).all(axis=1)
    if not ok.all():
        xy, radius = xy[ok], radius[ok]
    if len(xy) < 2:
        return float("inf")
    rmax = float(radius.max())
    span = float(np.hypot(*(xy.max(axis=0) - xy.min(axis=0))))  # every pair is within this
    reach = 2 * rmax + NEAR
    while True:
        got = close_pairs(xy[None], radius, reach, 0.0, 0)
        assert got is not None  # no budget given
        # a pair of clearance c is within reach if c <= reach - 2 rmax
        if got[0] <= reach - 2 * rmax or reach > span:
            return got[0]
        reach *= 4


def clearance_over_time(pose: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(T,) :func:`clearance_at` per sample: negative is overlap (contact)."""
    pose = pose if hasattr(pose, "shape") else np.asarray(pose, dtype=float)
    T, N = _pose_shape(pose)
    r = _radius(radius, N)
    out = np.full(T, np.inf)
    if N < 2:
        return out
    for ticks in tick_chunks(T, 2 * N):  # a piece at a time: the poses may be on disk (sim.outputs.stream)
        for k, xy in enumerate(_xy(pose, ticks), ticks.start):
            out[k] = clearance_at(xy, r)
    return out


def communication_parts(pose: np.ndarray, reach: float) -> np.ndarray:
    """Per tick: the parts of the graph of robots within ``reach`` (positions as the wire carries them)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    out = np.ones(len(pose), np.int64)
    for k in range(len(pose)):  # one tick's positions at a time, as the wire carries them
        xy = np.asarray(pose[k, :, :2], np.float32).astype(float)
        pairs = cKDTree(xy).query_pairs(reach, output_type="ndarray")
        n = len(xy)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        out[k] = connected_components(graph, directed=False)[0]
    return out


# robots above which the optimum (N^2 costs, O(N^3) time) is left to bench.bench_auction: a run's metrics say None
OPTIMUM_UP_TO = 3000


def assignment_over_optimum(pose: np.ndarray, goal: np.ndarray, assignment: np.ndarray, step: np.ndarray) -> list:
    """Per image step: the cost (m^2, eq. 5-7) of the assignment at its first tick over the optimum, or None
    where that is not one goal per robot or there are more than OPTIMUM_UP_TO robots."""
    from scipy.optimize import linear_sum_assignment

    def over(first: int) -> float | None:
        a, xy, g = assignment[first], pose[first, :, :2], goal[first]
        one_goal_each = (a >= 0).all() and (a < len(g)).all() and len(np.unique(a)) == len(a)
        if len(a) > OPTIMUM_UP_TO or not one_goal_each or not np.isfinite(g).all():
            return None
        goals = np.empty_like(g)
        goals[a] = g  # goal index -> where it is
        cost = ((xy[:, None, :] - goals[None]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(cost)
        return float(cost[np.arange(len(a)), a].sum() - cost[rows, cols].sum())

    firsts = [int(np.flatnonzero(step == k)[0]) for k in np.unique(step)]
    with ThreadPoolExecutor(len(os.sched_getaffinity(0))) as solvers:  # the solver frees the GIL
        return list(solvers.map(over, firsts))


def path_lengths(pose: np.ndarray) -> np.ndarray:
    """(N,) length of each robot's xy path (steps touching a non-finite sample are skipped)."""
    T, N = _pose_shape(pose)
    total = np.zeros(N)
    for ticks in tick_chunks(T - 1, N):
        step = _moved(pose, np.arange(ticks.start, ticks.stop))
        # numpy adds the rows of an axis-0 sum in order: the running total first keeps that order
        total = np.nansum(np.concatenate([total[None], np.where(np.isfinite(step), step, np.nan)]), axis=0)
    return total


def time_to_converge(t: np.ndarray, pose: np.ndarray, goal: np.ndarray, tolerance: float) -> float | None:
    """First ``t[k]`` from which on every robot with a goal is within ``tolerance`` of it; None if not at
    the end, or no robot has a goal at the end (robots that stand without one have reached nothing)."""
    t = np.asarray(t, dtype=float)
    T, N = _pose_shape(pose)
    if np.shape(goal) != (T, N, 2) or t.shape != (T,):
        raise ValueError(f"shapes: t {t.shape}, pose {np.shape(pose)}, goal {np.shape(goal)}")
    ok, some = _arrived(pose, goal, tolerance)
    if not T or not some[-1] or not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    k = 0 if len(bad) == 0 else int(bad[-1]) + 1
    return float(t[k])


def _arrived(pose: Any, goal: Any, tolerance: float, members: Any = None, current: Any = None) -> tuple[Any, Any]:
    """Per tick: every robot with a goal that counts (from ``current``'s set) at it, and whether any has one."""
    T, N = _pose_shape(pose)
    every, some = np.zeros(T, bool), np.zeros(T, bool)
    for ticks in tick_chunks(T, N):
        err, has_goal = _goal_errors(pose, goal, members, ticks)
        arrived = err <= tolerance if current is None else (err <= tolerance) & current[ticks]
        every[ticks] = np.where(has_goal, arrived, True).all(axis=1)
        some[ticks] = has_goal.any(axis=1)
    return every, some


def _goal_errors(pose: Any, goal: Any, members: np.ndarray | None, ticks: slice) -> tuple[np.ndarray, np.ndarray]:
    """At these ticks, each robot's distance to its goal (NaN: none, no pose, not a member) and whether it
    has a goal that counts, both (ticks, N)."""
    g = np.asarray(goal[ticks], dtype=float)
    err = np.sqrt(((_xy(pose, ticks) - g) ** 2).sum(-1))
    has_goal = np.isfinite(g).all(axis=2)
    if members is not None:
        has_goal = has_goal & members[ticks]
        err = np.where(members[ticks], err, np.nan)
    return err, has_goal


def step_metrics(
    t: np.ndarray,
    pose: np.ndarray,
    goal: np.ndarray,
    step: np.ndarray,
    tolerance: float,
    current: np.ndarray | None = None,
    members: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Per image step (``step`` (T,), negative: none): its times, convergence, goal errors at its end and path
    length. Distributed runs also give ``members`` (T, N), the newest goal set's robots (no other is waited
    for), and ``current`` (T, N), whose goal comes from that set."""
    t = np.asarray(t, dtype=float)
    T, N = _pose_shape(pose)
    step = np.asarray(step).astype(int).reshape(-1)
    if step.shape != t.shape or np.shape(goal) != (T, N, 2):
        raise ValueError(f"shapes: t {t.shape}, step {step.shape}, pose {np.shape(pose)}, goal {np.shape(goal)}")

    within = np.logical_and(*_arrived(pose, goal, tolerance, members, current))  # and some robot has a goal
    out = []
    for k in sorted(set(step[step >= 0].tolist()), key=lambda s: int(np.argmax(step == s))):
        idx = np.flatnonzero(step == k)
        first, last = int(idx[0]), int(idx[-1])
        ok = idx[within[idx]]
        err, has_goal = _goal_errors(pose, goal, members, slice(last, last + 1))
        at_end = err[0][has_goal[0]]
        known = bool(len(at_end) and np.isfinite(at_end).any())
        # Motion from each of the step's samples to the next one belongs to the step.
        legs = _pairwise_nansum(idx[idx < T - 1], N, lambda rows: _moved(pose, rows))
        out.append(
            {
                "index": int(k),
                "t_start": float(t[first]),
                "t_end": float(t[last]),
                "converged_at": float(t[ok[0]] - t[first]) if len(ok) else None,
                "max_goal_error_at_end": float(np.nanmax(at_end)) if known else None,
                "median_goal_error_at_end": float(np.nanmedian(at_end)) if known else None,
                "path_length_m": legs,
            }
        )
    return out


def _per_robot_second(values: Mapping[str, float], robots: int, duration_s: float) -> dict[str, float | None]:
    denom = robots * duration_s
    return {str(k): (float(v) / denom if denom > 0 else None) for k, v in values.items()}


@dataclass(frozen=True)
class Steps:
    """A run's image steps, as :func:`step_metrics` takes them."""

    step: np.ndarray
    current: np.ndarray | None = None
    members: np.ndarray | None = None


@dataclass(frozen=True)
class TrueRecord:
    """The world's true record of a run (``clearance``: if already computed; ``steps``: image steps)."""

    t: np.ndarray
    pose: np.ndarray
    radius: np.ndarray | Sequence[float]
    goal: np.ndarray | None = None
    tolerance: float = 0.05
    clearance: np.ndarray | None = None
    steps: Steps | None = None


@dataclass(frozen=True)
class Traffic:
    """What crossed the bus over the run: messages and bytes per kind, ticks missed, agents crashed."""

    counts: Mapping[str, int] = field(default_factory=dict)
    bytes: Mapping[str, int] = field(default_factory=dict)
    missed_ticks: int = 0
    agents_crashed: int = 0


def summarise(
    record: TrueRecord, *, wall_s: float, contacts: int, traffic: Traffic | None = None, **extra: Any
) -> dict[str, Any]:
    """The metrics.json dict (inf/NaN left for write_json to make null); ``extra`` keys are added, and may
    not replace a computed one."""
    t = np.asarray(record.t, dtype=float)
    # read a piece at a time below: the poses may be on disk (sim.outputs.stream)
    pose = record.pose if hasattr(record.pose, "shape") else np.asarray(record.pose, dtype=float)
    T, N = _pose_shape(pose)
    if t.shape != (T,):
        raise ValueError(f"t has shape {t.shape}, pose {np.shape(pose)}")
    duration = float(t[-1] - t[0]) if T else 0.0
    wall_s = float(wall_s)
    goal, traffic = record.goal, traffic or Traffic()
    converged = None if goal is None else time_to_converge(t, pose, goal, record.tolerance)
    out: dict[str, Any] = {
        "robots": int(N),
        "samples": int(T),
        "duration_s": duration,
        "wall_s": wall_s,
        "realtime_factor": (duration / wall_s) if wall_s > 0 else None,
        **_closeness(record, t, pose, N, contacts),
        "converged": converged is not None,
        "time_to_converge_s": None if converged is None else float(converged - t[0]),
        "convergence_tolerance_m": float(record.tolerance) if goal is not None else None,
        "path_length_m": path_lengths(pose).tolist(),
        "messages_per_robot_s": _per_robot_second(traffic.counts, N, duration),
        "bytes_per_robot_s": _per_robot_second(traffic.bytes, N, duration),
        "messages_total": {str(k): int(v) for k, v in traffic.counts.items()},
        "bytes_total": {str(k): int(v) for k, v in traffic.bytes.items()},
        "missed_ticks": int(traffic.missed_ticks),
        "agents_crashed": int(traffic.agents_crashed),
    }
    if (steps := record.steps) is not None and goal is not None:
        out["steps"] = step_metrics(t, pose, goal, steps.step, record.tolerance, steps.current, steps.members)
    if clash := set(extra) & set(out):
        raise ValueError(f"summarise: extra keys would replace computed ones: {sorted(clash)}")
    out.update(extra)
    return out


def _closeness(record: TrueRecord, t: np.ndarray, pose: Any, robots: int, contacts: int) -> dict[str, Any]:
    """How close the robots came: the least clearance and when, the contact events, the deepest overlap."""
    r = _radius(record.radius, robots)
    clr = clearance_over_time(pose, r) if record.clearance is None else np.asarray(record.clearance, dtype=float)
    finite = np.isfinite(clr)  # the least finite clearance and when (none: inf, None)
    k = int(np.argmin(np.where(finite, clr, np.inf))) if finite.any() else None
    min_clear = float("inf") if k is None else float(clr[k])
    return {
        "min_clearance_m": min_clear,
        "min_clearance_at_s": None if k is None else float(t[k] - t[0]),
        "contacts": int(contacts),
        "max_overlap_m": 0.0 if k is None else float(max(0.0, -min_clear)),
    }


def reported(fields: Any, name: str) -> int:
    """A count another process reported; a field it got wrong (anyone may publish on an open bus) counts as none."""
    value = fields.get(name) if isinstance(fields, dict) else None
    return value if type(value) is int and value > 0 else 0


def lockstep_waits_given_up(agent_stats: list[dict[str, Any]], world: dict[str, Any]) -> dict[str, int]:
    """Lock-step waits that ran out, by what was waited for: each let the machine's load, not the seed, shape
    the run (a missed tick is one too, counted apart)."""
    return {
        "neighbour_states": sum(reported(s.get("lockstep_gave_up"), "neighbour_states") for s in agent_stats),
        "goal_sets": sum(reported(s.get("lockstep_gave_up"), "goal_sets") for s in agent_stats),
        "auction_rounds": sum(reported(s.get("auction"), "abandoned_blocks") for s in agent_stats),
        "world_goal_sets": reported(world, "goal_sets_not_awaited"),
    }
