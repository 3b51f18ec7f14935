"""The live view of a swarm, and the replay of a finished run, in Rerun's viewer (``pixelswarm[view]``).

:class:`SwarmView` logs a swarm to a Rerun recording, one batch per tick whatever the size of the
swarm (one entity holds every robot, so 1000 robots stay fluid):

- ``arena`` and ``obstacles``: outlines, once (static);
- ``swarm/robots``: each robot as a disc in its LED colour, and per robot (on hover) its goal,
  whether it is at its goal and its missed ticks;
- ``swarm/heading``: each robot's heading, an arrow of its radius;
- ``swarm/goals``: the goals, faint, in their robots' colours (the picture beneath the swarm);
- ``swarm/trails``: each robot's positions over the last 2 s, as faint dots;
- ``metrics/clearance`` and ``metrics/at_goal``: time series.

The timelines are ``tick`` (the control step) and ``time`` (display time, s).

Where it goes (``sink``): ``"native"`` starts Rerun's viewer on this machine (its window outlives the
run); ``"web"`` serves Rerun's web viewer on 127.0.0.1 (:attr:`SwarmView.url`) until :meth:`close`;
a path writes an ``.rrd`` file (what the tests read back, and what :func:`replay` writes beside a
run's ``trajectory.npz``).  Every server listens on 127.0.0.1 only.
"""

from __future__ import annotations

import os
import queue
import subprocess
import threading
import time
import urllib.parse
import urllib.request
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from transport.session import free_port, listening

from .processes import stop_processes

__all__ = ["SwarmView", "ViewUnavailable", "replay", "VIEW_FILE", "TRAIL"]

VIEW_FILE = "view.rrd"  # beside trajectory.npz
TRAIL = 10  # positions kept per robot's trail: every TRAIL_EVERY-th tick's
TRAIL_EVERY = 2
TRAIL_DOT = 0.004  # m, radius of a trail's dots
TRAIL_ALPHA = 90
QUEUE_TICKS = 50  # ticks handed over and not yet logged, at most (then the run waits for the view)
GOAL_ALPHA = 70  # the goals are faint: the picture beneath the robots
LOOPBACK = "127.0.0.1"
START_TIMEOUT = 30.0  # s for Rerun's server to listen


class ViewUnavailable(Exception):
    """rerun-sdk is not installed, or its viewer did not start: one line for the user."""


def _rerun() -> Any:
    try:
        import rerun
    except ImportError:
        raise ViewUnavailable("the view needs rerun-sdk: pip install 'pixelswarm[view]'") from None
    return rerun


def _viewer() -> list[str]:
    """Rerun's viewer binary, as rerun-sdk ships it (run directly: a process of ours to stop by its id,
    not a wrapper whose child would outlive it)."""
    try:
        import rerun_cli
    except ImportError:
        raise ViewUnavailable("the view needs rerun-sdk: pip install 'pixelswarm[view]'") from None
    binary = Path(rerun_cli.__file__).parent / "rerun"
    if not binary.is_file():
        raise ViewUnavailable(f"rerun-sdk has no viewer binary at {binary}")
    return [str(binary)]


def _wait_listening(port: int, proc: subprocess.Popen, timeout: float = START_TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ViewUnavailable(f"Rerun's viewer exited at start (code {proc.returncode})")
        if listening(port, LOOPBACK):
            return
        time.sleep(0.1)
    raise ViewUnavailable(f"Rerun's viewer did not listen on {LOOPBACK}:{port} within {timeout:g} s")


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
        rr = _rerun()
        self._rr = rr
        self.n = robots
        self.radius = np.broadcast_to(np.asarray(radius, dtype=float), (robots,)).copy()
        self.tolerance = tolerance
        self.url: str | None = None
        self.process: subprocess.Popen | None = None
        self._trail: deque[np.ndarray] = deque(maxlen=TRAIL)
        # ticks are logged on a thread of the view's own: the run hands over copies and goes on (a full
        # queue makes it wait: no tick is dropped)
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue(maxsize=QUEUE_TICKS)
        self._logger = threading.Thread(target=self._drain, name="rerun-view", daemon=True)
        self._logger.start()
        self.rec = rr.RecordingStream("pixelswarm", recording_id=f"{name}-{os.getpid()}-{time.time_ns()}")
        if sink in ("native", "web"):
            self._serve(web=sink == "web")
        else:
            self.rec.save(str(sink))
        self._static(arena, obstacles)

    # -- where it goes -----------------------------------------------------------------------
    def _serve(self, web: bool) -> None:
        """Rerun's viewer (its own process) listening on 127.0.0.1; this recording streams to it."""
        grpc = free_port(LOOPBACK)
        command = [*_viewer(), "--bind", LOOPBACK, "--port", str(grpc), "--expect-data-soon"]
        if web:
            page = free_port(LOOPBACK)
            command += ["--serve-web", "--web-viewer-port", str(page)]
        # the native window is the user's: it outlives the run (its own session); the web server is ours
        self.process = subprocess.Popen(
            command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=not web
        )
        _wait_listening(grpc, self.process)
        proxy = f"rerun+http://{LOOPBACK}:{grpc}/proxy"
        self.rec.connect_grpc(proxy)
        if web:
            _wait_listening(page, self.process)
            self.url = f"http://{LOOPBACK}:{page}/?url={urllib.parse.quote(proxy, safe='')}"
        else:
            self.process = None  # not ours to stop

    def _static(
        self, arena: tuple[float, float, float, float] | None, obstacles: list[list[tuple[float, float]]]
    ) -> None:
        """The arena's outline (None: not known, as to a viewer on the bus) and the obstacles."""
        rr = self._rr
        if arena is not None:
            x0, y0, x1, y1 = arena
            box = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
            self.rec.log("arena", rr.LineStrips2D([box], colors=[(200, 200, 200)]), static=True)
        if obstacles:
            loops = [[*map(list, o), list(o[0])] for o in obstacles]
            self.rec.log("obstacles", rr.LineStrips2D(loops, colors=[(120, 120, 120)]), static=True)

    # -- a tick --------------------------------------------------------------------------------
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
        """The swarm at one tick: ``pose`` (N,3), ``color`` (N,3) uint8, ``goal`` (N,2) NaN = none,
        ``missed`` (N,) ticks each robot has missed so far (distributed engine). Copied and logged
        on the view's thread."""
        copy = (
            int(tick),
            float(t),
            np.array(pose, dtype=float),
            np.array(color, dtype=np.uint8).reshape(-1, 3),
            np.array(goal, dtype=float).reshape(-1, 2),
            None if radius is None else np.array(radius, dtype=float),
            None if missed is None else np.array(missed, dtype=np.int64),
        )
        self._queue.put(copy)

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                self._log(*item)
            finally:
                self._queue.task_done()

    def _log(
        self,
        tick: int,
        t: float,
        pose: np.ndarray,
        rgb: np.ndarray,
        goal: np.ndarray,
        radius: np.ndarray | None,
        missed: np.ndarray | None,
    ) -> None:
        rr, rec = self._rr, self.rec
        if radius is not None:
            self.radius = np.where(np.isfinite(radius), radius, self.radius)
        xy = pose[:, :2]
        has_goal = np.isfinite(goal).all(axis=1)
        error = np.hypot(*(xy - goal).T)
        at_goal = has_goal & (error <= self.tolerance)
        rec.set_time("tick", sequence=tick)
        rec.set_time("time", duration=t)
        r = np.where(np.isfinite(self.radius), self.radius, 0.0)
        rec.log("swarm/robots", rr.Points2D(xy, colors=rgb, radii=r))
        rec.log(
            "swarm/robots",
            rr.AnyValues(
                goal_x=np.where(has_goal, goal[:, 0], np.nan),
                goal_y=np.where(has_goal, goal[:, 1], np.nan),
                at_goal=at_goal,
                heading_rad=pose[:, 2],
                missed_ticks=np.zeros(len(xy), np.int64) if missed is None else missed,
            ),
        )
        theta = np.where(np.isfinite(pose[:, 2]), pose[:, 2], 0.0)
        rec.log(
            "swarm/heading",
            rr.Arrows2D(origins=xy, vectors=np.column_stack([np.cos(theta), np.sin(theta)]) * r[:, None]),
        )
        faint = np.column_stack([rgb[has_goal], np.full(int(has_goal.sum()), GOAL_ALPHA, np.uint8)])
        rec.log("swarm/goals", rr.Points2D(goal[has_goal], colors=faint, radii=r[has_goal] * 0.6))
        # the trails as dots, one flat batch (a strip per robot costs ten times as much to log)
        if tick % TRAIL_EVERY == 0 or not self._trail:
            self._trail.append(xy.copy())
        dots = np.concatenate(self._trail)
        trail_rgb = np.tile(np.column_stack([rgb, np.full(len(rgb), TRAIL_ALPHA, np.uint8)]), (len(self._trail), 1))
        rec.log("swarm/trails", rr.Points2D(dots, colors=trail_rgb, radii=TRAIL_DOT))
        rec.log("metrics/clearance", rr.Scalars(_min_clearance(xy, r)))
        rec.log("metrics/at_goal", rr.Scalars(float(at_goal.sum())))

    def flush(self) -> None:
        """Hand every tick given so far to its sink."""
        self._queue.join()
        self.rec.flush()

    def close(self) -> None:
        """Hand every tick to its sink (a file is complete after this); stop the web server."""
        if self._logger.is_alive():
            self._queue.put(None)
            self._logger.join()
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
        try:
            self.process.wait()
        except KeyboardInterrupt:
            pass


def stop_on_sigterm() -> None:
    """SIGTERM as Ctrl-C: the ``finally`` that stops the viewer's process runs."""
    import signal

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)


def _min_clearance(xy: np.ndarray, r: np.ndarray) -> float:
    """The smallest gap between two robots' discs (m), from a k-d tree: cheap at 1000 robots."""
    from scipy.spatial import cKDTree

    ok = np.isfinite(xy).all(axis=1)
    if ok.sum() < 2:
        return float("nan")
    dist, idx = cKDTree(xy[ok]).query(xy[ok], k=2)
    rr = r[ok]
    return float(np.min(dist[:, 1] - rr - rr[idx[:, 1]]))


def replay(run_dir: Path, sink: str | os.PathLike, scene: dict[str, Any] | None = None) -> SwarmView:
    """A finished run's ``trajectory.npz`` (and ``scene.json``) logged tick by tick to ``sink``."""
    import json

    data = np.load(run_dir / "trajectory.npz")
    if scene is None:
        scene = json.loads((run_dir / "scene.json").read_text())
    arena = tuple(scene["arena"])
    obstacles = [[tuple(v) for v in o] for o in scene.get("obstacles", [])]
    pose, color, goal, radius = data["pose"], data["color"], data["goal"], data["radius"]
    view = SwarmView(
        scene.get("name", run_dir.name),
        arena,  # type: ignore[arg-type]
        obstacles,
        radius,
        robots=pose.shape[1],
        sink=sink,
        tolerance=float(scene.get("robot", {}).get("goal_tolerance", 0.02)),
    )
    for k, t in enumerate(data["t"].tolist()):
        view.tick(k, t, pose[k], color[k], goal[k])
    return view


def view_recording(rrd: Path, *, web: bool = False) -> None:
    """Open a recording in Rerun's viewer: its window (returns at once; the window is the user's), or
    its web viewer on 127.0.0.1, the address printed, until Ctrl-C."""
    _rerun()
    if not web:
        command = [*_viewer(), "--bind", LOOPBACK, "--port", str(free_port(LOOPBACK)), str(rrd)]
        subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        return
    grpc, page = free_port(LOOPBACK), free_port(LOOPBACK)
    command = [*_viewer(), "--bind", LOOPBACK, "--port", str(grpc), "--serve-web"]
    command += ["--web-viewer-port", str(page), str(rrd)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stop_on_sigterm()
    try:
        _wait_listening(page, process)
        proxy = f"rerun+http://{LOOPBACK}:{grpc}/proxy"
        print(f"view: http://{LOOPBACK}:{page}/?url={urllib.parse.quote(proxy, safe='')} (Ctrl-C to stop)", flush=True)
        process.wait()
    finally:
        stop_processes([process], 10)


def url_serves(url: str) -> bool:
    """Whether the page answers (the web viewer is up)."""
    with urllib.request.urlopen(url, timeout=10) as response:
        return bool(response.status == 200)
