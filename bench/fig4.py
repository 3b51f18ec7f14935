"""Reproduce the paper's Fig. 4: normalised cost of eq. 1 per Lloyd iteration for 14 goals on six
images (disk; disk and line with 10+4 and 6+8 robots; line; L; T), 25 seeded runs each.

The cost of each run is divided by the highest initial cost among the 25 runs of its image (as in the
paper). Top: the inputs; middle: the lowest-cost goal set of each image; bottom: the cost curves of
plain Lloyd (as in the paper, relax=1) and of pixelswarm's default (over-relaxed Lloyd, never rising).

    .venv/bin/python -m bench.fig4          # writes docs/fig4_cvt_cost.png and prints a summary
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from coordinator import shapes
from coordinator.goals import goals_from_prepared, prepare_image
from coordinator.goals.cvt import RELAX
from coordinator.goals.resize import from_arena

OUT = Path(__file__).resolve().parent.parent / "docs" / "fig4_cvt_cost.png"
CASES = [
    ("disk", None, "disk"),
    ("disk_and_line", {0: 10, 1: 4}, "disk and line 10+4"),
    ("disk_and_line", {0: 6, 1: 8}, "disk and line 6+8"),
    ("line", None, "line"),
    ("L", None, "L"),
    ("T", None, "T"),
]
COLOURS = ["tab:red", "tab:orange", "tab:purple", "tab:blue", "tab:green", "tab:brown"]


def runs(size: int, n: int, seeds: int, relax: float) -> list[dict]:
    """Per case: image, prepared image, normalised cost histories and the best goal set."""
    out = []
    for name, counts, title in CASES:
        img = shapes.draw(name, size)
        prep = prepare_image(img)
        sets = [goals_from_prepared(prep, n, seed=s, region_counts=counts, relax=relax) for s in range(seeds)]
        top = max(gs.cost_history[0] for gs in sets)
        hists = [np.asarray(gs.cost_history) / top for gs in sets]
        best = min(sets, key=lambda gs: gs.cost_history[-1])
        out.append({"title": title, "img": img, "prep": prep, "hists": hists, "best": best})
    return out


def summary(label: str, cases: list[dict]) -> list[str]:
    lines = []
    for c in cases:
        rises = sum(int(np.any(np.diff(h) > 1e-12 * h[:-1])) for h in c["hists"])
        at30 = max(h[min(30, len(h) - 1)] / h[-1] - 1 for h in c["hists"])
        iters = [len(h) - 1 for h in c["hists"]]
        lines.append(
            f"{label:>9} | {c['title']:<20} | runs with a rise: {rises} | worst gap to final at "
            f"iteration 30: {100 * at30:.2f} % | iterations {min(iters)}-{max(iters)}"
        )
    return lines


def plot(plain: list[dict], default: list[dict], path: Path, relax: float) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 8.5))
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(3, 6, height_ratios=[1, 1, 1.6])
    for i, c in enumerate(default):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(c["img"], interpolation="nearest")
        ax.set_title(c["title"], fontsize=9)
        ax.axis("off")
        ax = fig.add_subplot(gs[1, i])
        best = c["best"]
        px = from_arena(best.goals, c["prep"].shape, best.arena)
        ax.imshow(0.35 * c["img"] / 255.0 + 0.65, interpolation="nearest")
        ax.scatter(px[:, 0] - 0.5, px[:, 1] - 0.5, s=22, c=best.colors / 255.0, edgecolors="black", linewidths=0.5)
        ax.axis("off")
    for j, (cases, title) in enumerate(
        ((plain, "plain Lloyd (paper)"), (default, f"pixelswarm default (over-relaxed, relax={relax:g})"))
    ):
        ax = fig.add_subplot(gs[2, 3 * j : 3 * j + 3])
        for c, col in zip(cases, COLOURS):
            for k, h in enumerate(c["hists"]):
                ax.plot(np.arange(len(h)), h, color=col, lw=0.7, alpha=0.6, label=c["title"] if k == 0 else None)
        ax.set_xlim(0, 60)
        ax.set_xlabel("iteration")
        ax.set_ylabel("normalised cost (eq. 1)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        if j == 0:
            ax.legend(fontsize=7)
    fig.suptitle("Fig. 4 reproduced: 14 goals, 25 seeded runs per image", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256, help="image side in pixels")
    ap.add_argument("--n", type=int, default=14)
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    plain = runs(args.size, args.n, args.seeds, 1.0)
    default = runs(args.size, args.n, args.seeds, RELAX)
    print("\n".join(summary("plain", plain) + summary("default", default)))
    plot(plain, default, args.out, RELAX)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
