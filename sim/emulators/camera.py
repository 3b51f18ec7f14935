"""An overhead-camera emulator: ArUco markers on robots, seen by a tilted camera over the floor.

    python -m sim.emulators.camera OUT_DIR --robots 14 --frames 60  # video.avi, truth.csv, hardware.toml

What it draws, and `CameraStream` (the camera live, as MJPEG over HTTP): docs/camera.md.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import http.server
import math
import os
import shutil
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from hardware.config import Started, every
from sim.args import OneLineParser, refuse

if TYPE_CHECKING:
    from .mocap import PoseFunction

Pose = tuple[float, float, float]  # x, y (metres), theta (radians)

SUPERSAMPLE = 4  # hi-res pixels per image pixel, per axis, when drawing a marker
CELL_PX = 24  # pixels per marker cell in the drawn marker image
FOURCC = "FFV1"  # lossless, and written by opencv-python-headless's FFmpeg
STREAM_RATE = 10.0  # Hz: CameraStream's frames (a hardware file's camera rate, by default)
JPEG_QUALITY = 95
MAX_WANDERING = 24  # robots whose plates the wandering grid keeps apart


@dataclass(frozen=True)
class OverheadCamera:
    """The camera, the floor and how frames are spoiled."""

    width: int = 1280
    height: int = 960
    floor: tuple[float, float] = (2.0, 1.5)
    origin: tuple[float, float] = (0.0, 0.0)  # where the floor's near left corner is, in floor metres
    margin: float = 40.0  # pixels between the floor's near corners and the image edge
    keystone: float = 0.1  # the far edge is drawn this fraction narrower: the camera is tilted
    dictionary: str = "DICT_4X4_50"
    marker_size: float = 0.05
    # the last four ids of DICT_4X4_50 near the floor's corners, clear of the robots' area
    reference: dict[int, tuple[float, float]] = field(
        default_factory=lambda: {46: (0.1, 0.1), 47: (1.9, 0.1), 48: (1.9, 1.4), 49: (0.1, 1.4)}
    )
    blur_sigma: float = 1.0  # pixels
    noise_sigma: float = 4.0  # grey levels
    floor_grey: float = 110.0
    plate_grey: float = 235.0

    def floor_to_image(self) -> np.ndarray:
        """The 3x3 homography from floor metres to image pixels (pixel centres at whole numbers)."""
        m, w, h = self.margin, self.width - 1.0, self.height - 1.0
        inset = self.keystone * (w - 2 * m) / 2
        floor = self._outline().astype(np.float32)
        image = np.array([[m, h - m], [w - m, h - m], [w - m - inset, m], [m + inset, m]], np.float32)
        return cv2.getPerspectiveTransform(floor, image).astype(float)

    def poses_table(self) -> dict:
        """The hardware file's `[poses]` table that tracks this camera."""
        return {
            "kind": "camera",
            "dictionary": self.dictionary,
            "marker_size": self.marker_size,
            "reference": {str(m): list(xy) for m, xy in self.reference.items()},
        }

    def render(self, robots: dict[int, Pose], rng: np.random.Generator) -> np.ndarray:
        """A grey frame (uint8, height x width) with each robot's marker at its pose."""
        frame = self._background.copy()
        to_image = self.floor_to_image()
        plates = [(m, (x, y, 0.0)) for m, (x, y) in self.reference.items()] + list(robots.items())
        for marker, pose in plates:
            self._draw_marker(frame, to_image, _marker_image(self.dictionary, marker), pose)
        if self.blur_sigma > 0:
            frame = cv2.GaussianBlur(frame, (0, 0), self.blur_sigma)
        # OpenCV's generator, seeded from rng for each frame: faster than numpy's here
        noise = np.empty_like(frame)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(noise, 0.0, self.noise_sigma)  # type: ignore[call-overload]  # stubs lack the Scalar form
        frame += noise
        return np.clip(frame + 0.5, 0, 255).astype(np.uint8)  # + 0.5 then truncation: rounding

    @functools.cached_property
    def _background(self) -> np.ndarray:
        """The frame without markers, drawn once per camera."""
        frame = np.full((self.height, self.width), self.floor_grey / 2, np.float32)
        corners = cv2.perspectiveTransform(self._outline()[None], self.floor_to_image())
        cv2.fillConvexPoly(frame, np.rint(corners[0]).astype(np.int32), float(self.floor_grey), cv2.LINE_AA)
        return frame

    def _outline(self) -> np.ndarray:
        """The floor's corners in floor metres, near left first, counter-clockwise."""
        (fw, fh), (x0, y0) = self.floor, self.origin
        return np.array([[x0, y0], [x0 + fw, y0], [x0 + fw, y0 + fh], [x0, y0 + fh]], np.float64)

    def _draw_marker(self, frame: np.ndarray, floor_to_image: np.ndarray, image: np.ndarray, pose: Pose) -> None:
        n = image.shape[0]
        metres_per_px = self.marker_size / (n - 2 * CELL_PX)
        x, y, theta = pose
        ahead, right = np.array([math.cos(theta), math.sin(theta)]), np.array([math.sin(theta), -math.cos(theta)])
        # marker image pixels -> floor: its centre (pixel edges at half-integers) at (x, y), its top edge ahead
        centre = (n - 1) / 2
        to_floor = np.eye(3)
        to_floor[:2, 0] = right * metres_per_px
        to_floor[:2, 1] = -ahead * metres_per_px
        to_floor[:2, 2] = np.array([x, y]) - centre * metres_per_px * (right - ahead)
        to_image = floor_to_image @ to_floor
        outline = cv2.perspectiveTransform(
            np.array([[[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]]], np.float64), to_image
        )[0]
        x0, y0 = np.floor(outline.min(axis=0)).astype(int) - 1
        x1, y1 = np.ceil(outline.max(axis=0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, self.width), min(y1, self.height)
        if x0 >= x1 or y0 >= y1:
            return
        s = SUPERSAMPLE
        # image pixel (i, j) is the mean of hi-res pixels s*(i - x0) .. s*(i - x0) + s - 1
        to_hires = np.array([[s, 0, s * (0.5 - x0) - 0.5], [0, s, s * (0.5 - y0) - 0.5], [0, 0, 1]])
        size = (s * (x1 - x0), s * (y1 - y0))
        warp = to_hires @ to_image
        ink = cv2.warpPerspective(image, warp, size, flags=cv2.INTER_LINEAR, borderValue=0.0)
        cover = cv2.warpPerspective(np.ones_like(image), warp, size, flags=cv2.INTER_LINEAR, borderValue=0.0)
        ink = cv2.resize(ink, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        cover = cv2.resize(cover, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        roi = frame[y0:y1, x0:x1]
        roi[:] = roi * (1.0 - cover) + ink * self.plate_grey


@functools.cache
def _marker_image(dictionary_name: str, marker: int) -> np.ndarray:
    """The marker (6 cells with its black border) on a white plate one cell wide all round, 0..1."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name))
    side = (dictionary.markerSize + 2) * CELL_PX
    image = cv2.aruco.generateImageMarker(dictionary, marker, side)
    image = cv2.copyMakeBorder(image, CELL_PX, CELL_PX, CELL_PX, CELL_PX, cv2.BORDER_CONSTANT, value=255)
    return image.astype(np.float32) / 255.0


def wandering_robots(n: int, frames: int, fps: float, seed: int) -> list[dict[int, Pose]]:
    """n robots (ids 0..n-1) on a grid, each circling its own spot and turning at its own rate."""
    if not 1 <= n <= MAX_WANDERING:
        raise ValueError(f"wandering robots: 1 to {MAX_WANDERING}, not {n}")
    rng = np.random.default_rng(seed)
    columns = math.ceil(math.sqrt(n * 4 / 3))
    rows = math.ceil(n / columns)
    xs, ys = np.linspace(0.4, 1.6, columns), np.linspace(0.4, 1.1, rows) if rows > 1 else np.array([0.75])
    spots = [(x, y) for y in ys for x in xs][:n]
    phase, speed = rng.uniform(0, 2 * np.pi, n), rng.uniform(-1.5, 1.5, n)
    heading, turn = rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.0, 1.0, n)
    radius = 0.06
    return [
        {
            i: (
                spots[i][0] + radius * math.cos(phase[i] + speed[i] * t),
                spots[i][1] + radius * math.sin(phase[i] + speed[i] * t),
                math.remainder(heading[i] + turn[i] * t, 2 * math.pi),
            )
            for i in range(n)
        }
        for t in (k / fps for k in range(frames))
    ]


def render_frames(camera: OverheadCamera, poses: Iterable[dict[int, Pose]], seed: int) -> Iterator[np.ndarray]:
    rng = np.random.default_rng(seed)
    for robots in poses:
        yield camera.render(robots, rng)


def write_video(path: Path, frames: Iterable[np.ndarray], fps: float) -> None:
    """Write grey frames to a lossless grey FFV1 video (e.g. `video.avi`)."""
    writer: cv2.VideoWriter | None = None
    try:
        for frame in frames:
            if writer is None:
                height, width = frame.shape[:2]
                writer = cv2.VideoWriter(
                    str(path), cv2.VideoWriter.fourcc(*FOURCC), fps, (width, height), isColor=False
                )
                if not writer.isOpened():
                    raise OSError(f"cannot write video {path} with codec {FOURCC}")
            writer.write(frame)
    finally:
        if writer is not None:
            writer.release()


def write_truth(path: Path, poses: Iterable[dict[int, Pose]], fps: float) -> None:
    """The true poses as CSV, in the columns `pixelswarm track` writes."""
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "id", "x", "y", "theta", "frame"])
        for k, robots in enumerate(poses):
            for i, (x, y, theta) in sorted(robots.items()):
                out.writerow([f"{k / fps:.4f}", i, f"{x:.6f}", f"{y:.6f}", f"{theta:.6f}", k])


def poses_toml(camera: OverheadCamera, source: str | None = None) -> str:
    """The hardware file's `[poses]` table as TOML text (reading ``source``, if given)."""
    lines = ["[poses]", 'kind = "camera"', f'dictionary = "{camera.dictionary}"', f"marker_size = {camera.marker_size}"]
    lines += [] if source is None else [f'source = "{source}"']
    lines += ["", "[poses.reference]"] + [f'"{m}" = [{x}, {y}]' for m, (x, y) in camera.reference.items()]
    return "\n".join(lines) + "\n"


_BOUNDARY = "frame"
_SEND_BUFFER = 65536  # bytes the kernel holds for a reader: less than a frame, so frames do not queue


class _Reader(http.server.BaseHTTPRequestHandler):
    """One client of the stream, sent the newest frame whenever it has taken the last: a slow reader
    skips frames rather than falling behind."""

    timeout = 10.0  # s: a reader that stops reading is dropped, not waited for

    def __init__(self, *args: Any, stream: CameraStream) -> None:
        self.stream = stream
        super().__init__(*args)  # which serves the request

    def setup(self) -> None:
        super().setup()
        self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _SEND_BUFFER)

    def handle(self) -> None:
        with contextlib.suppress(OSError):  # the reader went away, or stopped reading
            super().handle()

    def do_GET(self) -> None:
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={_BOUNDARY}")
        self.end_headers()
        sent = 0
        while (newest := self.stream.next_part(sent)) is not None:
            sent, part = newest
            self.wfile.write(part)

    def log_message(self, format: str, *args: Any) -> None:
        """Nothing: a camera logs no requests."""


class CameraStream(Started):
    """The overhead camera as a network camera: frames of ``poses(t)`` (row i: robot i, t in s since start)
    at STREAM_RATE Hz, served as MJPEG over HTTP on 127.0.0.1 at `url`. `swap` and `shift` spoil a frame."""

    def __init__(self, poses: PoseFunction, camera: OverheadCamera) -> None:
        self.poses = poses
        self.camera = camera
        self.error: Exception | None = None  # what stopped the rendering thread, if anything did
        self._rng = np.random.default_rng(0)  # the pixel noise's
        self.glitched: list[float] = []  # time.monotonic() at which each spoiled frame was rendered
        self._glitches: list[tuple[float, Callable]] = []  # (not before, the poses it changes)
        self._lock = threading.Lock()
        self._part: tuple[int, bytes] = (0, b"")  # the newest frame's part of the stream, and its number
        self._new_part = threading.Condition()
        self._halt = threading.Event()
        self._server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Reader, stream=self))
        self.url = f"http://127.0.0.1:{self._server.server_address[1]}/video.mjpg"
        self._threads = [
            threading.Thread(target=self._server.serve_forever, args=(0.2,), name="camera-accept", daemon=True),
            threading.Thread(target=self._render, name="camera-render", daemon=True),
        ]

    def start(self) -> CameraStream:
        self._started = time.monotonic()
        for thread in self._threads:
            thread.start()
        return self

    def close(self) -> None:
        self._halt.set()
        with self._new_part:
            self._new_part.notify_all()  # the readers end
        if self._threads[0].is_alive():
            self._server.shutdown()  # serve_forever returns
        for thread in self._threads:
            if thread.is_alive():
                thread.join()
        self._server.server_close()

    def next_part(self, after: int) -> tuple[int, bytes] | None:
        """The newest frame's part and its number, once newer than part ``after``; None once closing."""
        with self._new_part:
            self._new_part.wait_for(lambda: self._part[0] > after or self._halt.is_set())
            return None if self._halt.is_set() else self._part

    def poses_toml(self) -> str:
        """The hardware file's `[poses]` table that tracks this stream."""
        return poses_toml(self.camera, self.url)

    def swap(self, a: int, b: int, at: float | None = None) -> None:
        """Draw robot a's marker at b's pose and b's at a's in one frame, the first rendered at or
        after ``at`` (time.monotonic(); None: the next)."""
        self._glitch(at, lambda robots: {a: robots[b], b: robots[a]})

    def shift(self, robot: int, dx: float, dy: float, at: float | None = None) -> None:
        """Draw a robot's marker (dx, dy) metres off its pose in one frame, as `swap` says which."""
        self._glitch(at, lambda robots: {robot: (robots[robot][0] + dx, robots[robot][1] + dy, robots[robot][2])})

    def _glitch(self, at: float | None, change: Callable[[dict[int, Pose]], dict[int, Pose]]) -> None:
        with self._lock:
            self._glitches.append((at or 0.0, change))

    def _spoil(self, robots: dict[int, Pose], now: float) -> dict[int, Pose]:
        """The poses to draw: those of the glitches due by ``now`` spoiled."""
        with self._lock:
            due = [change for at, change in self._glitches if at <= now]
            self._glitches = [g for g in self._glitches if g[0] > now]
        spoiled = dict(robots)
        for change in due:
            spoiled.update(change(robots))  # each from the true poses
        if due:
            self.glitched.append(now)
        return spoiled

    def _render(self) -> None:
        self.error = every(1.0 / STREAM_RATE, self._started, self._halt, self._render_frame)

    def _render_frame(self, t: float) -> None:
        rows = np.asarray(self.poses(t), float).reshape(-1, 3)
        robots = {i: (float(x), float(y), float(theta)) for i, (x, y, theta) in enumerate(rows)}
        image = self.camera.render(self._spoil(robots, time.monotonic()), self._rng)
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        data = jpeg.tobytes()
        head = f"--{_BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(data)}\r\n\r\n".encode()
        with self._new_part:
            self._part = (self._part[0] + 1, head + data + b"\r\n")
            self._new_part.notify_all()


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m sim.emulators.camera", description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="new folder to write video.avi, truth.csv and hardware.toml into")
    parser.add_argument("--robots", type=int, default=14, help=f"robots, ids 0..N-1, 1 to {MAX_WANDERING} (default 14)")
    parser.add_argument("--frames", type=int, default=60, help="frames (default 60)")
    parser.add_argument("--fps", type=float, default=10.0, help="frame rate (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of motion and pixel noise (default 0)")
    args = parser.parse_args(argv)
    if not 1 <= args.robots <= MAX_WANDERING or args.frames < 1 or not 0 < args.fps < math.inf:
        parser.error(f"need 1 to {MAX_WANDERING} robots, 1 or more frames and a positive fps")
    if args.out.exists():
        parser.error(f"{args.out} already exists; choose a new folder")
    camera = OverheadCamera()
    poses = wandering_robots(args.robots, args.frames, args.fps, args.seed)
    temp = None  # everything is written into a temporary folder beside OUT, renamed when complete
    try:
        temp = Path(tempfile.mkdtemp(prefix=f".{args.out.name}.", dir=args.out.parent))
        write_video(temp / "video.avi", render_frames(camera, poses, args.seed), args.fps)
        write_truth(temp / "truth.csv", poses, args.fps)
        (temp / "hardware.toml").write_text(poses_toml(camera))
        umask = os.umask(0)
        os.umask(umask)
        temp.chmod(0o777 & ~umask)  # mkdtemp's 0700 would outlive the rename
        temp.rename(args.out)
        temp = None
    except OSError as err:
        return refuse(parser.prog, f"cannot write {args.out}: {err.strerror or err}")
    finally:
        if temp is not None:
            shutil.rmtree(temp, ignore_errors=True)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
