"""Benchmark of goal generation: N = 1000 goals from a 512 x 512 image, side by side in one run:

- pixelswarm, CVT with the mass density of eq. 2 (the whole pipeline: image -> goal set),
- pixelswarm, the k-means variant (binary density, same pipeline),
- scikit-learn KMeans (n_init=1, k-means++ initialisation) on the same foreground pixels (fit only),
- scikit-learn KMeans started from pixelswarm's initial samples (same start, fit only).

Cost columns: "k-means cost" is the binary-density cost (sum over foreground pixels of the squared
distance to the nearest goal, in the normalised square Q, each pixel weighing its area), computed the
same way for every row; "eq. 1 cost" is the density-weighted cost that the CVT minimises.
Times are medians over --repeat runs (wall clock).

    .venv/bin/python -m bench.bench_goals      # prints the table, writes bench/results/goals.md
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import scipy
from scipy.spatial import cKDTree

from coordinator import shapes
from coordinator.goals import goals_from_prepared, prepare_image
from coordinator.goals.cvt import binary_domain, cvt_cost, density_domain
from coordinator.goals.resize import from_arena
from coordinator.goals.sampling import poisson_samples

from .common import write_results


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


def run(n: int, size: int, shape: str, repeat: int, seed: int) -> tuple[list[dict], dict]:
    img = shapes.draw(shape, size)
    prep = prepare_image(img)
    if len(prep.seg.regions) != 1:
        raise SystemExit(f"shape {shape!r} has {len(prep.seg.regions)} regions; pick a one-region shape")
    rows, cols = prep.seg.pixels(0)
    pts = binary_domain(rows, cols).points
    dens = density_domain(rows, cols)
    scale = prep.scale
    out = []
    for method, label in (
        ("cvt", "pixelswarm CVT, eq. 2 density (image -> goals)"),
        ("kmeans", "pixelswarm k-means variant (image -> goals)"),
    ):

        def job(method=method):
            return goals_from_prepared(prepare_image(img), n, method=method, seed=seed)

        t, gs = _median_time(job, repeat)
        g = from_arena(gs.goals, prep.shape, gs.arena)
        out.append(
            {
                "name": label,
                "time": t,
                "iters": gs.params["iterations"],
                "kmeans_cost": _binary_cost(pts, g, scale),
                "eq1_cost": cvt_cost(dens, g, scale),
            }
        )
    try:
        from sklearn import __version__ as skv
        from sklearn.cluster import KMeans
    except ImportError:  # the reference is a test extra
        skv = None
    if skv is not None:
        init, _ = poisson_samples(rows, cols, n, np.random.default_rng([seed, 0]))
        for label, kw in (
            ("scikit-learn KMeans, n_init=1, k-means++ (fit only)", {"init": "k-means++"}),
            ("scikit-learn KMeans from pixelswarm's initial samples (fit only)", {"init": init}),
        ):

            def job(kw=kw):
                return KMeans(n_clusters=n, n_init=1, random_state=seed, **kw).fit(pts)

            t, km = _median_time(job, repeat)
            c = km.cluster_centers_
            out.append(
                {
                    "name": label,
                    "time": t,
                    "iters": int(km.n_iter_),
                    "kmeans_cost": _binary_cost(pts, c, scale),
                    "eq1_cost": cvt_cost(dens, c, scale),
                }
            )
    info = {"pixels": len(pts), "sklearn": skv}
    return out, info


def table(rows: list[dict]) -> str:
    ref = next((r for r in rows if r["name"].startswith("scikit-learn KMeans, n_init=1")), None)
    lines = [
        "| method | time (s) | iterations | k-means cost | vs KMeans | eq. 1 cost |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        rel = f"{r['kmeans_cost'] / ref['kmeans_cost']:.4f}" if ref else "-"
        lines.append(
            f"| {r['name']} | {r['time']:.3f} | {r['iters']} | {r['kmeans_cost']:.5e} | {rel} | {r['eq1_cost']:.5e} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--shape", default="T", choices=shapes.SHAPES)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    rows, info = run(args.n, args.size, args.shape, args.repeat, args.seed)
    cmd = ".venv/bin/python -m bench.bench_goals" + "".join(
        f" --{k} {v}"
        for k, v in (
            ("n", args.n),
            ("size", args.size),
            ("shape", args.shape),
            ("repeat", args.repeat),
            ("seed", args.seed),
        )
    )
    ours = [r for r in rows if r["name"].startswith("pixelswarm")]
    ref = next((r for r in rows if r["name"].startswith("scikit-learn KMeans, n_init=1")), None)
    lines = [
        f"{args.n} goals from a {args.size} x {args.size} image of the `{args.shape}` shape "
        f"({info['pixels']} foreground pixels), seed {args.seed}, median wall time of {args.repeat} runs; "
        f"load average {load:.2f} at start; numpy {np.__version__}, scipy {scipy.__version__}, "
        f"scikit-learn {info['sklearn'] or 'not installed'}.",
        "",
        table(rows),
        "",
        "- goal `<= 1 s` (image -> goals): " + ", ".join(f"{r['name'].split(' (')[0]} {r['time']:.2f} s" for r in ours),
    ]
    if ref:
        lines.append(
            "- goal `cost <= KMeans`: "
            + ", ".join(
                f"{r['name'].split(' (')[0]} {'yes' if r['kmeans_cost'] <= ref['kmeans_cost'] else 'no'} "
                f"({r['kmeans_cost'] / ref['kmeans_cost']:.4f})"
                for r in ours
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
    write_results("goals", f"Goal generation: {args.n} goals from a {args.size} x {args.size} image", cmd, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
