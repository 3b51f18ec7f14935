"""Writing a finished run: metrics, trajectory, plots, video and the scene, then the atomic commit."""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from agent.core.params import RobotParams
from coordinator.resolved import save_resolved
from coordinator.scene import Scene
from sim.outputs.metrics import (
    Steps,
    Traffic,
    TrueRecord,
    assignment_over_optimum,
    clearance_over_time,
    communication_parts,
    summarise,
)
from sim.outputs.rundir import RunDir, write_json, write_npz_streamed
from sim.outputs.stream import FLOAT32_FROM, PER_TICK, SCRATCH, OnDisk

if TYPE_CHECKING:  # the renderers load matplotlib, OpenCV and PyAV: imported only where used
    from sim.outputs.render import Recording

INCOMPLETE = "INCOMPLETE"  # the marker file of a run directory whose run did not run its course

# pixels times frames of display.mp4 above which it plays faster than real time (its cost grows with both)
VIDEO_PIXEL_BUDGET = 6e9
FRAMES_SAID_EVERY = 5.0  # s between progress lines while display.mp4 is written


def write_trajectory(path: Path, arrays: dict[str, Any], radius: np.ndarray) -> Path:
    """trajectory.npz, arrays column-major (a robot's successive ticks adjacent, for deflate to store a robot at
    rest once), per-tick floats as float32 from :data:`FLOAT32_FROM` robots."""
    single = radius.shape[0] >= FLOAT32_FROM

    def stored() -> Iterator[tuple[str, Any]]:  # one copy at a time
        yield "radius", radius
        for name, a in arrays.items():
            a = a if isinstance(a, OnDisk) else np.asarray(a)
            kind = np.float32 if single and name in PER_TICK else a.dtype
            yield name, ColumnMajor(a, kind) if isinstance(a, OnDisk) else np.asarray(a, kind, order="F")

    return write_npz_streamed(path, stored())


class ColumnMajor:
    """An array on disk as trajectory.npz stores it (column-major, in ``dtype``), written a block of robots at once."""

    BLOCK_BYTES = 1 << 26  # of one block of robots' values over every tick

    def __init__(self, array: OnDisk, dtype: Any) -> None:
        self.array, self.dtype = array, np.dtype(dtype)

    def write(self, out: Any) -> None:
        a, (ticks, robots, *rest) = self.array, self.array.shape
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": True, "shape": a.shape}
        np.lib.format.write_array_header_1_0(out, header)
        block = max(1, self.BLOCK_BYTES // max(1, ticks * a.dtype.itemsize * int(np.prod(rest, dtype=int))))
        for last in np.ndindex(*rest[::-1]):  # the trailing axes, the last one slowest
            for first in range(0, robots, block):
                values = a[(slice(None), slice(first, first + block), *last[::-1])]
                out.write(np.ascontiguousarray(values.T, self.dtype).tobytes())


def newest_goal_set(arrays: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """Per tick, the newest goal set's robots and whose announced goal comes from it (T,N); None without goal sets."""
    if "goal_set_epoch" not in arrays:
        return None
    epochs = list(arrays["goal_set_epochs"])
    newest = arrays["goal_set_epoch"]  # (T,)
    rows = np.array([epochs.index(e) if e in epochs else -1 for e in newest])
    members = np.where(rows[:, None] >= 0, arrays["goal_set_robots"][np.maximum(rows, 0)], False)
    current = arrays["assignment_epoch"] == newest[:, None]
    return members, current


def goal_set_arrays(by_epoch: Mapping[int, Any], robots: int) -> dict[str, np.ndarray]:
    """The goal sets by epoch as trajectory.npz keeps them (every engine): positions padded with NaN to the
    largest set, colours, who takes part, and the scene step each shows."""
    epochs = sorted(by_epoch)
    g_max = max(len(by_epoch[e].positions) for e in epochs)
    goal_sets = np.full((len(epochs), g_max, 2), np.nan)
    colors = np.zeros((len(epochs), g_max, 3), np.uint8)
    members = np.zeros((len(epochs), robots), bool)
    for i, e in enumerate(epochs):
        gs = by_epoch[e]
        goal_sets[i, : len(gs.positions)] = gs.positions
        colors[i, : len(gs.colors)] = gs.colors
        members[i, gs.robots[gs.robots < robots]] = True
    return {
        "goal_set_epochs": np.array(epochs),
        "goal_sets": goal_sets,
        "goal_set_colors": colors,
        "goal_set_robots": members,
        "goal_set_steps": np.array([by_epoch[e].timing.step for e in epochs]),
    }


@dataclass
class RunOutcome:
    """How a run went beside its trajectory: ``reach`` the robots' communication range (m), ``extra`` further
    metrics.json keys (``complete=False`` writes the INCOMPLETE marker)."""

    wall_s: float
    contacts: list[dict[str, Any]]
    traffic: Traffic | None = None
    reach: float = np.inf
    extra: dict[str, Any] = field(default_factory=dict)


def recording_of(
    scene: Scene, arrays: dict[str, Any], radius: np.ndarray, ticks: np.ndarray | slice | None = None
) -> Recording:
    """The run's trajectory arrays at these ticks (None: all, on disk ones staying there) as the writers draw them."""
    from sim.outputs.render import Recording

    pick = {k: arrays[k] if ticks is None else arrays[k][ticks] for k in ("t", "pose", "goal", "color")}
    return Recording(pick["t"], pick["pose"], radius, scene.arena, scene.obstacles, pick["goal"], pick["color"])


def write_run(
    run_dir: RunDir,
    scene: Scene,
    params: RobotParams,
    arrays: dict[str, Any],
    outcome: RunOutcome,
    *,
    video: bool,
    plots: bool,
    progress: TextIO | None = None,
) -> Path:
    """Everything a run directory holds, from the true trajectory; returns the committed path. ``progress``
    hears that the writing began and how the video comes along (the longest part of a large run's writing)."""
    if progress is not None:
        end = outcome.extra.get("end_reason")
        print(f"[{scene.name}] run ended ({end}); writing {run_dir.final_path.name}", file=progress, flush=True)
    radius = np.full(scene.robots, params.radius)
    t = arrays["t"]
    # trajectory.npz on a thread (deflate and the disk free the GIL) beside the metrics and drawings
    with ThreadPoolExecutor(1, thread_name_prefix="trajectory") as writer:
        trajectory = writer.submit(write_trajectory, run_dir / "trajectory.npz", arrays, radius)
        clearance = clearance_over_time(arrays["pose"], radius) if len(t) else np.zeros(0)
        metrics = _run_metrics(scene, params, arrays, outcome, radius, clearance)
        write_json(run_dir / "metrics.json", metrics)
        if outcome.extra.get("complete") is False:  # the INCOMPLETE marker: why it ended early (or failed to start)
            why = [outcome.extra.get("end_reason") or "incomplete", outcome.extra.get("startup_failure")]
            (run_dir / INCOMPLETE).write_text("".join(f"{line}\n" for line in why if line))
        if len(t) and plots:
            from sim.outputs.render import write_plots

            write_plots(run_dir.path, recording_of(scene, arrays, radius), clearance)
        if len(t) and video:
            said = _frames_said(progress, f"[{scene.name}] display.mp4")
            _write_display_video(run_dir, scene, arrays, radius, metrics.get("time_to_converge_s"), said)
        trajectory.result()  # its error, if any, is the run's
    save_resolved(scene, run_dir.path, robot=params.to_dict())  # scene.json, goal_sets.npz
    shutil.rmtree(run_dir / SCRATCH, ignore_errors=True)  # a streamed recording's raw files (sim.outputs.stream)
    return run_dir.commit()


def _run_metrics(
    scene: Scene,
    params: RobotParams,
    arrays: dict[str, Any],
    outcome: RunOutcome,
    radius: np.ndarray,
    clearance: np.ndarray,
) -> dict[str, Any]:
    """metrics.json: the true record's summary, splits by the communication range, assignments over the optimum."""
    keys: dict[str, Any] = dict(
        scene=scene.name, seed=scene.seed, clock=scene.clock, contact_events=outcome.contacts, **outcome.extra
    )
    if np.isfinite(outcome.reach):
        parts = communication_parts(arrays["pose"], outcome.reach)
        keys.update(range_m=outcome.reach, split_ticks=int((parts > 1).sum()), most_parts=int(parts.max(initial=1)))
    members, current = newest_goal_set(arrays) or (None, None)
    steps = None if arrays.get("step") is None else Steps(arrays["step"], current=current, members=members)
    record = TrueRecord(arrays["t"], arrays["pose"], radius, arrays["goal"], params.goal_tolerance, clearance, steps)
    metrics = summarise(record, wall_s=outcome.wall_s, contacts=len(outcome.contacts), traffic=outcome.traffic, **keys)
    if scene.steps and "assignment" in arrays and arrays.get("step") is not None and metrics.get("steps"):
        over = assignment_over_optimum(arrays["pose"], arrays["goal"], arrays["assignment"], arrays["step"])
        for entry, value in zip(metrics["steps"], over):
            entry["assignment_over_optimum_m2"] = value
    return metrics


def _frames_said(out: TextIO | None, what: str) -> Callable[[int, int], None] | None:
    """A progress line for ``what`` every :data:`FRAMES_SAID_EVERY` s of writing, and one at its end."""
    if out is None:
        return None
    last = time.monotonic()

    def say(done: int, frames: int) -> None:
        nonlocal last
        if done == frames or time.monotonic() - last >= FRAMES_SAID_EVERY:
            last = time.monotonic()
            print(f"{what}: {done} of {frames} frames", file=out, flush=True)

    return say


def _write_display_video(
    run_dir: RunDir,
    scene: Scene,
    arrays: dict[str, Any],
    radius: np.ndarray,
    formed: float | None,
    progress: Callable[[int, int], None] | None,
) -> None:
    """display.mp4 at real time (or faster, :data:`VIDEO_PIXEL_BUDGET`), holding the final picture once the display
    ``formed`` (s from the start; None: never), telling ``progress`` of its frames. No encoder here: a warning."""
    from sim.outputs.render import frame_indices, held_frames, video_size, write_video

    t = arrays["t"]
    size = video_size(scene.arena, radius)
    # real time, unless its frames at real time exceed the budget
    over = len(frame_indices(t, 10, max_frames=0)) * size * size / VIDEO_PIXEL_BUDGET
    speed = 1.0 if over <= 1 else float(np.ceil(over))
    idx = held_frames(t, None if formed is None else float(t[0]) + formed, speed=speed)
    try:
        frames = recording_of(scene, arrays, radius, idx)
        write_video(run_dir / "display.mp4", frames, size_px=size, speed=None, max_frames=0, progress=progress)
    except RuntimeError as err:  # no encoder here: the run's data matter more than its video
        print(f"pixelswarm: warning: no display.mp4: {err}", file=sys.stderr)
