"""The overhead-camera tracker on one core: frames per second and accuracy on rendered footage.

Rendered 1280x960 frames (sim.emulators.camera: a tilted camera over 2 x 1.5 m of floor, 5 cm
DICT_4X4_50 markers, 14 robots wandering, four reference markers, Gaussian blur and pixel noise) are
tracked by hardware.camera.ArucoTracker with each of OpenCV's corner refinements, and by the ArUco
detection alone (no refinement, no poses) as the reference. All variants see each frame in turn, so
they share the machine's load; cv2.setNumThreads(1) holds each to one core, and speed is read from the
thread's CPU time (a shared machine's wall clock includes waiting for a core). Two conditions: the
emulator's defaults and a harsher camera (more blur, more noise).

    .venv/bin/python -m bench.bench_tracker            # writes bench/results/tracker.md
    .venv/bin/python -m bench.bench_tracker --quick    # a short run, prints only
"""

from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from bench.common import write_results
from hardware.camera import CORNER_REFINEMENT, ArucoTracker, CameraConfig
from sim.emulators.camera import OverheadCamera, render_frames, wandering_robots

ROBOTS, FPS, SEED = 14, 10.0, 3
REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
}
CONDITIONS = {
    "defaults (blur 1.0 px, noise 4 grey levels)": OverheadCamera(),
    "harsh (blur 1.5 px, noise 8 grey levels)": OverheadCamera(blur_sigma=1.5, noise_sigma=8.0),
}


@dataclass
class Tally:
    seconds: list[float] = field(default_factory=list)  # wall clock
    cpu: list[float] = field(default_factory=list)  # this thread's CPU time: less swayed by other work
    found: int = 0
    drawn: int = 0
    position: list[float] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)


def measure(camera: OverheadCamera, frames: int) -> dict[str, Tally]:
    config = CameraConfig.from_table(camera.poses_table(), "bench [poses]")
    truth = wandering_robots(ROBOTS, frames, FPS, SEED)
    images = list(render_frames(camera, truth, SEED))
    detection_only = ArucoTracker(config, cv2.aruco.CORNER_REFINE_NONE)
    trackers = {name: ArucoTracker(config, method) for name, method in REFINEMENTS.items()}
    tallies = {name: Tally() for name in ["detection alone", *trackers]}
    for k, (robots, image) in enumerate(zip(truth, images)):
        start, start_cpu = time.perf_counter(), time.thread_time()
        detection_only.detect(image)
        tallies["detection alone"].seconds.append(time.perf_counter() - start)
        tallies["detection alone"].cpu.append(time.thread_time() - start_cpu)
        for name, tracker in trackers.items():
            start, start_cpu = time.perf_counter(), time.thread_time()
            result = tracker.update(image, k / FPS, k)
            tally = tallies[name]
            tally.seconds.append(time.perf_counter() - start)
            tally.cpu.append(time.thread_time() - start_cpu)
            tally.drawn += len(robots)
            tally.found += len(result.poses)
            for i, pose in result.poses.items():
                x, y, theta = robots[i]
                tally.position.append(math.hypot(pose.x - x, pose.y - y))
                tally.heading.append(abs(math.remainder(pose.theta - theta, 2 * math.pi)))
    return tallies


def table(tallies: dict[str, Tally]) -> list[str]:
    lines = [
        "| variant | frames/s of CPU (median) | CPU ms per frame (median, p95) | wall ms per frame (median) | found "
        "| position mm (mean, p95, max) | heading deg (mean, p95, max) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, t in tallies.items():
        cpu, wall = np.array(t.cpu) * 1e3, np.array(t.seconds) * 1e3
        label = f"{name} (chosen)" if REFINEMENTS.get(name) == CORNER_REFINEMENT else name
        speed = f"| {label} | {1e3 / np.median(cpu):.1f} | {np.median(cpu):.1f}, {np.percentile(cpu, 95):.1f} | {np.median(wall):.1f} "
        if not t.drawn:
            lines.append(speed + "| - | - | - |")
            continue
        mm, deg = np.array(t.position) * 1e3, np.degrees(t.heading)
        lines.append(
            speed + f"| {100 * t.found / t.drawn:.2f} % | {mm.mean():.2f}, {np.percentile(mm, 95):.2f}, {mm.max():.2f} "
            f"| {deg.mean():.2f}, {np.percentile(deg, 95):.2f}, {deg.max():.2f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=100, help="frames per condition (default 100)")
    parser.add_argument("--quick", action="store_true", help="20 frames, print only")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    frames = 20 if args.quick else args.frames
    lines = [
        f"{ROBOTS} robots, {frames} frames of 1280x960 per condition (seed {SEED}), OpenCV {cv2.__version__}, "
        "cv2.setNumThreads(1). Speed from the tracking thread's CPU time per frame (the machine is shared: "
        "wall-clock times include waiting for a core). Found: robot-frames with a pose, of those drawn. "
        "Errors against the rendered truth.",
    ]
    for condition, camera in CONDITIONS.items():
        lines += ["", f"### {condition}", "", *table(measure(camera, frames))]
    lines += ["", f"Load average at the end (1, 5, 15 min): {', '.join(f'{x:.1f}' for x in os.getloadavg())}."]
    if args.quick:
        print("\n".join(lines))
        return
    write_results(
        "tracker",
        "Overhead-camera tracker: frames per second on one core, and accuracy",
        f".venv/bin/python -m bench.bench_tracker --frames {frames}",
        lines,
    )


if __name__ == "__main__":
    main()
