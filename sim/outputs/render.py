"""What an audience would see, and the plots of a run: top-down frames (OpenCV), H.264 MP4 (PyAV's libx264: the pip
OpenCV wheels have none) and plots (matplotlib's Agg canvas, no pyplot state). World x right, y up; colours RGB."""

from __future__ import annotations

import os
from collections.abc import Callable, Generator, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Final

import av
import cv2
import numpy as np
from av.codec.codec import UnknownCodecError

from sim.outputs.metrics import tick_chunks
from sim.outputs.stream import OnDisk


@dataclass(frozen=True)
class Recording:
    """A run as the writers draw it; ``radius``, ``goal`` and ``color`` may be given once for all ticks."""

    t: np.ndarray
    pose: np.ndarray
    radius: np.ndarray | float
    arena: Sequence[float]
    obstacles: Sequence[Sequence[Sequence[float]]] | None = ()
    goal: np.ndarray | None = None
    color: np.ndarray | None = None

    def checked(self) -> Recording:
        """Arrays as floats, broadcast over time; arrays on disk (sim.outputs.stream) stay there."""
        t = np.asarray(self.t, dtype=float)
        pose = self.pose if isinstance(self.pose, OnDisk) else np.asarray(self.pose, dtype=float)
        if pose.ndim != 3 or pose.shape[0] != len(t):
            raise ValueError(f"pose must be (T,N,3) with T = len(t); got {pose.shape}, T={len(t)}")
        T, N = pose.shape[:2]
        color = None if self.color is None else _over_time(self.color, (T, N, 3), None)
        goal = None if self.goal is None else _over_time(self.goal, (T, N, 2), float)
        radius = np.broadcast_to(np.asarray(self.radius, dtype=float), (N,))
        return Recording(t, pose, radius, self.arena, self.obstacles or (), goal, color)


def _over_time(a: Any, shape: tuple[int, ...], dtype: Any) -> Any:
    """(T, N, k) values given per tick, or once for every tick."""
    return a if isinstance(a, OnDisk) else np.broadcast_to(np.asarray(a, dtype=dtype), shape)


BACKGROUND = (18, 18, 18)  # BGR
ARENA_EDGE = (70, 70, 70)
OBSTACLE_FILL = (105, 105, 105)
OBSTACLE_EDGE = (150, 150, 150)
ROBOT_RIM = (85, 85, 85)
TEXT = (210, 210, 210)

# H.264 as every browser decodes it (4:2:0, High profile), playable before it has all downloaded; x264's default CRF
H264_ENCODER: Final = "libx264"  # Final: PyAV then knows add_stream makes a video stream
H264_OPTIONS = {"crf": "23", "preset": "veryfast"}
H264_PROFILE = "High"
H264_PIX_FMT = "yuv420p"
MP4_OPTIONS = {"movflags": "+faststart"}

_SHIFT = 4  # sub-pixel bits for cv2 drawing
_ONE = 1 << _SHIFT
_MARGIN = 0.03  # of the frame's size, left around the arena (at least 2 px)

# robots above which discs are stamped all at once (numpy), not drawn one by one: a few pixels wide, where
# anti-aliasing and a heading tick show nothing
STAMP_ABOVE = 1000
MIN_DISC_PX = 2.0  # the narrowest disc a video draws (:func:`video_size`)
MAX_VIDEO_PX = 4096  # H.264 level 5.1's widest frame


def video_size(arena: Sequence[float], radius: np.ndarray | float, size_px: int = 720) -> int:
    """``size_px``, or more (to :data:`MAX_VIDEO_PX`) until the smallest robot is :data:`MIN_DISC_PX` across."""
    r = float(np.min(np.asarray(radius, dtype=float)))
    if not np.isfinite(r) or r <= 0:
        return size_px
    while size_px < MAX_VIDEO_PX and 2 * r * _View(arena, size_px).scale < MIN_DISC_PX:
        size_px += 16
    return min(size_px, MAX_VIDEO_PX)


def _stamp(img: np.ndarray, centre: np.ndarray, r_px: np.ndarray, bgr: np.ndarray, ring: bool = False) -> None:
    """Discs of radius ``r_px`` (N,) at pixel ``centre`` (N, 2) in ``bgr`` (N, 3), an assignment per radius."""
    h, w = img.shape[:2]
    rounded = np.maximum(np.round(r_px * 2) / 2, 0.5)
    for r in np.unique(rounded).tolist():
        which = np.flatnonzero(rounded == r)
        k = int(np.ceil(r + 0.5))  # the offsets of the pixels of a disc (or its one-pixel rim) of radius r
        dy, dx = np.mgrid[-k : k + 1, -k : k + 1]
        d = np.hypot(dx, dy)
        keep = np.abs(d - r) <= 0.5 if ring else d <= r + 0.25
        dy, dx = dy[keep], dx[keep]
        rows = np.rint(centre[which, 1]).astype(np.int64)[:, None] + dy
        cols = np.rint(centre[which, 0]).astype(np.int64)[:, None] + dx
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        colour = np.broadcast_to(bgr[which, None, :], (*rows.shape, 3))
        img[rows[inside], cols[inside]] = colour[inside]


class _View:
    """World -> pixel transform for an arena, plus the static background."""

    def __init__(self, arena: Sequence[float], size_px: int):
        xmin, ymin, xmax, ymax = (float(v) for v in arena)
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"bad arena {arena}")
        self.arena = (xmin, ymin, xmax, ymax)
        margin = max(2, int(round(size_px * _MARGIN)))
        self.scale = (size_px - 2 * margin) / max(xmax - xmin, ymax - ymin)  # px per metre
        w = int(round((xmax - xmin) * self.scale)) + 2 * margin
        h = int(round((ymax - ymin) * self.scale)) + 2 * margin
        self.width, self.height = w + (w % 2), h + (h % 2)  # even sizes suit video codecs
        self.ox = (self.width - (xmax - xmin) * self.scale) / 2
        self.oy = (self.height - (ymax - ymin) * self.scale) / 2

    def px(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) world -> (..., 2) float pixel (col, row)."""
        xy = np.asarray(xy, dtype=float)
        xmin, _, _, ymax = self.arena
        col = self.ox + (xy[..., 0] - xmin) * self.scale
        row = self.oy + (ymax - xy[..., 1]) * self.scale
        return np.stack([col, row], axis=-1)

    def fixed(self, xy: np.ndarray) -> np.ndarray:
        """Pixel coordinates as fixed-point ints for cv2 with ``shift=_SHIFT``."""
        return np.round(self.px(xy) * _ONE).astype(np.int64)

    def background(self, obstacles: Sequence[Sequence[Sequence[float]]] | None) -> np.ndarray:
        img = np.full((self.height, self.width, 3), BACKGROUND, np.uint8)
        xmin, ymin, xmax, ymax = self.arena
        corners = self.fixed(np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]]))
        cv2.polylines(img, [corners.astype(np.int32)], True, ARENA_EDGE, 1, cv2.LINE_AA, _SHIFT)
        for poly in obstacles or []:  # polygons of 3 vertices or more (coordinator.scene)
            p = self.fixed(np.asarray(poly, dtype=float).reshape(-1, 2)).astype(np.int32)
            cv2.fillPoly(img, [p], OBSTACLE_FILL, cv2.LINE_AA, _SHIFT)
            cv2.polylines(img, [p], True, OBSTACLE_EDGE, 1, cv2.LINE_AA, _SHIFT)
        return img


def _draw(
    img: np.ndarray,
    view: _View,
    time_s: float | None,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None,
    goal: np.ndarray | None,
) -> np.ndarray:
    """The swarm on ``img`` in its LED colours (None: white) over its goals' rings (None: none, or drawn on
    ``img`` already: :func:`_goal_rings`), and the display time in the top-left corner."""
    bgr = _bgr(color, len(pose))
    if goal is not None:
        _goal_rings(img, view, radius, bgr, goal)
    _robots(img, view, pose, radius, bgr)
    if time_s is not None and np.isfinite(time_s):
        fs = max(0.35, view.height / 1300)
        label = f"t = {time_s:7.2f} s"
        (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, fs, 1)
        x0, y0 = 4, 4 + th
        cv2.rectangle(img, (x0 - 2, y0 - th - 3), (x0 + tw + 2, y0 + base), BACKGROUND, -1)  # on background
        cv2.putText(img, label, (x0, y0), cv2.FONT_HERSHEY_SIMPLEX, fs, TEXT, 1, cv2.LINE_AA)
    return img


def _bgr(color: np.ndarray | None, n: int) -> np.ndarray:
    """(N, 3) int64 BGR of the robots' LED colours (RGB; None: white)."""
    if color is None:
        return np.full((n, 3), 230, np.int64)
    return np.asarray(color).reshape(n, 3)[:, ::-1].astype(np.int64)


def _dim(bgr: np.ndarray) -> np.ndarray:
    """A goal's dim shade of its robot's colour."""
    return np.maximum(bgr * 0.45, 55)


def _goal_rings(img: np.ndarray, view: _View, radius: np.ndarray, bgr: np.ndarray, goal: np.ndarray) -> None:
    """Each goal (NaN: none) as a dim one-pixel ring of its robot's size (stamped above :data:`STAMP_ABOVE`)."""
    rpx = radius * view.scale
    g = np.asarray(goal, dtype=float).reshape(len(bgr), 2)
    gok = np.isfinite(g).all(axis=1)
    if len(bgr) > STAMP_ABOVE:
        _stamp(img, view.px(g[gok]), rpx[gok], _dim(bgr).astype(np.uint8)[gok], ring=True)
        return
    r_fx = np.maximum(np.round(rpx * _ONE), _ONE).astype(np.int64).tolist()  # fixed-point radii, at least a pixel
    gfx, gcol = view.fixed(np.where(gok[:, None], g, 0.0)).tolist(), _dim(bgr).astype(np.int64).tolist()
    for i in np.flatnonzero(gok).tolist():
        cv2.circle(img, tuple(gfx[i]), r_fx[i], tuple(gcol[i]), 1, cv2.LINE_AA, _SHIFT)


def _robots(img: np.ndarray, view: _View, pose: np.ndarray, radius: np.ndarray, bgr: np.ndarray) -> None:
    """Each placed robot as a disc with a rim and, where its heading is known, a tick toward its front (dark on a
    light disc, light on a dark one); above :data:`STAMP_ABOVE`, a stamped disc alone."""
    rpx = radius * view.scale
    xy = pose[:, :2]
    ok = np.isfinite(xy).all(axis=1)
    if len(bgr) > STAMP_ABOVE:
        _stamp(img, view.px(xy[ok]), rpx[ok], bgr[ok].astype(np.uint8))
        return
    r_fx = np.maximum(np.round(rpx * _ONE), _ONE).astype(np.int64)  # fixed-point radii, at least a pixel
    has_th = np.isfinite(pose[:, 2])
    th = np.where(has_th, pose[:, 2], 0.0)
    xy0 = np.where(ok[:, None], xy, 0.0)
    c = view.fixed(xy0)
    tip = view.fixed(xy0 + 0.95 * radius[:, None] * np.stack([np.cos(th), np.sin(th)], axis=-1))
    lum = 0.114 * bgr[:, 0] + 0.587 * bgr[:, 1] + 0.299 * bgr[:, 2]
    tick_thick = np.clip(np.round(rpx * 0.18), 1, 4).astype(int)
    cl, tl, rl, bl = c.tolist(), tip.tolist(), r_fx.tolist(), bgr.tolist()
    for i in np.flatnonzero(ok).tolist():
        centre = tuple(cl[i])
        cv2.circle(img, centre, rl[i], tuple(bl[i]), -1, cv2.LINE_AA, _SHIFT)
        cv2.circle(img, centre, rl[i], ROBOT_RIM, 1, cv2.LINE_AA, _SHIFT)
        if has_th[i]:
            tick = (20, 20, 20) if lum[i] > 110 else (200, 200, 200)
            cv2.line(img, centre, tuple(tl[i]), tick, int(tick_thick[i]), cv2.LINE_AA, _SHIFT)


def frame_indices(t: np.ndarray, fps: float, speed: float | None = 1.0, max_frames: int = 3000) -> np.ndarray:
    """The samples :func:`write_video` shows: the latest at each frame time at ``speed`` x real time (None: every
    sample), subsampled evenly to at most ``max_frames`` (0: no limit)."""
    t = np.asarray(t, dtype=float)
    T = len(t)
    if T == 0:
        return np.zeros(0, dtype=int)
    if speed is None:
        idx = np.arange(T)
    else:
        if speed <= 0 or fps <= 0:
            raise ValueError("fps and speed must be positive")
        span = float(t[-1] - t[0])
        nf = int(np.floor(span * fps / speed + 1e-9)) + 1
        tf = t[0] + np.arange(nf) * (speed / fps)
        idx = np.clip(np.searchsorted(t, tf + 1e-9, side="right") - 1, 0, T - 1)
    if max_frames and len(idx) > max_frames:
        idx = idx[np.round(np.linspace(0, len(idx) - 1, int(max_frames))).astype(int)]
    return idx


HOLD_S = 3.0  # s of video that show the final picture at least: a run ends converge_hold after it forms


def held_frames(t: np.ndarray, formed_at: float | None, fps: float = 10, speed: float = 1.0) -> np.ndarray:
    """:func:`frame_indices`, then the last sample repeated until the final picture (formed at ``formed_at``;
    None: the last sample) shows for :data:`HOLD_S` seconds of video."""
    idx = frame_indices(t, fps, speed, max_frames=0)
    if not len(idx):
        return idx
    t = np.asarray(t, dtype=float)
    since = float(t[-1]) if formed_at is None else float(formed_at)
    shown = int(np.count_nonzero(t[idx] >= since - 1e-9))
    missing = max(0, int(np.ceil(HOLD_S * fps - 1e-9)) - shown)
    return np.concatenate([idx, np.full(missing, idx[-1], dtype=idx.dtype)])


def write_video(
    path: str | os.PathLike,
    recording: Recording,
    fps: float = 10,
    size_px: int = 720,
    *,
    speed: float | None = 1.0,
    max_frames: int = 3000,
    fourcc: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Write the video of the :func:`frame_indices` samples (H.264, or OpenCV's ``fourcc``); returns its frame
    count, and tells ``progress`` (frames written, of all) after each. RuntimeError if the encoder fails; then
    no file is left at ``path``."""
    path = Path(path)
    rec = recording.checked()
    idx = frame_indices(rec.t, fps, speed, max_frames)
    if len(idx) == 0:
        raise ValueError("write_video: no samples")

    view = _View(rec.arena, size_px)
    frames = _drawn_ahead(_painter(rec, view), idx.tolist(), progress)
    try:
        if fourcc is None:
            _encode_h264(path, frames, fps, view.width, view.height)
        else:
            _encode_opencv(path, frames, fps, view.width, view.height, fourcc)
    except BaseException:
        frames.close()  # the frame drawn ahead is finished and its thread gone before the error goes on
        path.unlink(missing_ok=True)  # a half-written video is worse than none
        raise
    return int(len(idx))


def _painter(rec: Recording, view: _View) -> Callable[[int], np.ndarray]:
    """Sample k of ``rec`` drawn as :func:`_draw` draws it, the goals' rings drawn once while they stand still
    (as an image holds): the same pixels."""
    bg = view.background(rec.obstacles)
    at = lambda a, k: None if a is None else a[k]  # a tick's values, or none
    radius = np.asarray(rec.radius)
    under = (b"", bg)  # the last frame's goals and colours, and the background with their rings

    def draw(k: int) -> np.ndarray:
        nonlocal under
        goal, color = at(rec.goal, k), at(rec.color, k)
        bgr = _bgr(color, len(radius))
        key = b"" if goal is None else np.asarray(goal).tobytes() + bgr.tobytes()
        if goal is not None and key != under[0]:  # goals stand still while an image holds: rings drawn once
            under = (key, bg.copy())
            _goal_rings(under[1], view, radius, bgr, goal)
        return _draw(under[1].copy(), view, float(rec.t[k]), rec.pose[k], radius, color, None)

    return draw


def _drawn_ahead(
    draw: Callable[[int], np.ndarray], samples: list[int], progress: Callable[[int, int], None] | None
) -> Generator[np.ndarray, None, None]:
    """The frames of ``samples`` in order, each drawn on a thread while the encoder takes the one before: OpenCV
    and the encoder free the GIL, so the same frames come sooner. ``progress`` hears of each frame taken."""
    with ThreadPoolExecutor(1, thread_name_prefix="video-frames") as painter:
        ahead = painter.submit(draw, samples[0])
        for done, k in enumerate([*samples[1:], None], 1):
            frame = ahead.result()
            if k is not None:
                ahead = painter.submit(draw, k)
            yield frame
            if progress is not None:
                progress(done, len(samples))


def _encode_h264(path: Path, frames: Iterable[np.ndarray], fps: float, width: int, height: int) -> None:
    """BGR frames -> H.264 in MP4 with PyAV's libx264 (the encoder converts BGR to yuv420p)."""
    try:
        with av.open(str(path), "w", format="mp4", options=MP4_OPTIONS) as container:
            stream = container.add_stream(
                H264_ENCODER, rate=Fraction(fps).limit_denominator(1001), options=H264_OPTIONS
            )
            stream.width, stream.height, stream.pix_fmt = width, height, H264_PIX_FMT
            stream.codec_context.profile = H264_PROFILE
            for frame in frames:
                container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="bgr24")))
            container.mux(stream.encode())  # flush the frames the encoder still holds
    except (av.FFmpegError, UnknownCodecError) as e:
        raise RuntimeError(f"H.264 encoding of {path} failed ({H264_ENCODER} via PyAV): {e}") from e


def _encode_opencv(path: Path, frames: Iterable[np.ndarray], fps: float, width: int, height: int, fourcc: str) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*fourcc), float(fps), (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV VideoWriter could not open {path} with fourcc {fourcc!r}")
    try:
        for frame in frames:
            writer.write(frame)
    finally:
        writer.release()
    if not path.exists() or path.stat().st_size == 0:
        raise RuntimeError(f"OpenCV wrote no video data to {path}")


def _figure(w_in: float, h_in: float) -> tuple[Any, Any]:
    """A figure (its own Agg canvas at savefig: no pyplot state), and its one axes."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w_in, h_in), dpi=PLOT_DPI)
    return fig, fig.add_subplot(1, 1, 1)


def _robot_colours(n: int, color: np.ndarray | None) -> np.ndarray:
    """(n, 4) RGBA for plotting: the given RGB colours, but dark LEDs replaced by a colormap."""
    from matplotlib import colormaps

    cmap = colormaps["turbo"] if n > 20 else colormaps["tab20"]
    base = cmap(np.linspace(0.05, 0.95, n) if n > 20 else np.arange(n) % 20)
    if color is None:
        return base
    rgb = np.asarray(color, dtype=float).reshape(n, 3) / 255.0
    bright = rgb.max(axis=1) > 0.25
    base[bright, :3] = rgb[bright]
    return base


PLOT_POINTS = 1_000_000  # points of all robots' paths in trajectories.png together
PATH_POINTS = 1500  # points of one robot's path at most
PLOT_DPI = 120


def write_plots(out_dir: str | os.PathLike, recording: Recording, clearance: np.ndarray) -> dict[str, Path]:
    """Write ``clearance.png`` (minimum clearance over time) and ``trajectories.png`` (every robot's path in its
    final LED colour, start, end and last goal); returns their paths by name."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rec = recording.checked()
    paths = {"clearance": out_dir / "clearance.png", "trajectories": out_dir / "trajectories.png"}
    _plot_clearance(paths["clearance"], rec, np.asarray(clearance, dtype=float))
    _plot_trajectories(paths["trajectories"], rec)
    return paths


def _plot_clearance(path: Path, rec: Recording, clearance: np.ndarray) -> None:
    t, N = rec.t, rec.pose.shape[1]
    fig, ax = _figure(8, 3.6)
    fin = np.isfinite(clearance)
    if fin.any():
        ax.plot(t, np.where(fin, clearance, np.nan), color="#1f77b4", lw=1.2, label="minimum clearance")
        neg = fin & (clearance < 0)
        if neg.any():
            ax.fill_between(
                t, np.where(neg, clearance, 0.0), 0.0, where=neg, color="#d62728", alpha=0.3, lw=0, label="overlap"
            )
        k = int(np.argmin(np.where(fin, clearance, np.inf)))
        ax.plot([t[k]], [clearance[k]], "o", color="#d62728", ms=4)
        ax.annotate(
            f"min {clearance[k]:.3f} m", (t[k], clearance[k]), textcoords="offset points", xytext=(6, 6), fontsize=8
        )
    else:
        ax.text(0.5, 0.5, "fewer than two robots: no pairs", transform=ax.transAxes, ha="center")
    ax.axhline(0.0, color="#d62728", ls="--", lw=1.0, label="contact (0 m)")
    title = f"Minimum clearance between robots (centre distance − radii), N = {N}"
    ax.set(xlabel="time [s]", ylabel="clearance [m]", title=title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png")


def _plot_trajectories(path: Path, rec: Recording) -> None:
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon, Rectangle

    t, pose, obstacles = rec.t, rec.pose, rec.obstacles
    T, N = pose.shape[:2]
    xmin, ymin, xmax, ymax = (float(v) for v in rec.arena)
    aspect = (ymax - ymin) / (xmax - xmin)
    fig, ax = _figure(7.5, max(3.0, min(12.0, 7.0 * aspect + 0.8)))
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, ec="0.3", lw=1.0))
    for poly in obstacles or []:
        ax.add_patch(Polygon(np.asarray(poly, dtype=float), closed=True, fc="0.65", ec="0.4", lw=0.8, zorder=1))
    cols = _robot_colours(N, None if rec.color is None or T == 0 else rec.color[-1])  # the final LED colours
    # points a path, fewer with many robots: matplotlib's cost grows with all paths' points together
    per_robot = max(50, min(PATH_POINTS, PLOT_POINTS // max(N, 1)))
    step = max(1, int(np.ceil(T / per_robot))) if T else 1
    sub = pose[::step, :, :2]
    if T and (T - 1) % step:
        sub = np.concatenate([sub, pose[-1:, :, :2]], axis=0)
    segs = [sub[:, i][np.isfinite(sub[:, i]).all(axis=1)] for i in range(N)]
    lw = 1.0 if N <= 50 else 0.6
    ax.add_collection(LineCollection(segs, colors=cols, linewidths=lw, alpha=0.85, zorder=2))
    starts = np.array([s[0] if len(s) else (np.nan, np.nan) for s in segs]).reshape(-1, 2)
    ends = np.array([s[-1] if len(s) else (np.nan, np.nan) for s in segs]).reshape(-1, 2)
    ms = 18 if N <= 50 else 6
    ax.scatter(starts[:, 0], starts[:, 1], s=ms, facecolors="none", edgecolors=cols, lw=0.8, zorder=3, label="start")
    ax.scatter(ends[:, 0], ends[:, 1], s=ms, c=cols, zorder=4, label="end")
    if rec.goal is not None and T:
        last = _last_goals(rec.goal, T, N)
        if np.isfinite(last).any():
            ax.scatter(last[:, 0], last[:, 1], s=ms, marker="x", c="0.35", lw=0.8, zorder=3, label="goal")
    dx, dy, dur = 0.02 * (xmax - xmin), 0.02 * (ymax - ymin), float(t[-1] - t[0]) if len(t) else 0.0
    ax.set(xlim=(xmin - dx, xmax + dx), ylim=(ymin - dy, ymax + dy), aspect="equal", xlabel="x [m]", ylabel="y [m]")
    ax.set_title(f"Trajectories, N = {N}, {dur:.1f} s")
    ax.legend(loc="upper right", fontsize=8, markerscale=1.0)
    fig.tight_layout()
    fig.savefig(path, format="png")


def _last_goals(goal: Any, T: int, N: int) -> np.ndarray:
    """(N, 2) each robot's last goal (NaN: none), ``goal`` (T, N, 2) read a piece at a time."""
    last = np.full((N, 2), np.nan)
    for ticks in tick_chunks(T, N):
        g = np.asarray(goal[ticks], dtype=float)
        known = np.isfinite(g).all(axis=2)  # (ticks, N)
        has = known.any(axis=0)
        at = len(g) - 1 - np.argmax(known[::-1], axis=0)  # each robot's last sample with a goal here
        last[has] = g[at[has], np.flatnonzero(has)]
    return last
