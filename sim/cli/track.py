"""`pixelswarm track SOURCE --hardware FILE --out poses.csv`: the overhead-camera tracker, offline.

hardware.camera's ArucoTracker over every frame, one CSV row per robot seen per frame: `t,id,x,y,theta,frame`
(t in s from the video's frame rate, x and y in m, theta in rad). See docs/camera.md."""

from __future__ import annotations

import argparse
import csv
import io
import sys
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, TextIO

from sim.args import UsageError, refuse_if, usage_errors
from sim.outputs.rundir import atomic_write

if TYPE_CHECKING:
    from hardware.camera import CameraConfig

PROG = "pixelswarm track"
PROGRESS_EVERY = 50  # frames between progress lines


def add_track_parser(subparsers: Any) -> None:
    """Add the `track` subcommand to an argparse subparsers object (sets func=run_track)."""
    p = subparsers.add_parser(
        "track",
        help="track robots' ArUco markers in an overhead-camera video, offline, into a CSV of poses",
        description="Track robots' ArUco markers in an overhead-camera video into a CSV t,id,x,y,theta,frame.",
    )
    p.add_argument("video", type=Path, metavar="SOURCE", help="a video file (any format OpenCV's FFmpeg reads)")
    p.add_argument(
        "--hardware",
        type=Path,
        required=True,
        metavar="FILE",
        help="hardware TOML file with a [poses] table, kind 'camera'",
    )
    p.add_argument("--out", type=Path, required=True, metavar="CSV", help="CSV file to write")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress output")
    p.set_defaults(func=run_track)


def load_camera_config(path: Path) -> CameraConfig:
    """The `[poses]` table of a hardware file, validated."""
    # here, as in track_video: OpenCV loads only when this command runs, not with every `pixelswarm`
    from hardware.camera import CameraConfig
    from hardware.config import HardwareConfigError

    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as err:
        raise UsageError(f"cannot read hardware file {path}: {err.strerror or err}") from None
    except tomllib.TOMLDecodeError as err:
        raise UsageError(f"hardware file {path} is not valid TOML: {err}") from None
    refuse_if("poses" not in data, f"hardware file {path} has no [poses] table")
    with usage_errors(HardwareConfigError):
        return CameraConfig.from_table(data["poses"], f"{path} [poses]")


def track_video(video: Path, config: CameraConfig, out: TextIO, progress: TextIO | None) -> tuple[int, int]:
    """Track every frame of `video`, writing CSV rows to `out`; returns (frames, rows)."""
    import cv2

    from hardware.camera import MIN_REFERENCES, ArucoTracker, CameraError, open_capture

    refuse_if(not video.is_file(), f"no such video file {video}")
    with usage_errors(CameraError):
        capture = open_capture(str(video))
    try:
        fps = capture.get(cv2.CAP_PROP_FPS)
        fps = fps if fps > 0 else config.rate  # a video without a frame rate: the configured one
        total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        tracker = ArucoTracker(config)
        writer = csv.writer(out)
        writer.writerow(["t", "id", "x", "y", "theta", "frame"])
        frames = rows = 0
        while True:
            ok, image = capture.read()
            if not ok:
                break
            result = tracker.update(image, frames / fps, frames)
            for pose in sorted(result.poses.values(), key=lambda p: p.id):
                writer.writerow(
                    [f"{pose.t:.4f}", pose.id, f"{pose.x:.5f}", f"{pose.y:.5f}", f"{pose.theta:.5f}", frames]
                )
            rows += len(result.poses)
            frames += 1
            if progress is not None and frames % PROGRESS_EVERY == 0:
                print(f"{PROG}: frame {frames}/{total}, {len(result.poses)} robots seen", file=progress, flush=True)
    finally:
        capture.release()
    refuse_if(frames == 0, f"no frames could be read from {video}")
    if not tracker.calibrated:
        raise UsageError(
            f"fewer than {MIN_REFERENCES} of the reference markers {sorted(config.reference)} were ever seen in {video}"
        )
    return frames, rows


def run_track(args: argparse.Namespace) -> int:
    """The command; bad input, or a CSV that cannot be written, is a UsageError (one line, exit code 2).
    The CSV takes its name only when complete."""
    out: Path = args.out
    config = load_camera_config(args.hardware)
    if out.exists() and any(out.samefile(p) for p in (args.video, args.hardware) if Path(p).exists()):
        raise UsageError(f"cannot write {out}: it is the command's own input")
    if out.is_dir() or not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: {'a directory' if out.is_dir() else f'no such directory {out.parent}'}")
    counts: list[int] = []

    def write(fh: BinaryIO) -> None:
        text = io.TextIOWrapper(fh, newline="")
        counts.extend(track_video(args.video, config, text, None if args.quiet else sys.stderr))
        text.detach()  # flushed; atomic_write closes the file

    try:
        atomic_write(out, write)
    except OSError as err:
        raise UsageError(f"cannot write {out}: {err.strerror or err}") from None
    if not args.quiet:
        print(f"{PROG}: {counts[0]} frames, {counts[1]} robot poses -> {out}", file=sys.stderr)
    print(out)
    return 0
