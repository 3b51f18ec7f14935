"""The overhead-camera pose source: one ArUco marker (id = robot id) on top of each robot, seen by a fixed camera.

A homography (image -> floor metres), fitted to reference markers or given, places each marker on the floor,
its top edge ahead. A robot not seen in a frame is reported lost, never invented. Set-up: docs/camera.md."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from .config import FromTable, HardwareConfigError, Started, is_number, need
from .poses import PoseSample, StampGate

# A detection whose side on the floor is off by more than this fraction is not a robot's marker: dropped.
SIDE_TOLERANCE = 0.25
# Reference markers that move by more than this many pixels mean the camera moved: calibrate anew.
CAMERA_MOVED_PX = 3.0
# Fits lines to the marker's edges: on blurred, noisy frames more precise than CORNER_REFINE_SUBPIX.
CORNER_REFINEMENT = cv2.aruco.CORNER_REFINE_CONTOUR
MIN_REFERENCES = 4  # fewer floor points do not determine a homography
# A stream that delivers no frame (or does not open) within this long has stalled and is opened again:
# FFmpeg's own limit, 30 s, would hold the reading thread, and so close(), that long. Meanwhile the robots
# have stopped: their poses aged past the command timeout.
STREAM_TIMEOUT = 1.0  # s
CLOSE_WAIT = 2 * STREAM_TIMEOUT  # s: close() waits this long for the reading thread, at most


class CameraError(RuntimeError):
    """A camera or video that cannot be read: one line saying which and why."""


NOT_GIVEN: dict[int, tuple[float, float]] = {}  # CameraConfig.reference when the table has none (never filled)


@dataclass(frozen=True)
class CameraConfig(FromTable):
    """The `[poses]` table of kind "camera", validated. Every default is written here, once."""

    KIND = "camera"
    source: int | str = 0
    dictionary: str = "DICT_4X4_50"
    marker_size: float = 0.05
    reference: dict[int, tuple[float, float]] = field(default_factory=lambda: NOT_GIVEN)
    homography: tuple[tuple[float, ...], ...] | None = None
    rate: float = 10.0

    def __post_init__(self) -> None:
        checks = {"source": _source, "dictionary": _dictionary_name, "marker_size": _positive, "rate": _positive}
        for key, check in checks.items():
            object.__setattr__(self, key, check(getattr(self, key), key))  # frozen: set once, here
        referenced = self.reference is not NOT_GIVEN  # an empty table or a list is given, and refused
        if referenced:
            size = dictionary_size(self.dictionary)
            object.__setattr__(self, "reference", _reference(self.reference, size, "reference"))
        if self.homography is not None:
            object.__setattr__(self, "homography", _homography(self.homography, "homography"))
        need(
            referenced != (self.homography is not None),
            "give exactly one of [poses.reference] markers and a homography",
        )

    def check_robots(self, robot_ids: list[int], where: str) -> None:
        """The backend's robots carry markers ``robot_ids``: each must be in the dictionary and be no
        reference marker (a robot taken for a fixed floor point would bend the calibration)."""
        if not robot_ids:
            return
        size, last = dictionary_size(self.dictionary), max(robot_ids)
        need(last < size, f"{where}: {self.dictionary} has marker ids 0-{size - 1}, too few for robots 0-{last}")
        shared = sorted(set(robot_ids) & set(self.reference))
        need(
            not shared,
            f"{where}: reference marker ids {', '.join(map(str, shared))} are robot ids (the robots are 0-{last}): "
            "give the reference markers ids no robot has",
        )


def dictionary_size(name: str) -> int:
    """How many markers a cv2.aruco predefined dictionary holds (ids 0 to size - 1)."""
    return len(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList)


def _source(value: Any, what: str) -> int | str:
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    if isinstance(value, str) and value.strip():
        return value
    raise HardwareConfigError(f"{what} must be a device number, a video file or a stream URL, not {value!r}")


def _dictionary_name(value: Any, what: str) -> str:
    if not (isinstance(value, str) and value.startswith("DICT_") and hasattr(cv2.aruco, value)):
        raise HardwareConfigError(f"{what} {value!r} is not a cv2.aruco dictionary (e.g. 'DICT_4X4_50')")
    return value


def _number(value: Any, what: str) -> float:
    need(is_number(value), f"{what} must be a finite number, not {value!r}")
    return float(value)


def _positive(value: Any, what: str) -> float:
    number = _number(value, what)
    need(number > 0, f"{what} must be positive, not {value!r}")
    return number


def _reference(value: Any, dictionary_size: int, where: str) -> dict[int, tuple[float, float]]:
    need(isinstance(value, Mapping), f"{where}: must be a table of marker id -> [x, y]")
    out: dict[int, tuple[float, float]] = {}
    written: dict[int, str] = {}  # marker id -> its key as written, to name both of two that collide
    for key, xy in value.items():
        text = str(key).strip()
        need(text.isascii() and text.isdigit(), f"{where}: marker id {key!r} is not a whole number")
        marker = int(text)
        if marker in written:  # "46" and "046": one marker placed twice
            raise HardwareConfigError(f"{where}: marker ids {written[marker]!r} and {key!r} are both marker {marker}")
        written[marker] = str(key)
        if not 0 <= marker < dictionary_size:
            raise HardwareConfigError(
                f"{where}: marker id {marker} is outside the dictionary (0..{dictionary_size - 1})"
            )
        if not (isinstance(xy, list | tuple) and len(xy) == 2):
            raise HardwareConfigError(f"{where}: marker {marker} must be at [x, y] metres, not {xy!r}")
        out[marker] = (_number(xy[0], f"{where}: {marker} x"), _number(xy[1], f"{where}: {marker} y"))
    points = np.array(list(out.values()), dtype=float).reshape(-1, 2)
    need(len(out) >= MIN_REFERENCES, f"{where}: needs at least {MIN_REFERENCES} markers, not {len(out)}")
    spread = np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-3) >= 2  # not all on one line
    need(spread, f"{where}: the markers lie on one line; spread them over the floor")
    return out


def _homography(value: Any, where: str) -> tuple[tuple[float, ...], ...]:
    rows = value if isinstance(value, list | tuple) else []
    if len(rows) != 3 or not all(isinstance(r, list | tuple) and len(r) == 3 for r in rows):
        raise HardwareConfigError(f"{where}: must be a 3x3 list of numbers (image pixels -> floor metres)")
    matrix = tuple(tuple(_number(v, where) for v in row) for row in rows)
    singular = abs(np.linalg.det(np.array(matrix))) < 1e-12
    need(not singular, f"{where}: the matrix is singular")
    return matrix


@dataclass(frozen=True)
class MarkerPose:
    """A robot's pose on the floor (metres, radians) and the time of the frame it was seen in."""

    id: int
    x: float
    y: float
    theta: float
    t: float


@dataclass(frozen=True)
class TrackedFrame:
    """One frame's result: the robots seen in it, and those seen before but not in it."""

    t: float
    index: int
    poses: dict[int, MarkerPose]
    lost: frozenset[int]


def marker_centre(corners: np.ndarray) -> np.ndarray:
    """The centre of a square seen in perspective: where its diagonals cross (not its corners' mean)."""
    h = np.hstack([corners, np.ones((4, 1))])
    point = np.cross(np.cross(h[0], h[2]), np.cross(h[1], h[3]))
    return point[:2] / point[2]


class ArucoTracker:
    """Marker detections -> robot poses on the floor, one frame at a time."""

    def __init__(self, config: CameraConfig, corner_refinement: int = CORNER_REFINEMENT) -> None:
        self.config = config
        parameters = cv2.aruco.DetectorParameters()
        parameters.cornerRefinementMethod = corner_refinement
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, config.dictionary))
        self.detector = cv2.aruco.ArucoDetector(dictionary, parameters)
        self.homography: np.ndarray | None = None if config.homography is None else np.array(config.homography)
        # each reference marker's image centre: (sum of x, of y, count), a running mean for a fixed camera
        self._reference_sum: dict[int, np.ndarray] = {}
        self._last: dict[int, MarkerPose] = {}

    @property
    def calibrated(self) -> bool:
        return self.homography is not None

    def detect(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """Marker id -> its four image corners (4x2, OpenCV's order); ids seen twice are dropped."""
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        corners, ids, _ = self.detector.detectMarkers(grey)
        if ids is None:
            return {}
        markers = [int(i) for i in ids.ravel()]
        seen = Counter(markers)
        return {m: c.reshape(4, 2).astype(float) for m, c in zip(markers, corners) if seen[m] == 1}

    def update(self, image: np.ndarray, t: float, index: int = 0) -> TrackedFrame:
        """Track one frame taken at time `t` (seconds)."""
        markers = self.detect(image)
        if self.config.reference:
            self._calibrate({m: c for m, c in markers.items() if m in self.config.reference})
        poses: dict[int, MarkerPose] = {}
        robots = {m: c for m, c in markers.items() if m not in self.config.reference}
        if self.homography is not None and robots:
            corners = np.array(list(robots.values())).reshape(-1, 1, 2)
            floor = cv2.perspectiveTransform(corners, self.homography).reshape(-1, 4, 2)
            centre = floor.mean(axis=1)  # the floor is the marker's own plane: the corners' mean is its centre
            ahead = floor[:, 0] + floor[:, 1] - floor[:, 2] - floor[:, 3]  # centre -> middle of the top edge
            side = np.linalg.norm(floor - np.roll(floor, 1, axis=1), axis=2).mean(axis=1)
            for k, marker in enumerate(robots):
                if abs(side[k] / self.config.marker_size - 1.0) <= SIDE_TOLERANCE:
                    theta = math.atan2(ahead[k, 1], ahead[k, 0])
                    poses[marker] = MarkerPose(marker, float(centre[k, 0]), float(centre[k, 1]), theta, t)
        self._last.update(poses)
        return TrackedFrame(t, index, poses, frozenset(set(self._last) - set(poses)))

    def last_seen(self) -> dict[int, MarkerPose]:
        """Every robot ever seen -> its latest pose (with the time it was seen)."""
        return dict(self._last)

    def _calibrate(self, seen: dict[int, np.ndarray]) -> None:
        centres = {m: marker_centre(c) for m, c in seen.items()}
        means = {m: s[:2] / s[2] for m, s in self._reference_sum.items()}
        moved = [np.linalg.norm(p - means[m]) > CAMERA_MOVED_PX for m, p in centres.items() if m in means]
        if moved and sum(moved) * 2 > len(moved):
            # the old calibration is wrong now: no poses until the references are seen again
            self._reference_sum.clear()
            self.homography = None
        for m, p in centres.items():
            self._reference_sum[m] = self._reference_sum.get(m, 0.0) + np.append(p, 1.0)
        if len(self._reference_sum) < MIN_REFERENCES:
            return
        ids = sorted(self._reference_sum)
        image = np.array([self._reference_sum[m][:2] / self._reference_sum[m][2] for m in ids])
        floor = np.array([self.config.reference[m] for m in ids])
        homography, _ = cv2.findHomography(image, floor)
        if homography is not None:
            self.homography = homography


def open_capture(source: int | str) -> cv2.VideoCapture:
    """Open a camera device, video file or stream (giving up after STREAM_TIMEOUT), or raise CameraError."""
    if is_stream(source):
        ms = round(STREAM_TIMEOUT * 1000)
        timeouts = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        capture = cv2.VideoCapture(source, cv2.CAP_ANY, timeouts)
    else:
        capture = cv2.VideoCapture(source)
    if not capture.isOpened():
        capture.release()
        raise CameraError(f"cannot open video source {source!r}")
    return capture


def is_stream(source: int | str) -> bool:
    return isinstance(source, str) and "://" in source


def is_file(source: int | str) -> bool:
    return isinstance(source, str) and not is_stream(source)


class CameraPoseSource(Started):
    """Reads frames in a thread and hands out each robot's latest pose, stamped with its frame's time (a file's:
    from 0 at its frame rate, played at that rate if `realtime`; else `clock()` when read), as `gate` takes them."""

    def __init__(
        self,
        config: CameraConfig,
        *,
        realtime: bool = True,
        tracker: ArucoTracker | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.config = config
        self.tracker = tracker or ArucoTracker(config)
        self.realtime = realtime
        self.clock = clock
        self._lock = threading.Lock()
        self._frame: TrackedFrame | None = None
        self._latest: dict[int, tuple[MarkerPose, float]] = {}  # robot -> newest pose, when it was tracked
        self.gate = StampGate()
        self._frames = 0
        self._stop = threading.Event()
        self.finished = threading.Event()  # set when the source ends or fails
        self.error: str | None = None  # why no frames come (a stream: while it is being opened again)
        self._thread: threading.Thread | None = None
        self._capture: cv2.VideoCapture | None = None

    def start(self) -> CameraPoseSource:
        self._capture = open_capture(self.config.source)
        if not is_file(self.config.source):
            self._capture.set(cv2.CAP_PROP_FPS, self.config.rate)
        self._thread = threading.Thread(target=self._run, name="camera-poses", daemon=True)
        self._thread.start()
        return self

    def latest(self) -> dict[int, PoseSample]:
        """Every robot seen so far, by id, with its newest pose (stamped with its frame's time)."""
        with self._lock:
            latest = dict(self._latest)
        now = time.monotonic()
        return {r: PoseSample(p.x, p.y, p.theta, p.t, now - at) for r, (p, at) in sorted(latest.items())}

    def stats(self) -> dict[str, int]:
        """Frames tracked, poses dropped for their stamps, restarts taken (summed over robots)."""
        with self._lock:
            return dict(frames=self._frames, **self.gate.stats(), robots=len(self._latest))

    def robot_stats(self, robot: int) -> dict[str, int]:
        """One robot's poses dropped for their stamps, and restarts taken."""
        with self._lock:
            return self.gate.robot_stats(robot)

    def frame(self) -> TrackedFrame | None:
        """The latest frame's result (robots seen in it and robots lost), or None before the first."""
        with self._lock:
            return self._frame

    def close(self) -> None:
        """Stop reading; waits for a read under way at most CLOSE_WAIT (the thread, left behind, releases the
        capture itself once its read returns)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(CLOSE_WAIT)
        elif self._capture is not None:  # never read from
            self._capture.release()

    def _run(self) -> None:
        assert self._capture is not None
        from_file = is_file(self.config.source)
        fps = self._capture.get(cv2.CAP_PROP_FPS) or self.config.rate
        started = time.monotonic()
        index = 0
        try:
            while not self._stop.is_set():
                ok, image = self._capture.read()
                if not ok:
                    if not from_file:
                        self.error = f"video source {self.config.source!r} stopped delivering frames"
                    if is_stream(self.config.source) and self._reopen():
                        continue
                    break
                t = index / fps if from_file else self.clock()
                frame = self.tracker.update(image, t, index)
                tracked = time.monotonic()
                now = t if from_file else self.clock()  # the frame clock now (a file: its frames' times)
                with self._lock:
                    self._frame = frame
                    self._frames += 1
                    for r, pose in frame.poses.items():
                        if self.gate.admit(r, pose.t, now, tracked):
                            self._latest[r] = (pose, tracked)
                index += 1
                if from_file and self.realtime:
                    self._stop.wait(max(0.0, started + index / fps - time.monotonic()))
        finally:
            self._capture.release()  # here, not in close(): releasing it under a read under way would crash
            self.finished.set()

    def _reopen(self) -> bool:
        """A stalled stream, opened again until it opens (True) or close() is called (False)."""
        assert self._capture is not None
        self._capture.release()
        while not self._stop.is_set():
            try:
                self._capture = open_capture(self.config.source)
                self.error = None  # frames come again
                return True
            except CameraError:
                self._stop.wait(STREAM_TIMEOUT)
        return False
