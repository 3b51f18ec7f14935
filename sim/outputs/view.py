"""The live view of a swarm, and the replay of a finished run, in Rerun's viewer (``pixelswarm[view]``): all
robots as one entity whatever the swarm's size, logged in batches on a thread of the view's own (docs/cli.md,
``--view``), to Rerun's native or web viewer (on 127.0.0.1 only) or an ``.rrd`` file."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import sys
import threading
import time
import urllib.parse
import zipfile
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sim.outputs.metrics import clearance_at
from sim.processes import stop_on_sigterm, stop_processes
from transport.codec import Truth
from transport.session import free_port, listening

VIEW_FILE = "view.rrd"  # beside trajectory.npz
TRAIL = 10  # positions kept per robot's trail: every TRAIL_EVERY-th tick's
TRAIL_EVERY = 2
TRAIL_DOT = 0.004  # m, radius of a trail's dots
TRAIL_ALPHA = 90
QUEUE_TICKS = 1000  # ticks handed over and not yet logged, at most (then the run waits for the view)
FLUSH_PERIOD = 0.1  # s: the view logs what came in this long as one batch (it refreshes at 10 Hz)
FAST_FLUSH_PERIOD = 0.25  # s: the same after a batch of many ticks (a run too fast to watch tick by tick)
MAX_BATCH = 200  # ticks a batch at most
SLOW_BATCH = 3  # a batch of at most this many ticks is of a run near real time: everything logged at its last
EXTRAS_PERIOD = 0.5  # s of wall time between two logs of the rest (hover, trails, metrics) in a faster run
DOTS_ABOVE = 150  # robot diameters across the display above which robots are drawn as dots of a fixed size
DOT = 2.5  # their radius then, in the viewer's points (at true size they would be a pixel or less)
TRAIL_DOT_POINTS = 0.8  # a trail's dots then, in points
NOSE = 0.65  # the heading dot's centre, in radii from the robot's
NOSE_DOT = 0.3  # its radius, in robot radii
NOSE_COLOR = (20, 20, 20)
DRAW_ABOVE = 40.0  # draw order above the robots' discs (Rerun draws 2D points at 30)
GOAL_ALPHA = 70  # the goals are faint: the picture beneath the robots
LOOPBACK = "127.0.0.1"
DISPLAY = ("arena", "obstacles", "swarm")  # the entities drawn on the display (the rest are time series)
START_TIMEOUT = 30.0  # s for Rerun's server to listen
# trajectory.npz's arrays a replay draws, and their dimensions: T ticks, N robots
RUN_ARRAYS = {"t": ("T",), "pose": ("T", "N", 3), "color": ("T", "N", 3), "goal": ("T", "N", 2), "radius": ("N",)}


class ViewUnavailable(Exception):
    """rerun-sdk is not installed, or its viewer did not start: one line for the user."""


def _rerun() -> Any:
    try:
        import rerun
    except ImportError:
        raise ViewUnavailable("the view needs rerun-sdk: pip install 'pixelswarm[view]'") from None
    return rerun


def _wait_listening(port: int, proc: subprocess.Popen, timeout: float = START_TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ViewUnavailable(f"Rerun's viewer exited at start (code {proc.returncode})")
        if listening(port, LOOPBACK):
            return
        time.sleep(0.1)
    raise ViewUnavailable(f"Rerun's viewer did not listen on {LOOPBACK}:{port} within {timeout:g} s")


class _TickHandover:
    """The ticks the run hands over, logged by ``log`` a batch at a time on a thread of their own (a full
    queue makes the run wait: no tick is dropped)."""

    def __init__(self, log: Callable[[list[tuple[Any, ...]]], None]) -> None:
        self._log = log
        self.failure: str | None = None  # why the view stopped logging, if it did
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue(maxsize=QUEUE_TICKS)
        self._hurry = threading.Event()  # set by flush and close: log what there is without waiting for more
        self._logger = threading.Thread(target=self._drain, name="rerun-view", daemon=True)
        self._logger.start()
        self.put = self._queue.put  # a tick handed over

    def _drain(self) -> None:
        """Log batches of the ticks within FLUSH_PERIOD (FAST_FLUSH_PERIOD after a large batch), sleeping while
        they gather (waking at each tick would take the GIL from the run). A failure stops the view, not the run."""
        done, period = False, FLUSH_PERIOD
        while not done:
            items = [self._queue.get()]  # None: close
            if items[0] is not None and self._queue.qsize() < MAX_BATCH:
                self._hurry.wait(period)
            with contextlib.suppress(queue.Empty):
                while items[-1] is not None and len(items) < MAX_BATCH:
                    items.append(self._queue.get_nowait())
            done = items[-1] is None
            batch = [item for item in items if item is not None]
            period = FLUSH_PERIOD if len(batch) <= SLOW_BATCH else FAST_FLUSH_PERIOD
            try:
                if batch and self.failure is None:
                    self._log(batch)
            except Exception as err:  # the view's fault, not the run's: one line, and no more logging
                self.failure = f"{type(err).__name__}: {err}"
                print(f"pixelswarm: the view stopped logging: {self.failure}", file=sys.stderr, flush=True)
            finally:
                for _ in items:
                    self._queue.task_done()

    def flush(self) -> None:
        """Every tick handed over so far logged (no more batching)."""
        self._hurry.set()
        self._queue.join()

    def close(self) -> None:
        """Every tick logged, and the thread ended."""
        self._hurry.set()
        if self._logger.is_alive():
            self._queue.put(None)
            self._logger.join()


class _Trails:
    """Each robot's trail: its last TRAIL positions of every TRAIL_EVERY-th tick, as faint dots in its colour."""

    def __init__(self) -> None:
        self._points: deque[np.ndarray] = deque(maxlen=TRAIL)
        self._rgb: np.ndarray | None = None  # the trail's colours, and the robots' colours they are of
        self._rgb_of: np.ndarray | None = None

    def keep(self, ticks: np.ndarray, xy: np.ndarray) -> None:
        steps = np.flatnonzero(ticks % TRAIL_EVERY == 0)
        if not self._points and not (steps.size and steps[0] == 0):
            self._points.append(xy[0].copy())
        self._points.extend(xy[i].copy() for i in steps[-TRAIL:])

    def log(self, rr: Any, rec: Any, rgb: Any, dots: bool | None) -> None:
        """The trails as one flat batch of dots (far cheaper than a strip per robot)."""
        if self._rgb is None or len(self._rgb) != len(self._points) * len(rgb) or self._rgb_of is not rgb:
            faint = np.column_stack([rgb, np.full(len(rgb), TRAIL_ALPHA, np.uint8)])
            self._rgb, self._rgb_of = np.tile(faint, (len(self._points), 1)), rgb
        radius = -TRAIL_DOT_POINTS if dots else TRAIL_DOT
        points = rr.Points2D(np.concatenate(self._points), colors=self._rgb, radii=radius)
        rec.log("swarm/trails", points)


class SwarmView:
    """One recording of a swarm of ``radius.size`` robots; :meth:`tick` logs a tick."""

    def __init__(
        self,
        name: str,
        arena: tuple[float, float, float, float] | None,
        obstacles: list[list[tuple[float, float]]],
        radius: np.ndarray | float,
        *,
        robots: int,
        sink: str | os.PathLike = "native",
        tolerance: float = 0.02,
    ) -> None:
        self._rr = rr = _rerun()
        self.radius = np.broadcast_to(np.asarray(radius, dtype=float), (robots,)).copy()
        self.tolerance = tolerance
        self.url: str | None = None
        self.process: subprocess.Popen | None = None
        # what was logged last: logged again only when it changes
        self._goals_shown: tuple[np.ndarray, np.ndarray] | None = None
        self._rgb_shown: np.ndarray | None = None
        self._radius_shown: np.ndarray | None = None
        self.dots: bool | None = None  # robots drawn as dots of DOT points (decided at the first tick)
        self._extent = 0.0  # m across the arena, if known
        self._extras_at = -np.inf  # time.monotonic() of the last batch that logged more than the robots
        self._trails = _Trails()
        # ticks are logged on a thread of the view's own: the run hands over copies and goes on
        self._handover = _TickHandover(self._log)
        self.rec = rr.RecordingStream("pixelswarm", recording_id=f"{name}-{os.getpid()}-{time.time_ns()}")
        try:
            self._open(sink)
        except BaseException:
            self._handover.close()
            raise
        self._static(arena, obstacles)

    def _open(self, sink: str | os.PathLike) -> None:
        """The recording to a file, or to Rerun's viewer (its own process) listening on 127.0.0.1."""
        if sink not in ("native", "web"):
            try:  # made here first: rerun's own failure is a traceback, and a warning on stderr besides
                open(sink, "wb").close()
            except OSError as err:
                raise ViewUnavailable(f"cannot write {sink}: {err.strerror or err}") from None
            self.rec.save(str(sink), default_blueprint=_layout())
            return
        self.process, grpc, page, proxy = _start_viewer(sink == "web", "--expect-data-soon")
        _wait_listening(grpc, self.process)
        self.rec.connect_grpc(proxy, default_blueprint=_layout())
        if page is not None:
            _wait_listening(page, self.process)
            self.url = _page_url(proxy, page)
        else:
            self.process = None  # not ours to stop

    def _static(
        self, arena: tuple[float, float, float, float] | None, obstacles: list[list[tuple[float, float]]]
    ) -> None:
        """The arena's outline (None: not known, as to a viewer on the bus) and the obstacles."""
        rr = self._rr
        # Rerun's 2D views point y down: mirrored, so the picture stands upright and the data keep y up
        for entity in DISPLAY:
            self.rec.log(entity, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        nose = float(np.nanmax(self.radius, initial=0.0)) * NOSE_DOT
        dots = rr.Points2D.from_fields(colors=[NOSE_COLOR], radii=[nose], draw_order=DRAW_ABOVE)
        self.rec.log("swarm/heading", dots, static=True)
        if arena is not None:
            x0, y0, x1, y1 = arena
            self._extent = max(x1 - x0, y1 - y0)
            box = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
            self.rec.log("arena", rr.LineStrips2D([box], colors=[(200, 200, 200)]), static=True)
        if obstacles:
            loops = [[*map(list, o), list(o[0])] for o in obstacles]
            self.rec.log("obstacles", rr.LineStrips2D(loops, colors=[(120, 120, 120)]), static=True)

    def truth(self, m: Truth, goal: np.ndarray, radius: np.ndarray) -> None:
        """:meth:`tick` of the world's truth, with the goals and sizes the robots' states said."""
        missed = np.maximum(0, m.tick - m.applied.astype(np.int64)) if len(m.applied) == m.count else None
        self.tick(m.tick, m.stamp, m.pose, m.color, goal, radius=radius, missed=missed)

    def tick(
        self,
        tick: int,
        t: float,
        pose: np.ndarray,
        color: np.ndarray,
        goal: np.ndarray,
        *,
        radius: np.ndarray | None = None,
        missed: np.ndarray | None = None,
    ) -> None:
        """The swarm at one tick (``goal`` NaN: none; ``missed``: ticks each robot missed so far), copied in
        float32 (as Rerun keeps positions) and logged on the view's thread."""
        if self._handover.failure is not None:
            return
        copy = (
            int(tick),
            float(t),
            np.array(pose, dtype=np.float32).reshape(-1, 3),
            np.array(color, dtype=np.uint8).reshape(-1, 3),
            np.array(goal, dtype=np.float32).reshape(-1, 2),
            None if radius is None else np.array(radius, dtype=float),
            None if missed is None else np.array(missed, dtype=np.int64),
        )
        self._handover.put(copy)

    def _log(self, batch: list[tuple[Any, ...]]) -> None:
        """Every tick's positions and headings as columns (Rerun's cost is per call, not per robot); colours
        and sizes where they changed; the rest once a batch, at its last tick."""
        k = len(batch)
        ticks = np.array([item[0] for item in batch], np.int64)
        times = np.array([item[1] for item in batch])
        xy = np.stack([item[2][:, :2] for item in batch])  # (K, N, 2) float32
        n = xy.shape[1]
        parts = np.full(k, n)
        if self.dots is None:
            self.dots = self._as_dots(xy[0])
        self._send("swarm/robots", ticks, times, "Position2D", xy, parts)
        self._changes(batch, ticks, times)
        r = np.where(np.isfinite(self.radius), self.radius, 0.0).astype(np.float32)
        # the heading as a dark dot toward each disc's front (one position, where an arrow takes two)
        if not self.dots:  # a heading dot would hide a robot drawn as a dot
            theta = np.stack([item[2][:, 2] for item in batch])  # NaN where unknown: no dot
            nose = np.empty((k, n, 2), np.float32)
            np.cos(theta, out=nose[..., 0])
            np.sin(theta, out=nose[..., 1])
            nose *= (r * NOSE)[None, :, None]
            nose += xy
            self._send("swarm/heading", ticks, times, "Position2D", nose, parts)

        self._trails.keep(ticks, xy)
        # a fast run's batches are many ticks: what follows, at most every EXTRAS_PERIOD of wall time
        if k > SLOW_BATCH and time.monotonic() - self._extras_at < EXTRAS_PERIOD:
            return
        self._extras_at = time.monotonic()
        self._log_last(batch[-1], r)

    def _as_dots(self, xy: np.ndarray) -> bool:
        """Whether robots are drawn as dots: a picture of a thousand robots is hundreds of diameters across."""
        placed = xy[np.isfinite(xy).all(axis=1)]
        spread = float(np.ptp(placed, axis=0).max()) if len(placed) else 0.0
        known = np.isfinite(self.radius)
        size = 2 * float(np.median(self.radius[known])) if known.any() else 0.0
        return size > 0 and max(self._extent, spread) > DOTS_ABOVE * size

    def _log_last(self, last: tuple[Any, ...], r: np.ndarray) -> None:
        """The batch's last tick beyond positions: metrics, hover, the goals when they changed, trails."""
        rr, rec = self._rr, self.rec
        tick, t, last_pose, last_rgb, last_goal, _, missed = last
        rec.set_time("tick", sequence=int(tick))
        rec.set_time("time", duration=float(t))
        off = last_goal - last_pose[:, :2]
        at_goal = np.einsum("nc,nc->n", off, off) <= self.tolerance**2  # NaN (no goal) is never at it
        rec.log("metrics/at_goal", rr.Scalars(float(at_goal.sum())))
        gap = clearance_at(last_pose[:, :2].astype(float), r.astype(float))  # as metrics.json takes it
        rec.log("metrics/clearance", rr.Scalars(gap if np.isfinite(gap) else float("nan")))  # NaN: no point
        rec.log(
            "swarm/robots",
            rr.AnyValues(
                goal_x=last_goal[:, 0],
                goal_y=last_goal[:, 1],
                at_goal=at_goal,
                heading_rad=last_pose[:, 2],
                missed_ticks=np.zeros(len(last_pose), np.int64) if missed is None else missed,
            ),
        )
        if self._goals_shown is None or not (
            np.array_equal(last_goal, self._goals_shown[0], equal_nan=True)
            and np.array_equal(last_rgb, self._goals_shown[1])
        ):
            has_goal = np.isfinite(last_goal).all(axis=1)
            faint = np.column_stack([last_rgb[has_goal], np.full(int(has_goal.sum()), GOAL_ALPHA, np.uint8)])
            radii = -DOT * 0.6 if self.dots else r[has_goal] * 0.6  # negative: in the viewer's points
            rec.log("swarm/goals", rr.Points2D(last_goal[has_goal], colors=faint, radii=radii))
            self._goals_shown = (last_goal, last_rgb)
        self._trails.log(self._rr, self.rec, self._rgb_shown, self.dots)

    def _send(self, entity: str, ticks: Any, times: Any, component: str, values: Any, parts: Any) -> None:
        """One Points2D component's values of several ticks (``parts`` a tick) as columns, built whole (the
        archetype's ``columns`` would split every row apart)."""
        rr = self._rr
        index = [rr.TimeColumn("tick", sequence=ticks), rr.TimeColumn("time", duration=times)]
        batch = getattr(rr.components, f"{component}Batch")(values.reshape(-1, *values.shape[2:]))
        field = {"Position2D": "positions", "Color": "colors", "Radius": "radii"}[component]
        column = batch.described(getattr(rr.Points2D, f"descriptor_{field}")()).partition(parts)
        self.rec.send_columns(entity, index, [column])

    def _changes(self, batch: list[tuple[Any, ...]], ticks: np.ndarray, times: np.ndarray) -> None:
        """The robots' colours and sizes at the ticks they changed at."""
        rgb = np.stack([item[3] for item in batch])
        before = rgb[:1] if self._rgb_shown is None else self._rgb_shown[None]
        changed = np.flatnonzero((rgb != np.concatenate([before, rgb[:-1]])).any(axis=(1, 2)))
        if self._rgb_shown is None:
            changed = np.union1d(changed, [0])
        if changed.size:
            parts = np.full(changed.size, rgb.shape[1])
            self._send("swarm/robots", ticks[changed], times[changed], "Color", rgb[changed], parts)
            self._rgb_shown = batch[changed[-1]][3]
        for i, item in enumerate(batch):
            if item[5] is None and self._radius_shown is not None:
                continue
            radius = self.radius if item[5] is None else np.where(np.isfinite(item[5]), item[5], self.radius)
            if self._radius_shown is None or not np.array_equal(radius, self._radius_shown, equal_nan=True):
                self.radius, one = radius, slice(i, i + 1)
                known = np.where(np.isfinite(radius), radius, 0.0)[None]
                sizes = np.full_like(known, -DOT) if self.dots else known
                self._send("swarm/robots", ticks[one], times[one], "Radius", sizes, [len(radius)])
                self._radius_shown = radius.copy()

    def flush(self) -> None:
        """Hand every tick given so far to its sink (the run is over: no more batching)."""
        self._handover.flush()
        self.rec.flush()

    def close(self) -> None:
        """Hand every tick to its sink (a file is complete after this); stop the web server."""
        self._handover.close()
        self.rec.flush()
        self.rec.disconnect()
        if self.process is not None:
            stop_processes([self.process], 10)
            self.process = None

    def serve_until_interrupted(self) -> None:
        """Keep the web viewer up (after the run) until Ctrl-C or SIGTERM."""
        if self.process is None:
            return
        stop_on_sigterm()
        with contextlib.suppress(KeyboardInterrupt):
            self.process.wait()


def _layout() -> Any:
    """The viewer's layout: the display large, the two time series beside it, the side panels folded."""
    import rerun.blueprint as rrb

    display = rrb.Spatial2DView(name="display", origin="/", contents=[f"/{e}/**" for e in DISPLAY])
    plots = rrb.Vertical(rrb.TimeSeriesView(origin="/metrics/clearance"), rrb.TimeSeriesView(origin="/metrics/at_goal"))
    return rrb.Blueprint(rrb.Horizontal(display, plots, column_shares=[3, 1]), collapse_panels=True)


def replay(run_dir: Path, sink: str | os.PathLike, scene: dict[str, Any] | None = None) -> SwarmView:
    """A finished run's ``trajectory.npz`` (and ``scene.json``) logged tick by tick to ``sink``; ValueError,
    before anything is written, for a run directory that does not read."""
    data = _trajectory(run_dir)
    try:
        scene = json.loads((run_dir / "scene.json").read_text()) if scene is None else scene
        x0, y0, x1, y1 = (float(v) for v in scene["arena"])
        obstacles = [[(float(x), float(y)) for x, y in o] for o in scene.get("obstacles", [])]
        name = str(scene.get("name", run_dir.name))
        tolerance = float(scene.get("robot", {}).get("goal_tolerance", 0.02))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
        raise ValueError(f"{run_dir / 'scene.json'} does not read as a run's scene ({err})") from None
    pose, color, goal, radius = data["pose"], data["color"], data["goal"], data["radius"]
    view = SwarmView(name, (x0, y0, x1, y1), obstacles, radius, robots=pose.shape[1], sink=sink, tolerance=tolerance)
    for k, t in enumerate(data["t"].tolist()):
        view.tick(k, t, pose[k], color[k], goal[k])
    return view


def _trajectory(run_dir: Path) -> dict[str, np.ndarray]:
    """trajectory.npz's RUN_ARRAYS, their shapes checked; ValueError in one line if it does not read."""
    path = run_dir / "trajectory.npz"
    try:
        with np.load(path) as npz:
            data = {key: npz[key] for key in RUN_ARRAYS if key in npz.files}
    except OSError as err:
        raise ValueError(f"cannot read {path}: {err.strerror or err}") from None
    except (ValueError, EOFError, zipfile.BadZipFile, TypeError):  # no .npz archive (a .npy: TypeError)
        raise ValueError(f"{path} is not a NumPy .npz archive (empty or damaged)") from None
    if missing := [key for key in RUN_ARRAYS if key not in data]:
        raise ValueError(f"{path} has no {', '.join(missing)}: not a run's trajectory")
    sizes: dict[str, int] = {}  # T and N as the first array to have them says
    for key, dims in RUN_ARRAYS.items():
        shape = data[key].shape
        wanted = [sizes.setdefault(d, n) if isinstance(d, str) else d for d, n in zip(dims, shape)]
        if len(shape) != len(dims) or tuple(wanted) != shape:
            raise ValueError(f"{path}: {key} has shape {shape}, not ({', '.join(map(str, dims))}) of the others")
    return data


def _start_viewer(web: bool, *extra: str) -> tuple[subprocess.Popen, int, int | None, str]:
    """Rerun's viewer on 127.0.0.1: its process, gRPC port, page's port (``web``) and the proxy a recording
    streams to. The native window is the user's: it outlives us (its own session); the web server is ours."""
    _rerun()  # rerun_cli comes in rerun-sdk's wheel
    import rerun_cli

    binary = Path(rerun_cli.__file__).parent / "rerun"  # run directly: a wrapper's child would outlive it
    if not binary.is_file():
        raise ViewUnavailable(f"rerun-sdk has no viewer binary at {binary}")
    grpc, page = free_port(LOOPBACK), free_port(LOOPBACK) if web else None
    command = [str(binary), "--bind", LOOPBACK, "--port", str(grpc)]
    command += [*(["--serve-web", "--web-viewer-port", str(page)] if web else []), *extra]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=not web)
    return process, grpc, page, f"rerun+http://{LOOPBACK}:{grpc}/proxy"


def _page_url(proxy: str, page: int) -> str:
    return f"http://{LOOPBACK}:{page}/?url={urllib.parse.quote(proxy, safe='')}"


def no_window() -> str | None:
    """Why Rerun's native window cannot open here (a Linux session without a display), None if it can."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display to open Rerun's window on (neither $DISPLAY nor $WAYLAND_DISPLAY is set)"
    return None


def view_recording(rrd: Path, *, web: bool = False) -> None:
    """Open a recording in Rerun's window (the user's: returns at once), or its web viewer until Ctrl-C."""
    process, _, page, proxy = _start_viewer(web, str(rrd))
    if page is None:
        return
    stop_on_sigterm()
    try:
        _wait_listening(page, process)
        print(f"view: {_page_url(proxy, page)} (Ctrl-C to stop)", flush=True)
        process.wait()
    finally:
        stop_processes([process], 10)
