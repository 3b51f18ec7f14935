"""Benchmark of animation goal generation (paper 6.1): initialising each keyframe's CVT from the
previous frame's goals, moved by the regions' T_i^f and M_i^f, against fresh random samples.

Cases: the leaf (11 keyframes) with N = 100 (256 px) and N = 1000 (512 px, so that a robot still has
tens of pixels), and the 14-robot story (256 px). For each, side by side in one run:

- disparity: goal_disparity between consecutive goal sets (mean distance of the squared-distance
  optimal assignment, eq. 7), in pixels of the keyframes (the runs' arenas may differ slightly);
- time: wall clock of keyframe_goals (all frames: segmentation, motion estimates, Lloyd), median of
  --repeat runs; Lloyd iterations summed over the frames; the final cost of eq. 1 summed over frames.

Both robot-count rules are measured: N_i proportional to the area in every frame (paper 4.2, the
default) and keep_counts (each region keeps the N_i of its region in the previous frame).

    .venv/bin/python -m bench.bench_keyframes     # prints the tables, writes bench/results/keyframes.md
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import scipy

from coordinator.drawings import keyframes
from coordinator.keyframes import KeyframeGoals, keyframe_goals

from .common import write_results

CASES = (("leaf", 100, 256), ("leaf", 1000, 512), ("story", 14, 256))


def _run(
    frames: list[np.ndarray], n: int, init: bool, keep: bool, seed: int, repeat: int
) -> tuple[float, KeyframeGoals]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = keyframe_goals(frames, n, init_from_previous=init, keep_counts=keep, seed=seed)
        times.append(time.perf_counter() - t)
    assert out is not None
    return statistics.median(times), out


def _summary(kg: KeyframeGoals) -> dict:
    return {
        "disp": kg.disparities() / kg.metres_per_pixel,
        "iters": sum(r.iterations for r in kg.reports),
        "cost": sum(s.cost_history[-1] for s in kg.sets),
    }


def case_lines(name: str, n: int, size: int, seed: int, repeat: int) -> list[str]:
    frames = keyframes(name, size)
    lines = [
        f"### {name}, N = {n}, {len(frames)} keyframes of {size} x {size} px",
        "",
        "| robot counts | start | mean disparity (px) | time (s) | Lloyd iterations | eq. 1 cost (sum) "
        "| frames (f first, p from G_{f-1}, r partly, x fresh) |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    per_frame = []
    for keep in (False, True):
        rows = {}
        for init in (True, False):
            t, kg = _run(frames, n, init, keep, seed, repeat)
            s = _summary(kg)
            rows[init] = s
            modes = "".join({"first": "f", "previous": "p", "partial": "r", "fresh": "x"}[r.mode] for r in kg.reports)
            lines.append(
                f"| {'kept' if keep else 'by area'} | {'previous frame' if init else 'fresh'} | "
                f"{s['disp'].mean():.2f} | {t:.2f} | {s['iters']} | {s['cost']:.4e} | {modes} |"
            )
        per_frame.append((keep, rows))
    lines += ["", "Disparity per frame pair (px), init from previous / fresh:", ""]
    for keep, rows in per_frame:
        pairs = " ".join(f"{a:.1f}/{b:.1f}" for a, b in zip(rows[True]["disp"], rows[False]["disp"]))
        better = int(np.sum(rows[True]["disp"] <= rows[False]["disp"]))
        lines.append(
            f"- {'kept' if keep else 'by area'}: {pairs} (lower or equal with init in "
            f"{better} of {len(rows[True]['disp'])})"
        )
    return lines + [""]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"Seed {args.seed}, median wall time of {args.repeat} runs; load average {load:.2f} at start; "
        f"numpy {np.__version__}, scipy {scipy.__version__}.",
        "",
    ]
    for name, n, size in CASES:
        lines += case_lines(name, n, size, args.seed, args.repeat)
    lines += [
        "Disparity: mean distance between the goals of consecutive keyframes under the assignment of least "
        "total squared distance (scipy's linear_sum_assignment), i.e. how far robots standing on G_{f-1} "
        "move to G_f, in keyframe pixels. Time: the whole keyframe_goals call (segmentation, region "
        "correspondence and motion estimates when initialising, Lloyd, colours), all frames. Cost: eq. 1 "
        "(divided by K_m, normalised square) of each final goal set, summed over the frames (lower is a "
        "more uniform covering). With N_i by area, robots also move between regions whose areas change "
        "(the branch gives robots to the growing leaf), which no per-region initialisation can anticipate.",
    ]
    cmd = f".venv/bin/python -m bench.bench_keyframes --repeat {args.repeat} --seed {args.seed}"
    write_results("keyframes", "Keyframe animation goals: initialised from the previous frame vs fresh", cmd, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
