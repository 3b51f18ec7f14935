"""`pixelswarm track SOURCE --hardware FILE --out poses.csv`: the overhead-camera tracker, offline.

Runs hardware.camera's ArucoTracker, set up by a hardware file's `[poses]` table (kind "camera"), over
every frame and writes one CSV row per robot seen per frame: `t,id,x,y,theta,frame` (t in s from the
video's frame rate, x and y in m on the floor, theta in rad). Bad input is one line on stderr and exit
code 2; the CSV takes its name only when complete. See docs/camera.md.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from sim.args import UsageError

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
    if "poses" not in data:
        raise UsageError(f"hardware file {path} has no [poses] table")
    try:
        return CameraConfig.from_table(data["poses"], f"{path} [poses]")
    except HardwareConfigError as err:
        raise UsageError(str(err)) from None


def track_video(video: Path, config: CameraConfig, out: TextIO, progress: TextIO | None) -> tuple[int, int]:
    """Track every frame of `video`, writing CSV rows to `out`; returns (frames, rows)."""
    import cv2

    from hardware.camera import MIN_REFERENCES, ArucoTracker, CameraError, open_capture

    if not video.is_file():
        raise UsageError(f"no such video file {video}")
    try:
        capture = open_capture(str(video))
    except CameraError as err:
        raise UsageError(str(err)) from None
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
    if frames == 0:
        raise UsageError(f"no frames could be read from {video}")
    if not tracker.calibrated:
        raise UsageError(
            f"fewer than {MIN_REFERENCES} of the reference markers {sorted(config.reference)} were ever seen in {video}"
        )
    return frames, rows


def run_track(args: argparse.Namespace) -> int:
    """Run the track command; bad input, or a CSV that cannot be written, is a UsageError, which
    `pixelswarm` says as one line (exit code 2)."""
    out: Path = args.out
    temp: Path | None = None
    try:
        config = load_camera_config(args.hardware)
        parent = out.parent if str(out.parent) else Path(".")
        if out.is_dir() or not parent.is_dir():
            raise UsageError(
                f"cannot write {out}: {'a directory' if out.is_dir() else 'no such directory ' + str(parent)}"
            )
        fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".partial", dir=parent)
        temp = Path(name)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temp, 0o666 & ~umask)  # mkstemp's 0600 would outlive the rename
        with os.fdopen(fd, "w", newline="") as f:
            frames, rows = track_video(args.video, config, f, None if args.quiet else sys.stderr)
        os.replace(temp, out)
        temp = None
    except OSError as err:
        raise UsageError(f"cannot write {out}: {err.strerror or err}") from None
    finally:
        if temp is not None:
            temp.unlink(missing_ok=True)
    if not args.quiet:
        print(f"{PROG}: {frames} frames, {rows} robot poses -> {out}", file=sys.stderr)
    print(out)
    return 0
