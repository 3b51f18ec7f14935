"""Measures and writers of a run's outputs that only tests and benchmarks use (the runs themselves do not):
contact events, keyframe errors, one frame of the video, a compressed .npz, a JSON message in an MCAP log and
a closed log's messages in log-time order, whether the web view serves."""

from __future__ import annotations

import os
import urllib.request
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader

from sim.outputs.mcaplog import McapLog, _Decoders
from sim.outputs.metrics import _pose_shape, _radius
from sim.outputs.render import _draw, _View
from sim.outputs.rundir import dumps_json, write_npz_streamed


def contact_events(pose: np.ndarray, radius: np.ndarray) -> int:
    """Pair-contact events: pairs overlapping at a sample (the first too) but not at the one before."""
    T, N = _pose_shape(pose)
    pose = np.asarray(pose, dtype=float)
    r = _radius(radius, N)
    if N < 2:
        return 0
    from scipy.spatial import cKDTree

    rmax = float(r.max())
    prev: set[tuple[int, int]] = set()
    events = 0
    for k in range(T):
        xy = pose[k, :, :2]
        ok = np.flatnonzero(np.isfinite(xy).all(axis=1))
        cur: set[tuple[int, int]] = set()
        if len(ok) >= 2:
            pairs = cKDTree(xy[ok]).query_pairs(2 * rmax, output_type="ndarray")
            i, j = ok[pairs[:, 0]], ok[pairs[:, 1]]
            hit = np.sqrt(((xy[i] - xy[j]) ** 2).sum(-1)) - r[i] - r[j] < 0
            cur = set(zip(i[hit].tolist(), j[hit].tolist()))
        events += len(cur - prev)
        prev = cur
    return events


def keyframe_errors(
    traj: Mapping[str, np.ndarray], step_starts: list[float], frame_periods: list[float], v_max: float
) -> list[np.ndarray]:
    """Per keyframe of a distributed animation (paper 6.2), from trajectory.npz's arrays: each robot's distance
    to its goal when K_f dt is over, if v_max allowed the move from where it got that goal (else NaN)."""
    t, pose = traj["t"], traj["pose"][:, :, :2]
    epochs = [int(e) for e in traj["goal_set_epochs"]]
    steps = [int(s) for s in traj["goal_set_steps"]]
    assignment, epoch = traj["assignment"], traj["assignment_epoch"]
    out = []
    for f, (start, period) in enumerate(zip(step_starts, frame_periods)):
        errors = np.full(pose.shape[1], np.nan)
        sets = [e for e, s in zip(epochs, steps) if s == f]
        end = int(np.argmin(np.abs(t - (start + period))))
        if sets:
            e = sets[-1]
            goals = traj["goal_sets"][epochs.index(e)]
            for i in range(pose.shape[1]):
                # its goal of this keyframe as last announced by K_f dt (the next keyframe's goal set
                # may already have reached it in the sample at K_f dt)
                rows = np.flatnonzero((epoch[:, i] == e) & (t >= start - 1e-9) & (t <= t[end] + 1e-9))
                if not len(rows):
                    continue
                got, goal = int(rows[0]), goals[assignment[rows[-1], i]]
                left = t[end] - t[got]
                if left > 0 and np.hypot(*(pose[got, i] - goal)) / left <= v_max:
                    errors[i] = np.hypot(*(pose[end, i] - goal))
        out.append(errors)
    return out


def render_frame(
    time_s: float | None,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None,
    arena: Sequence[float],
    obstacles: Sequence[Sequence[Sequence[float]]] | None = (),
    goal: np.ndarray | None = None,
    size_px: int = 720,
) -> np.ndarray:
    """One BGR frame whose longer arena side spans ``size_px`` pixels with a margin (``color`` None: white)."""
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (len(pose),))
    view = _View(arena, size_px)
    return _draw(view.background(obstacles), view, time_s, pose, radius, color, goal)


def write_npz(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write arrays to a compressed ``.npz`` exactly at ``path``, atomically; object arrays are refused."""
    return write_npz_streamed(path, arrays.items())


def log_json(log: McapLog, channel_id: int, log_time_ns: int, payload: Any) -> None:
    """Write a dict on a JSON channel of ``log`` (NaN -> null)."""
    log.write_bytes(channel_id, log_time_ns, dumps_json(payload).encode("utf-8"))


def logged(path: str | os.PathLike, topics: Iterable[str]) -> list[tuple[int, str, Any]]:
    """(log time ns, topic, decoded message) of these topics of a closed file, in log-time order."""
    with open(path, "rb") as fh:
        messages = make_reader(fh, decoder_factories=[_Decoders()]).iter_decoded_messages(topics=sorted(topics))
        return [(m.log_time, c.topic, decoded) for _, c, m, decoded in messages]


def url_serves(url: str) -> bool:
    """Whether the page answers (the web viewer is up)."""
    with urllib.request.urlopen(url, timeout=10) as response:
        return bool(response.status == 200)
