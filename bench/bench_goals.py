"""Benchmark of goal generation at 1,000 and 10,000 goals, side by side in one run:

- pixelswarm now, CVT with the mass density of eq. 2 (the whole pipeline: image -> goal set),
- pixelswarm at ``--before REV`` (a temporary git worktree of that revision, same pipeline),
- scikit-learn KMeans (n_init=1, k-means++ initialisation) on the same foreground pixels (fit only).

Each case draws one shape (``--shape``) at its size in pixels. Cost columns: "k-means cost" is the
binary-density cost (sum over the foreground pixels of the squared distance to the nearest goal, in
the normalised square Q, each pixel weighing its area), computed by the same code for every row;
"eq. 1 cost" is the density-weighted cost that the CVT minimises. pixelswarm times are medians over
--repeat runs (wall clock); KMeans runs once a case (minutes at 10,000 goals).

    .venv/bin/python -m bench.bench_goals      # prints the table, writes bench/results/goals.md
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy
from scipy.spatial import cKDTree

from coordinator import shapes
from coordinator.goals import GoalOptions, goals_from_prepared, prepare_image
from coordinator.goals.cvt import binary_domain, density_domain
from coordinator.goals.resize import from_arena
from tests.support.goal_sets import cvt_cost

from .bench_runtime import worktree_at
from .common import write_results

BEFORE = "faa56e5"  # main before the lattice start and the local bounds of the Lloyd search (issue 43)
CASES = "1000:512,10000:1024"  # goals:pixels, the image's side

# Run in a worktree of --before: its own pipeline, timed the same way; the goals (pixels) to a file.
_BEFORE_JOB = """
import json, statistics, sys, time
import numpy as np
from coordinator import shapes
from coordinator.goals import goals_from_prepared, prepare_image
from coordinator.goals.resize import from_arena
shape, size, n, seed, repeat, out = sys.argv[1:]
img = shapes.draw(shape, int(size))
times = []
for _ in range(int(repeat)):
    t = time.perf_counter()
    gs = goals_from_prepared(prepare_image(img), int(n), seed=int(seed))
    times.append(time.perf_counter() - t)
np.save(out, from_arena(gs.goals, img.shape, gs.arena))
print(json.dumps({"time": statistics.median(times), "iters": gs.params["iterations"]}))
"""


def _median_time(fn, repeat: int):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def _binary_cost(points: np.ndarray, centres: np.ndarray, scale: float) -> float:
    d, _ = cKDTree(centres).query(points, workers=-1)
    return float(np.dot(d, d)) / scale**4


def run_case(n: int, size: int, shape: str, repeat: int, seed: int, before: Path | None) -> tuple[list[dict], int]:
    img = shapes.draw(shape, size)
    prep = prepare_image(img)
    if len(prep.seg.regions) != 1:
        raise SystemExit(f"shape {shape!r} has {len(prep.seg.regions)} regions; pick a one-region shape")
    rows, cols = prep.seg.pixels(0)
    pts = binary_domain(rows, cols).points
    dens = density_domain(rows, cols)

    def row(name: str, t: float, iters: int, goals_px: np.ndarray) -> dict:
        k, e = _binary_cost(pts, goals_px, prep.scale), cvt_cost(dens, goals_px, prep.scale)
        return {"n": n, "size": size, "name": name, "time": t, "iters": iters, "kmeans_cost": k, "eq1_cost": e}

    t, gs = _median_time(lambda: goals_from_prepared(prepare_image(img), n, GoalOptions(seed=seed)), repeat)
    out = [
        row("pixelswarm now (image -> goals)", t, gs.params["iterations"], from_arena(gs.goals, prep.shape, gs.arena))
    ]
    if before is not None:
        with tempfile.TemporaryDirectory() as tmp:
            dump = str(Path(tmp) / "goals.npy")
            job = [sys.executable, "-c", _BEFORE_JOB, shape, str(size), str(n), str(seed), str(repeat), dump]
            res = json.loads(subprocess.run(job, cwd=before, check=True, capture_output=True, text=True).stdout)
            out.append(row("pixelswarm before (image -> goals)", res["time"], res["iters"], np.load(dump)))
    try:
        from sklearn.cluster import KMeans
    except ImportError:  # the reference is a test extra
        return out, len(pts)
    t, km = _median_time(lambda: KMeans(n_clusters=n, n_init=1, random_state=seed).fit(pts), 1)
    out.append(row("scikit-learn KMeans, k-means++ (fit only)", t, int(km.n_iter_), km.cluster_centers_))
    return out, len(pts)


def table(rows: list[dict]) -> str:
    lines = [
        "| goals | method | time (s) | iterations | k-means cost | vs KMeans | eq. 1 cost |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        ref = next((q for q in rows if q["n"] == r["n"] and q["name"].startswith("scikit-learn")), None)
        rel = f"{r['kmeans_cost'] / ref['kmeans_cost']:.4f}" if ref else "-"
        lines.append(
            f"| {r['n']} | {r['name']} | {r['time']:.3f} | {r['iters']} | {r['kmeans_cost']:.5e} | {rel} "
            f"| {r['eq1_cost']:.5e} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=CASES, help="goals:pixels of the image's side, comma-separated")
    ap.add_argument("--shape", default="T", choices=shapes.SHAPES)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--before", default=BEFORE, help="git revision to run beside this checkout ('' for none)")
    args = ap.parse_args(argv)
    try:
        cases = [tuple(int(v) for v in c.split(":")) for c in args.cases.split(",")]
        assert all(len(c) == 2 and min(c) > 0 for c in cases) and args.repeat > 0
    except (ValueError, AssertionError):
        ap.error("--cases is goals:pixels,... of positive whole numbers, --repeat positive")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    rows: list[dict] = []
    pixels: dict[int, int] = {}
    with (
        worktree_at(args.before, build=False) if args.before else contextlib.nullcontext((None, None)) as (tree, commit)
    ):
        for n, size in cases:
            case, pixels[n] = run_case(n, size, args.shape, args.repeat, args.seed, tree)
            rows += case
            print(table(case), flush=True)
    cmd = (
        f".venv/bin/python -m bench.bench_goals --cases {args.cases} --shape {args.shape} --repeat {args.repeat} "
        f"--seed {args.seed} --before {args.before or repr('')}"
    )
    ours = [r for r in rows if r["name"].startswith("pixelswarm now")]
    refs = {r["n"]: r for r in rows if r["name"].startswith("scikit-learn")}
    lines = [
        f"The `{args.shape}` shape, {', '.join(f'{n} goals from {s} x {s} pixels ({pixels[n]} foreground)' for n, s in cases)}; "
        f"seed {args.seed}; pixelswarm: median wall time of {args.repeat} runs; before: {commit or 'not run'}; "
        f"load average {load:.2f} at start; numpy {np.__version__}, scipy {scipy.__version__}.",
        "",
        table(rows),
        "",
        "- goal `<= 3 s` at 10,000 goals (image -> goals): " + ", ".join(f"{r['n']}: {r['time']:.2f} s" for r in ours),
    ]
    if refs:
        lines.append(
            "- goal `cost <= KMeans`: "
            + ", ".join(
                f"{r['n']}: {'yes' if r['kmeans_cost'] <= refs[r['n']]['kmeans_cost'] else 'no'} "
                f"({r['kmeans_cost'] / refs[r['n']]['kmeans_cost']:.4f})"
                for r in ours
                if r["n"] in refs
            )
        )
    lines += [
        "",
        "k-means cost: sum over the foreground pixels of the squared distance to the nearest goal (binary "
        "density) in the normalised square (longer image side = 1), each pixel weighing its area; "
        "eq. 1 cost: the same with the mass density of eq. 2 (divided by K_m). pixelswarm times cover the "
        "whole pipeline (segmentation, initial samples, Lloyd, colours, resizing); scikit-learn times "
        "cover the fit on the foreground pixels only.",
    ]
    write_results("goals", "Goal generation at 1,000 and 10,000 goals", cmd, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
