"""The paper reproduced: Figs. 13-15 with the central engine (the default), Fig. 4's cost per Lloyd
iteration, and its animations measured (6.1-6.2): each keyframe's goals started from the previous
frame's, and the auction of a keyframe started from the carried assignment. One module, a benchmark per
name; each writes its figures to docs/ or its table to bench/results/<name>.md:

    .venv/bin/python -m bench.paper_figures [--quick]      # Figs. 13-15: docs/fig1[345]_*.png, paper_figures.md
    .venv/bin/python -m bench.paper_figures fig4           # docs/fig4_cvt_cost.png
    .venv/bin/python -m bench.paper_figures keyframes [--repeat 3] [--seed 0]
    .venv/bin/python -m bench.paper_figures carry [--robots 100] [--hosts 10] [--no-paper]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import statistics
import sys
import tempfile
import time
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

import sim.central.engine as central
from agent.assignment import frames_close
from agent.core.bidder import Participant
from agent.core.params import RobotParams
from coordinator import shapes
from coordinator.drawings import keyframes
from coordinator.goals import GoalOptions, goals_from_prepared, prepare_image
from coordinator.goals.cvt import RELAX
from coordinator.goals.resize import from_arena
from coordinator.keyframes import KeyframeGoals, goal_correspondence, keyframe_goals
from coordinator.scene import Scene, resolve_scene_path, scene_from_dict, scene_goal_set
from coordinator.warm_start import goal_matching

from .common import REPO, RESULTS, machine, parser_for, run_subcommand, write_results

# --- Figs. 13-15 (the default) ----------------------------------------------------------------
FIGURES_DOC = """Reproduce the paper's Figs. 13, 14 and 15 (section 7.2) with the central engine.

Fig. 13: path length per robot and in total over R runs of the Fig. 12 sequence (paper-sequence,
14 e-pucks, seeds 1..R: the goal sets are regenerated per run, the start grid is the same), at
epsilon_A = 0.001 m^2. Fig. 14: for epsilon_A in {1, 0.1, 0.01, 0.001} m^2, (a) the computation time
of the goal auction (every control iteration, 10 Hz; cold starts at image changes marked) and (b) the
execution time (time to converge, per transition and summed), plus the assignment cost against the
optimum (scipy's linear_sum_assignment on the same positions). Fig. 15: the trajectories of one
transition under a poor (1 m^2) and a good (0.001 m^2) epsilon_A.

The paper's runs are physical e-pucks; these are simulated e-pucks (differential drive, 2 mm / 3 deg
tracking noise, 2 % actuation noise) stepped by the central engine, which re-auctions every iteration
warm-started, with the hysteresis Delta C of the scene's robot parameters.

    .venv/bin/python -m bench.paper_figures              # 25 runs x 4 epsilons, docs/fig1[345]_*.png
    .venv/bin/python -m bench.paper_figures --quick      # 2 runs x 2 epsilons, 3 short steps
"""


SCENE = "paper-sequence"
EPSILONS = (1.0, 0.1, 0.01, 0.001)  # m^2, paper 7.2.2
FIG13_EPS = 0.001
QUICK_EPSILONS = (1.0, 0.001)
QUICK_STEPS, QUICK_HOLD = 3, 25.0
ENGINE_NOTE = "central engine, simulated e-pucks with 2 mm tracking noise"


# --- measuring the auction -----------------------------------------------------------------------
@dataclass
class AuctionCalls:
    """Every call of the goal auction in one run: its timing and how good its assignment is."""

    wall_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)  # thread CPU time: insensitive to a loaded machine
    rounds: list[int] = field(default_factory=list)
    cold: list[bool] = field(default_factory=list)  # view=None: the first call after an image change
    cost: list[float] = field(default_factory=list)  # eq. 7 on the positions the auction saw (m^2)
    optimum: list[float] = field(default_factory=list)  # linear_sum_assignment on the same positions


class TimedAuction:
    """Stands in for sim.central.engine.auction_assignment (one block of the agents' auction, settled in the
    engine): times each call, then (outside the timed part) scores it."""

    def __init__(self, assign: Any) -> None:
        self.assign = assign
        self.calls = AuctionCalls()

    def __call__(self, auction: Any, position: np.ndarray) -> np.ndarray:
        cold, rounds = not auction.started, auction.rounds  # a fresh participant: the image's cold start
        c0, w0 = time.thread_time(), time.perf_counter()
        held = self.assign(auction, position)
        w1, c1 = time.perf_counter(), time.thread_time()
        goals = auction.goals
        cost = ((position[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
        r, c = linear_sum_assignment(cost)
        calls = self.calls
        calls.wall_s.append(w1 - w0)
        calls.cpu_s.append(c1 - c0)
        calls.rounds.append(auction.rounds - rounds)
        calls.cold.append(cold)
        calls.cost.append(float(cost[np.arange(len(position)), held].sum()) if (held >= 0).all() else math.nan)
        calls.optimum.append(float(cost[r, c].sum()))
        return held


@contextmanager
def timed_auction() -> Iterator[AuctionCalls]:
    """Patch the central engine's auction for the duration of one run (sim/central/engine.py untouched)."""
    timed = TimedAuction(central.auction_assignment)
    central.auction_assignment = timed
    try:
        yield timed.calls
    finally:
        central.auction_assignment = timed.assign


# --- one run -------------------------------------------------------------------------------------
@dataclass
class Run:
    eps: float
    seed: int
    wall_s: float
    path: np.ndarray  # (K, N) m: each robot's path while step k was shown
    converged_at: list[float | None]  # per step, seconds after the image change (None: not within the hold)
    reassignments: np.ndarray  # (K,) goal changes after each step's first iteration (all robots)
    contacts: int
    calls: AuctionCalls
    xy: np.ndarray | None = None  # (T, N, 2) true positions, kept only for the Fig. 15 epsilons
    step: np.ndarray | None = None  # (T,)
    goal_sets: list[np.ndarray] = field(default_factory=list)


def scene_data(quick: bool) -> dict[str, Any]:
    data = tomllib.loads(resolve_scene_path(SCENE).read_text())
    if quick:  # the first transitions only, shorter holds: a bounded smoke run for the test
        data["steps"] = [dict(s, hold=QUICK_HOLD) for s in data["steps"][:QUICK_STEPS]]
    return data


def make_scene(data: dict[str, Any], eps: float, seed: int) -> Scene:
    data = dict(data, robot=dict(data.get("robot", {}), assign_eps=eps))
    return scene_from_dict(data, source=str(resolve_scene_path(SCENE)), seed=seed)


def run_once(data: dict[str, Any], eps: float, seed: int, keep_xy: bool) -> Run:
    scene = make_scene(data, eps, seed)
    assert RobotParams.from_dict(scene.robot).assign_eps == eps  # the override reaches the engine
    with tempfile.TemporaryDirectory(prefix="paper_figures_") as tmp, timed_auction() as calls:
        w0 = time.perf_counter()
        out = central.run_central(scene, Path(tmp) / "run", video=False, progress=None)
        wall = time.perf_counter() - w0
        metrics = json.loads((out / "metrics.json").read_text())
        traj = np.load(out / "trajectory.npz")
        pose, step, assignment = traj["pose"], traj["step"].astype(int), traj["assignment"]
    k_steps = len(scene.steps)
    moved = np.sqrt((np.diff(pose[:, :, :2], axis=0) ** 2).sum(-1))  # (T-1, N), sample k -> k+1
    path = np.array([moved[step[:-1] == k].sum(axis=0) for k in range(k_steps)])
    # Robots whose goal changed from one tick to the next within a step (a swap counts two).
    same = np.r_[False, step[1:] == step[:-1]]
    n_changes = np.r_[0, (assignment[1:] != assignment[:-1]).sum(axis=1)]
    reassign = np.array([int(n_changes[same & (step == k)].sum()) for k in range(k_steps)])
    steps = sorted(metrics["steps"], key=lambda s: s["index"])
    run = Run(eps, seed, wall, path, [s["converged_at"] for s in steps], reassign, int(metrics["contacts"]), calls)
    if keep_xy:
        run.xy, run.step = pose[:, :, :2].astype(np.float32), step
        run.goal_sets = [np.array(scene_goal_set(scene, k, scene.robots)[0]) for k in range(k_steps)]
    return run


# --- statistics ----------------------------------------------------------------------------------
def transition_labels(data: dict[str, Any]) -> list[str]:
    def short(s: dict[str, Any]) -> str:
        return str(s.get("name", s.get("shape"))).replace("disk_and_line_", "disk+line ").replace("_", "/")

    names = [data.get("layout", {}).get("kind", "start")] + [short(s) for s in data["steps"]]
    return [f"{a} -> {b}" for a, b in zip(names, names[1:])]


def execution_times(run: Run, holds: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Per step the time to converge (censored at the hold when it never converged) and the mask of
    censored steps."""
    t = np.array([c if c is not None else h for c, h in zip(run.converged_at, holds)], float)
    return t, np.array([c is None for c in run.converged_at])


def first_call_ratio(run: Run) -> np.ndarray:
    """(K,) cost / optimum of each step's cold-start assignment."""
    cold = np.flatnonzero(run.calls.cold)
    return np.array(run.calls.cost)[cold] / np.array(run.calls.optimum)[cold]


def mean_std(x: np.ndarray) -> str:
    return f"{np.mean(x):.2f} ± {np.std(x):.2f}"


@dataclass
class Summary:
    """The numbers behind the figures (also what the test checks)."""

    labels: list[str]
    holds: list[float]
    runs: dict[float, list[Run]]
    fig15: tuple[int, int]  # (step, seed)
    wall_s: float = 0.0

    def per_eps(self, eps: float) -> dict[str, Any]:
        runs = self.runs[eps]
        wall = np.concatenate([r.calls.wall_s for r in runs])
        cpu = np.concatenate([r.calls.cpu_s for r in runs])
        cold = np.concatenate([r.calls.cold for r in runs]).astype(bool)
        rounds = np.concatenate([r.calls.rounds for r in runs])
        # Every iteration: the excess over the optimum (a ratio explodes once the robots sit on their goals).
        excess = np.concatenate([np.array(r.calls.cost) - np.array(r.calls.optimum) for r in runs])
        first = np.array([first_call_ratio(r) for r in runs])  # (R, K)
        first_cost = np.array([np.array(r.calls.cost)[np.array(r.calls.cold)] for r in runs])
        ex = [execution_times(r, self.holds) for r in runs]
        return {
            "wall_ms": 1e3 * wall,
            "cpu_ms": 1e3 * cpu,
            "cold": cold,
            "rounds": rounds,
            "excess": excess,
            "ratio_first": first,
            "first_cost": first_cost,
            "exec": np.array([e[0] for e in ex]),
            "censored": np.array([e[1] for e in ex]),
            "path_total": np.array([r.path.sum() for r in runs]),
            "reassign": np.array([r.reassignments for r in runs]),
            "contacts": sum(r.contacts for r in runs),
        }


# --- figures -------------------------------------------------------------------------------------
def _figure(size: tuple[float, float]) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


def plot_fig13(s: Summary, path: Path) -> None:
    runs = s.runs[FIG13_EPS]
    per_robot = np.array([r.path.sum(axis=0) for r in runs])  # (R, N)
    per_step = np.array([r.path.sum(axis=1) for r in runs])  # (R, K)
    n = per_robot.shape[1]
    fig = _figure((12, 8.5))
    ax = fig.add_subplot(2, 1, 1)
    ax.boxplot(list(per_robot.T), positions=np.arange(1, n + 1), widths=0.6, manage_ticks=False)
    ax.set_ylabel("path length over the sequence (m)")
    right = ax.twinx()  # the summed total on its own axis, as in the paper
    red = {"color": "tab:red"}
    right.boxplot(
        [per_robot.sum(axis=1)],
        positions=[n + 1.2],
        widths=0.6,
        manage_ticks=False,
        boxprops=red,
        medianprops=red,
        whiskerprops=red,
        capprops=red,
        flierprops={"markeredgecolor": "tab:red"},
    )
    right.set_ylabel("summed total path length (m)", color="tab:red")
    # Ticks last: the twin axis shares x, and its boxplot would otherwise relabel it.
    ax.set_xlim(0.3, n + 1.9)
    ax.set_xticks(list(range(1, n + 1)) + [n + 1.2], [str(i) for i in range(n)] + ["total"])
    ax.set_xlabel("robot id")
    ax.axvline(n + 0.6, color="grey", lw=0.6)
    ax.set_title(
        f"Fig. 13: path length per robot (left axis) and summed over the 14 robots (right axis), "
        f"{len(runs)} runs, epsilon_A = {FIG13_EPS:g} m²",
        fontsize=10,
    )
    ax = fig.add_subplot(2, 1, 2)
    ax.boxplot(list(per_step.T), widths=0.6)
    ax.set_xticks(range(1, len(s.labels) + 1), s.labels, fontsize=8)
    for k, col in enumerate(per_step.T):
        ax.annotate(
            f"{col.mean():.1f}", (k + 1, col.max()), textcoords="offset points", xytext=(0, 4), ha="center", fontsize=8
        )
    ax.set_ylabel("summed path length (m)")
    ax.set_title("per transition: all 14 robots' path while the image was shown (mean above each box)", fontsize=10)
    fig.suptitle(
        f"Paper-sequence, {ENGINE_NOTE}; seeds 1..{len(runs)} (goal sets regenerated per run, same start grid)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_fig14(s: Summary, path: Path) -> None:
    eps_list = sorted(s.runs, reverse=True)
    stats = [s.per_eps(e) for e in eps_list]
    x = np.arange(1, len(eps_list) + 1)
    names = [f"{e:g}" for e in eps_list]
    fig = _figure((13, 9))
    ax = fig.add_subplot(2, 2, 1)
    # Tens of thousands of calls: whiskers at the 1st / 99th percentile, the maximum as a bar.
    red = {"color": "tab:red"}
    ax.boxplot([st["wall_ms"] for st in stats], positions=x - 0.18, widths=0.3, whis=(1, 99), showfliers=False)
    ax.boxplot(
        [st["wall_ms"][st["cold"]] for st in stats],
        positions=x + 0.18,
        widths=0.3,
        whis=(1, 99),
        showfliers=False,
        boxprops=red,
        medianprops=red,
        whiskerprops=red,
        capprops=red,
    )
    for xi, st in zip(x, stats):  # CPU time beside: what the wall time would be on an idle machine
        cold = st["cold"]
        ax.plot([xi - 0.18, xi + 0.18], [st["wall_ms"].max(), st["wall_ms"][cold].max()], "_", color="grey", ms=12)
        ax.plot([xi - 0.18, xi + 0.18], [st["wall_ms"].mean(), st["wall_ms"][cold].mean()], "k^", ms=6, zorder=5)
        ax.plot(
            [xi - 0.18, xi + 0.18],
            [st["cpu_ms"].mean(), st["cpu_ms"][cold].mean()],
            "D",
            color="tab:green",
            ms=5,
            zorder=5,
        )
    ax.set_yscale("log")
    ax.set_xticks(x, names)
    ax.set_xlabel("epsilon_A (m²)")
    ax.set_ylabel("auction wall time per call (ms)")
    ax.set_title(
        "(a) auction time per call: every iteration (black), cold starts at an image change (red);\n"
        "whiskers 1-99 %, ▲ mean wall, ◆ mean thread CPU, – max",
        fontsize=10,
    )
    ax = fig.add_subplot(2, 2, 2)
    ax.boxplot([st["exec"].sum(axis=1) for st in stats], widths=0.5)
    ax.set_xticks(x, names)
    ax.set_xlabel("epsilon_A (m²)")
    ax.set_ylabel("execution time, summed over the transitions (s)")
    cens = ", ".join(f"{int(st['censored'].sum())}" for st in stats)
    ax.set_title(
        "(b) execution time: time to converge, summed over the transitions"
        + (
            f"\ntransitions not converged within the hold (counted as the hold): {cens} of {stats[0]['censored'].size}"
            if any(st["censored"].any() for st in stats)
            else ""
        ),
        fontsize=10,
    )
    ax = fig.add_subplot(2, 2, 3)
    k = len(s.labels)
    width = 0.8 / len(eps_list)
    for j, (e, st) in enumerate(zip(eps_list, stats)):
        pos = np.arange(k) + (j - (len(eps_list) - 1) / 2) * width
        ax.bar(pos, st["exec"].mean(axis=0), width, yerr=st["exec"].std(axis=0), capsize=2, label=f"{e:g} m²")
    ax.set_xticks(range(k), s.labels, fontsize=8, rotation=20, ha="right")
    ax.set_ylabel("time to converge (s), mean ± std")
    ax.legend(title="epsilon_A", fontsize=8)
    ax.set_title("(b') execution time per transition", fontsize=10)
    ax = fig.add_subplot(2, 2, 4)
    ax.boxplot([st["ratio_first"].ravel() for st in stats], widths=0.5, sym=".")
    for xi, st in zip(x, stats):
        off = np.mean(st["excess"] > 1e-9)
        ax.annotate(
            f"not optimal at\n{100 * off:.1f} % of iterations",
            (xi, st["ratio_first"].max()),
            textcoords="offset points",
            xytext=(0, 6),
            ha="center",
            fontsize=8,
        )
    ax.set_xticks(x, names)
    ax.set_xlabel("epsilon_A (m²)")
    ax.set_ylabel("assignment cost / optimal cost (eq. 7)")
    ax.margins(y=0.2)
    ax.set_title(
        "(c) cost of each transition's first (cold-start) assignment against\n"
        "linear_sum_assignment on the same positions",
        fontsize=10,
    )
    runs = len(next(iter(s.runs.values())))
    fig.suptitle(f"Fig. 14: effect of epsilon_A, {runs} runs per value of paper-sequence; {ENGINE_NOTE}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_fig15(s: Summary, path: Path) -> None:
    k, seed = s.fig15
    eps_pair = (max(s.runs), min(s.runs))
    fig = _figure((11, 6.5))
    from matplotlib import colormaps

    cmap = colormaps["tab20"]
    first = None
    for j, eps in enumerate(eps_pair):
        run = next(r for r in s.runs[eps] if r.seed == seed)
        assert run.xy is not None and run.step is not None
        xy = run.xy[run.step == k]
        ax = fig.add_subplot(1, 2, j + 1, sharex=first, sharey=first)
        first = first or ax
        for i in range(xy.shape[1]):
            ax.plot(xy[:, i, 0], xy[:, i, 1], color=cmap(i % 20), lw=1.2)
            ax.plot(*xy[0, i], "o", color=cmap(i % 20), ms=5, mfc="none")
            ax.plot(*xy[-1, i], "o", color=cmap(i % 20), ms=4)
        g = run.goal_sets[k]
        ax.plot(g[:, 0], g[:, 1], "kx", ms=8, mew=1.5, label="goals")
        ax.set_aspect("equal")
        ex = run.converged_at[k]
        ax.set_title(
            f"epsilon_A = {eps:g} m²: path {run.path[k].sum():.1f} m, "
            f"{run.reassignments[k]} reassignments,\nconverged "
            + (f"after {ex:.1f} s" if ex is not None else "not within the hold"),
            fontsize=10,
        )
        ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle(
        f"Fig. 15: trajectories of the 14 robots, transition {s.labels[k]} (seed {seed}); "
        f"o start, ● end, x goals\n{ENGINE_NOTE}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def pick_fig15(runs: dict[float, list[Run]]) -> tuple[int, int]:
    """The transition where a poor epsilon_A lengthens the paths most on average (paired by seed),
    and on it the run whose excess is the median one: a typical example, not the worst."""
    poor = {r.seed: r for r in runs[max(runs)]}
    good = {r.seed: r for r in runs[min(runs)]}
    seeds = sorted(poor)
    excess = np.array([poor[s].path.sum(axis=1) - good[s].path.sum(axis=1) for s in seeds])  # (R, K)
    start = 1 if excess.shape[1] > 1 else 0  # not the move out of the start grid
    k = start + int(np.argmax(excess[:, start:].mean(axis=0)))
    order = np.argsort(excess[:, k])
    return k, seeds[int(order[len(order) // 2])]


# --- the results file ----------------------------------------------------------------------------
def results_lines(s: Summary, hysteresis: float) -> list[str]:
    runs13 = s.runs[FIG13_EPS]
    n_runs = len(runs13)
    per_step = np.array([r.path.sum(axis=1) for r in runs13])
    per_robot = np.array([r.path.sum(axis=0) for r in runs13])
    out = [
        f"{n_runs} runs per epsilon_A of `{SCENE}` (paper Fig. 12: 14 differential-drive e-pucks, "
        f"{len(s.labels)} images, {s.holds[0]:g} s holds), seeds 1..{n_runs}, {ENGINE_NOTE} (3 deg, 2 % "
        f"actuation noise). The goal auction re-runs every 0.1 s iteration warm-started, Delta C = "
        f"{hysteresis:g} m²; cold start (epsilon scaling) at each image change. Total wall time "
        f"{s.wall_s / 60:.1f} min; load average {os.getloadavg()[0]:.2f} at the end (2-core machine shared with "
        "other work: the auction's thread CPU time is given beside its wall time, as a load-insensitive "
        "check).",
        "",
        f"### Fig. 13: path length at epsilon_A = {FIG13_EPS:g} m² (`docs/fig13_path_length.png`)",
        "",
        "| transition | summed path length (m), mean ± std | min | max |",
        "|---|---:|---:|---:|",
    ]
    for label, col in zip(s.labels, per_step.T):
        out.append(f"| {label} | {mean_std(col)} | {col.min():.2f} | {col.max():.2f} |")
    tot = per_step.sum(axis=1)
    out += [
        f"| **whole sequence** | {mean_std(tot)} | {tot.min():.2f} | {tot.max():.2f} |",
        "",
        "Per robot over the sequence (m, mean ± std): "
        + ", ".join(f"{i}: {mean_std(c)}" for i, c in enumerate(per_robot.T))
        + f". Relative spread (std / mean): per robot {np.mean(per_robot.std(0) / per_robot.mean(0)):.1%} "
        f"on average, summed total {tot.std() / tot.mean():.1%} (paper: large per robot, small in total).",
        "",
        "### Fig. 14: epsilon_A (`docs/fig14_epsilon.png`)",
        "",
        "| epsilon_A (m²) | auction calls | per iteration, mean wall (ms) | median / p99 wall (ms) | "
        "mean CPU (ms) | cold start mean wall / CPU / max wall (ms) | cold start rounds | execution time (s) | "
        "not converged | cost ratio, first iteration: mean / max | iterations not optimal | "
        "reassignments per run | total path (m) | contacts |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    eps_list = sorted(s.runs, reverse=True)
    for e in eps_list:
        st = s.per_eps(e)
        w, c = st["wall_ms"], st["cold"]
        out.append(
            f"| {e:g} | {len(w)} | {w.mean():.3f} | {np.median(w):.3f} / {np.percentile(w, 99):.2f} | "
            f"{st['cpu_ms'].mean():.3f} | {w[c].mean():.2f} / {st['cpu_ms'][c].mean():.2f} / {w[c].max():.2f} | "
            f"{st['rounds'][c].mean():.0f} | {mean_std(st['exec'].sum(axis=1))} | "
            f"{int(st['censored'].sum())} of {st['censored'].size} | "
            f"{st['ratio_first'].mean():.3f} / {st['ratio_first'].max():.3f} | "
            f"{100 * np.mean(st['excess'] > 1e-9):.1f} % | {st['reassign'].sum(axis=1).mean():.1f} | "
            f"{mean_std(st['path_total'])} | {st['contacts']} |"
        )
    out += [
        "",
        "Execution time per transition (s, mean ± std; a transition not converged within its hold counts as the hold):",
        "",
        "| epsilon_A (m²) | " + " | ".join(s.labels) + " |",
        "|---:|" + "---:|" * len(s.labels),
    ]
    for e in eps_list:
        ex = s.per_eps(e)["exec"]
        out.append(f"| {e:g} | " + " | ".join(mean_std(col) for col in ex.T) + " |")
    out += [
        "",
        "Summed path length per transition (m, mean ± std):",
        "",
        "| epsilon_A (m²) | " + " | ".join(s.labels) + " |",
        "|---:|" + "---:|" * len(s.labels),
    ]
    for e in eps_list:
        paths = np.array([r.path.sum(axis=1) for r in s.runs[e]])
        out.append(f"| {e:g} | " + " | ".join(mean_std(col) for col in paths.T) + " |")
    out += [
        "",
        "Cost ratio of each transition's first (cold-start) assignment, mean (max):",
        "",
        "| epsilon_A (m²) | " + " | ".join(s.labels) + " |",
        "|---:|" + "---:|" * len(s.labels),
    ]
    for e in eps_list:
        r = s.per_eps(e)["ratio_first"]
        out.append(f"| {e:g} | " + " | ".join(f"{col.mean():.3f} ({col.max():.3f})" for col in r.T) + " |")
    k, seed = s.fig15
    out += [
        "",
        "### Fig. 15: trajectories (`docs/fig15_trajectories.png`)",
        "",
        f"Transition {s.labels[k]}, seed {seed}: the transition where epsilon_A = {max(s.runs):g} m² lengthens "
        f"the summed path most on average over the paired runs, and its median run.",
        "",
        "| epsilon_A (m²) | summed path (m) | reassignments | time to converge (s) |",
        "|---:|---:|---:|---:|",
    ]
    for e in (max(s.runs), min(s.runs)):
        run = next(r for r in s.runs[e] if r.seed == seed)
        ex = run.converged_at[k]
        out.append(
            f"| {e:g} | {run.path[k].sum():.2f} | {run.reassignments[k]} | "
            f"{'not within the hold' if ex is None else f'{ex:.1f}'} |"
        )
    out += [
        "",
        "Auction wall time is measured around each `sim.central.engine.auction_assignment` call of the central "
        "engine (one block of the agents' auction, agent.core.bidder, with one participant holding every robot; "
        "patched in by the script, sim/central/engine.py unchanged); rounds are Jacobi rounds in which some robot bid; "
        "a cold start is the first call after an image change (a fresh participant, no prices yet: epsilon "
        "scaling from the goal set's extent² / 10 down to epsilon_A, by factors of 10). "
        "Execution time is `steps[k].converged_at` of metrics.json: the first sample at which every robot "
        "is within 1 cm of its goal. Path lengths are of the true (not tracked) positions. Cost ratio: eq. 7 "
        "of the auction's assignment over scipy's `linear_sum_assignment` on the same tracked positions.",
    ]
    return out


def write_figure_results(path: Path, command: str, lines: list[str]) -> None:
    text = [
        "## Paper Figs. 13-15: path length, epsilon_A and trajectories (central engine)",
        "",
        f"Command: `{command}`",
        f"Machine: {machine()}; measured {time.strftime('%Y-%m-%d', time.gmtime())}.",
        "",
        *lines,
        "",
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(text))


# --- main ----------------------------------------------------------------------------------------
def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = parser_for("bench.paper_figures [figures]", FIGURES_DOC)
    p.add_argument("--runs", type=int, default=None, help="runs per epsilon_A, seeds 1..R (default 25, quick 2)")
    p.add_argument("--out", type=Path, default=REPO / "docs", help="where the PNGs go")
    p.add_argument(
        "--results",
        type=Path,
        default=None,
        help="the markdown results (default bench/results/paper_figures.md; quick: <out>/paper_figures.md)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"{len(QUICK_EPSILONS)} epsilons, the first {QUICK_STEPS} steps held {QUICK_HOLD:g} s",
    )
    args = p.parse_args(argv)
    args.runs = args.runs or (2 if args.quick else 25)
    if args.results is None:  # a quick run never overwrites the stored results
        args.results = args.out / "paper_figures.md" if args.quick else RESULTS / "paper_figures.md"
    return args


def main(argv: list[str] | None = None) -> Summary:
    args = parse_args(argv)
    command = " ".join(
        [".venv/bin/python -m bench.paper_figures", shlex.join(sys.argv[1:] if argv is None else argv)]
    ).strip()
    data = scene_data(args.quick)
    epsilons = QUICK_EPSILONS if args.quick else EPSILONS
    keep = {max(epsilons), min(epsilons)}  # Fig. 15's poor and good epsilon_A
    holds = [float(s["hold"]) for s in data["steps"]]
    w0 = time.perf_counter()
    total = len(epsilons) * args.runs
    runs: dict[float, list[Run]] = {e: [] for e in epsilons}
    # Seed-major: a load spike on the shared machine then slows every epsilon_A alike.
    for seed in range(1, args.runs + 1):
        for e in epsilons:
            run = run_once(data, e, seed, keep_xy=e in keep)
            runs[e].append(run)
            ex, cens = execution_times(run, holds)
            done = sum(len(v) for v in runs.values())
            print(
                f"[{done:3d}/{total}] epsilon_A {e:g} m² seed {seed:2d}: {run.wall_s:5.1f} s wall, "
                f"path {run.path.sum():6.2f} m, execution {ex.sum():6.1f} s"
                f"{f' ({int(cens.sum())} not converged)' if cens.any() else ''}, "
                f"auction {1e3 * np.mean(run.calls.wall_s):.2f} ms/call, contacts {run.contacts}",
                flush=True,
            )
    if FIG13_EPS not in runs:
        raise SystemExit(f"Fig. 13 needs epsilon_A = {FIG13_EPS:g}")
    summary = Summary(transition_labels(data), holds, runs, pick_fig15(runs), time.perf_counter() - w0)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, plot in (
        ("fig13_path_length.png", plot_fig13),
        ("fig14_epsilon.png", plot_fig14),
        ("fig15_trajectories.png", plot_fig15),
    ):
        plot(summary, args.out / name)
        print(f"wrote {args.out / name}", flush=True)
    hysteresis = RobotParams.from_dict(data.get("robot", {})).assign_hysteresis
    write_figure_results(args.results, command, results_lines(summary, hysteresis))
    print(f"wrote {args.results} ({summary.wall_s / 60:.1f} min)", flush=True)
    return summary


# --- Fig. 4 (fig4) ----------------------------------------------------------------------------
FIG4_DOC = """Reproduce the paper's Fig. 4: normalised cost of eq. 1 per Lloyd iteration for 14 goals on six
images (disk; disk and line with 10+4 and 6+8 robots; line; L; T), 25 seeded runs each.

The cost of each run is divided by the highest initial cost among the 25 runs of its image (as in the
paper). Top: the inputs; middle: the lowest-cost goal set of each image; bottom: the cost curves of
plain Lloyd (as in the paper, relax=1) and of pixelswarm's default (over-relaxed Lloyd, never rising).

    .venv/bin/python -m bench.paper_figures fig4          # writes docs/fig4_cvt_cost.png and prints a summary
"""


FIG4_OUT = Path(__file__).resolve().parent.parent / "docs" / "fig4_cvt_cost.png"
FIG4_CASES = [
    ("disk", None, "disk"),
    ("disk_and_line", {0: 10, 1: 4}, "disk and line 10+4"),
    ("disk_and_line", {0: 6, 1: 8}, "disk and line 6+8"),
    ("line", None, "line"),
    ("L", None, "L"),
    ("T", None, "T"),
]
FIG4_COLOURS = ["tab:red", "tab:orange", "tab:purple", "tab:blue", "tab:green", "tab:brown"]


def fig4_runs(size: int, n: int, seeds: int, relax: float) -> list[dict]:
    """Per case: image, prepared image, normalised cost histories and the best goal set."""
    out = []
    for name, counts, title in FIG4_CASES:
        img = shapes.draw(name, size)
        prep = prepare_image(img)
        sets = [
            goals_from_prepared(prep, n, GoalOptions(seed=s, region_counts=counts, relax=relax)) for s in range(seeds)
        ]
        top = max(gs.cost_history[0] for gs in sets)
        hists = [np.asarray(gs.cost_history) / top for gs in sets]
        best = min(sets, key=lambda gs: gs.cost_history[-1])
        out.append({"title": title, "img": img, "prep": prep, "hists": hists, "best": best})
    return out


def fig4_summary(label: str, cases: list[dict]) -> list[str]:
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


def plot_fig4(plain: list[dict], default: list[dict], path: Path, relax: float) -> None:
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
        for c, col in zip(cases, FIG4_COLOURS):
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


def fig4_main(argv: list[str] | None = None) -> int:
    ap = parser_for("bench.paper_figures fig4", FIG4_DOC)
    ap.add_argument("--size", type=int, default=256, help="image side in pixels")
    ap.add_argument("--n", type=int, default=14)
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--out", type=Path, default=FIG4_OUT)
    args = ap.parse_args(argv)
    plain = fig4_runs(args.size, args.n, args.seeds, 1.0)
    default = fig4_runs(args.size, args.n, args.seeds, RELAX)
    print("\n".join(fig4_summary("plain", plain) + fig4_summary("default", default)))
    plot_fig4(plain, default, args.out, RELAX)
    print(f"wrote {args.out}")
    return 0


# --- keyframe goals from the previous frame (keyframes) ---------------------------------------
KEYFRAMES_DOC = """Benchmark of animation goal generation (paper 6.1): initialising each keyframe's CVT from the
previous frame's goals, moved by the regions' T_i^f and M_i^f, against fresh random samples.

Cases: the leaf (11 keyframes) with N = 100 (256 px) and N = 1000 (512 px, so that a robot still has
tens of pixels), and the 14-robot story (256 px). For each, side by side in one run:

- disparity: goal_disparity between consecutive goal sets (mean distance of the squared-distance
  optimal assignment, eq. 7), in pixels of the keyframes (the runs' arenas may differ slightly);
- time: wall clock of keyframe_goals (all frames: segmentation, motion estimates, Lloyd), median of
  --repeat runs; Lloyd iterations summed over the frames; the final cost of eq. 1 summed over frames.

Both robot-count rules are measured: N_i proportional to the area in every frame (paper 4.2, the
default) and keep_counts (each region keeps the N_i of its region in the previous frame).

    .venv/bin/python -m bench.paper_figures keyframes     # prints the tables, writes bench/results/keyframes.md
"""


KEYFRAME_CASES = (("leaf", 100, 256), ("leaf", 1000, 512), ("story", 14, 256))


def keyframe_run(
    frames: list[np.ndarray], n: int, init: bool, keep: bool, seed: int, repeat: int
) -> tuple[float, KeyframeGoals]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = keyframe_goals(frames, n, GoalOptions(seed=seed), init_from_previous=init, keep_counts=keep)
        times.append(time.perf_counter() - t)
    assert out is not None
    return statistics.median(times), out


def keyframe_summary(kg: KeyframeGoals) -> dict:
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
            t, kg = keyframe_run(frames, n, init, keep, seed, repeat)
            s = keyframe_summary(kg)
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


def keyframes_main(argv: list[str] | None = None) -> int:
    ap = parser_for("bench.paper_figures keyframes", KEYFRAMES_DOC)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"Seed {args.seed}, median wall time of {args.repeat} runs; load average {load:.2f} at start; "
        f"numpy {np.__version__}, scipy {scipy.__version__}.",
        "",
    ]
    for name, n, size in KEYFRAME_CASES:
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
    cmd = f".venv/bin/python -m bench.paper_figures keyframes --repeat {args.repeat} --seed {args.seed}"
    write_results("keyframes", "Keyframe animation goals: initialised from the previous frame vs fresh", cmd, lines)
    return 0


# --- the carried assignment between keyframes (carry) -----------------------------------------
CARRY_DOC = """Consecutive keyframes: bids to agree on frame f's goal set when the auction starts cold, from the
previous frame's assignment carried over by the goals' correspondence (agent.core.bidder.Participant.carry,
prices zero), from that assignment with the previous prices carried too, or from the goal sets'
own matching and its prices (coordinator.warm_start.goal_matching, sent with the goal set: what the agents do after an agreed
frame).

Robots stand on frame f-1's goals (2 mm noise); frame f is frame f-1 turned and moved, its goals
listed in another order. Hosts exchange their records in lossless rounds (no zenoh: this measures
the protocol, not the transport). `frames_close` is the agents' rule for starting the auction from
the carried claims when the matching cannot be used (the robots changed).

    .venv/bin/python -m bench.paper_figures carry [--robots 100] [--hosts 10]
"""


CARRY_EPS, CARRY_HYSTERESIS = 1e-3, 5e-3  # the defaults of agent.core.params
CARRY_EXPLAIN = (
    "Robots stand on frame f-1's goals; frame f is that frame moved and turned, its goals listed in another "
    "order. Bids and message rounds until every host adopts an agreed final-phase instance of frame f's "
    "auction, starting cold, from the goal sets' matching with its prices (what the agents do), from the carried assignment (each robot claims the goal its last one "
    "corresponds to, prices zero; what the agents do when `frames_close`), or from that assignment with "
    "the previous prices carried too. In every case the robots drive to their carried goals at once; this "
    "measures only how soon the auction confirms or corrects them. Wall times are of this in-process "
    "exchange (no zenoh) and grow with other work on the machine; bids and rounds do not."
)
CARRY_MATCHING = (
    "What the agents do (`agent.assignment.AuctionLink._warm_start`): after an agreed frame the "
    "coordinator sends with frame f's goal set the matching of frame f-1's goals to frame f's, with prices "
    "in equilibrium for it (`coordinator.warm_start.goal_matching`: the robots' auction settled once as if a "
    "robot stood on each old goal; its wall time is included here), each "
    "robot claims the goal its last one is matched to, and the auction starts from those claims and prices. "
    "The prices are nearly in equilibrium for the real positions, whatever the frames' disparity. "
    "`frames_close` now only decides for a frame whose robots changed (a robot died)."
)
CARRY_RULE = (
    "The rule (`agent.assignment.frames_close`): start from the carried claims when corresponding goals are on "
    "average at most 1.5 goal spacings apart (the third column). Beyond that the claims skip the coarse "
    "epsilon phases that build the prices, and the fine phases fight a price war that costs more than a "
    "cold start."
)


def agree(parts: list[Participant], positions: np.ndarray, max_rounds: int = 100_000) -> int:
    """Message rounds until every host has adopted a final-phase instance; returns the rounds."""
    for p in parts:
        if not p.started:
            p.begin(0, {r: positions[r] for r in p.own})
    for rounds in range(1, max_rounds):
        for p in parts:
            p.bid_until_quiet()
            before = p.instance
            p.check_agreement()
            if p.instance != before:
                p.bid_until_quiet()
        if all(p.is_agreed and p.final_phase for p in parts):
            return rounds
        sent = [(p.instance, p.outgoing()) for p in parts]
        for i, (instance, (digest, recs)) in enumerate(sent):
            for j, q in enumerate(parts):
                if j != i:
                    if instance > q.instance:
                        q.begin(instance, {r: positions[r] for r in q.own})
                    q.absorb(instance, rounds, digest, recs)
    raise RuntimeError("no agreement")


def start_from_matching(parts: list[Participant], first: list[Participant], g1: np.ndarray, g2: np.ndarray) -> None:
    """What the agents do after an agreed frame (agent.assignment.AuctionLink._warm_start): claims and
    prices from the goal sets' matching."""
    matched, prices = goal_matching(g1, g2, CARRY_EPS)
    for new, old in zip(parts, first):
        new.carry(old, matched, prices=prices)


def paper_transition(n: int = 1000, k: int = 4, steps: tuple[int, int] = (0, 1)) -> list[str]:
    """The paper's sequence at 1000 robots (scene paper-sequence-1000), its first transition (disk to
    disk and line): robots 2 mm off the disk's goals, in 4 hosts of 250, the auction cold and from
    the goal sets' matching."""
    from coordinator.scene import load_scene

    goals = load_scene("paper-sequence-1000").image_goals
    g1, g2 = (np.asarray(goals.goal_set(s, n)[0]) for s in steps)
    pos = g1 + np.random.default_rng(0).normal(0.0, 0.002, g1.shape)
    robots = list(range(n))
    hosts = [robots[h * n // k : (h + 1) * n // k] for h in range(k)]
    first = [Participant(1, g1, robots, h, CARRY_EPS, CARRY_HYSTERESIS) for h in hosts]
    agree(first, pos)
    out = [
        f"The paper's sequence with {n} robots in {k} hosts (scene `paper-sequence-1000`), image {steps[0]} to "
        f"image {steps[1]}, robots 2 mm off image {steps[0]}'s goals:",
        "",
        "| start | bids | message rounds | wall s |",
        "|---|---|---|---|",
    ]
    for start in ("cold", "goal matching, its prices"):
        parts = [Participant(2, g2, robots, h, CARRY_EPS, CARRY_HYSTERESIS) for h in hosts]
        t0 = time.perf_counter()
        if start != "cold":
            start_from_matching(parts, first, g1, g2)
        rounds = agree(parts, pos)
        out.append(f"| {start} | {sum(p.bids for p in parts)} | {rounds} | {time.perf_counter() - t0:.2f} |")
        print(out[-1], flush=True)
    return out


def carry_main(argv: list[str] | None = None) -> int:
    ap = parser_for("bench.paper_figures carry", CARRY_DOC)
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--hosts", type=int, default=10)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--no-paper", action="store_true", help="skip the 1000-robot paper transition (about 2 min)")
    a = ap.parse_args(argv)
    n, k = a.robots, a.hosts
    robots = list(range(n))
    hosts = [robots[h::k] for h in range(k)]
    lines = [
        CARRY_EXPLAIN,
        "",
        f"{n} robots in {k} hosts, epsilon_A {CARRY_EPS}, Delta C {CARRY_HYSTERESIS}, seed {a.seed}.",
        "",
        "| frame f moved by | turned by | disparity / spacing | frames_close | start | bids | message rounds | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for shift, turn in ((0.03, 0.02), (0.1, 0.09), (0.3, 0.2), (1.0, 0.5)):
        rng = np.random.default_rng(a.seed)
        g1 = rng.uniform(-1.5, 1.5, (n, 2))
        c, s = np.cos(turn), np.sin(turn)
        g2 = (g1 @ np.array([[c, -s], [s, c]]).T + [shift, 0.0])[rng.permutation(n)]
        pos = g1 + rng.normal(0.0, 0.002, g1.shape)
        first = [Participant(1, g1, robots, h, CARRY_EPS, CARRY_HYSTERESIS) for h in hosts]
        agree(first, pos)
        previous = goal_correspondence(g1, g2)
        close = "yes" if frames_close(g1, g2, previous) else "no"
        disparity = np.hypot(*(g2 - g1[previous]).T).mean()
        ratio = disparity / np.median(cKDTree(g2).query(g2, k=2)[0][:, 1])  # as frames_close measures it
        for start in ("cold", "carried, prices zero", "carried, prices carried", "goal matching, its prices"):
            parts = [Participant(2, g2, robots, h, CARRY_EPS, CARRY_HYSTERESIS) for h in hosts]
            t0 = time.perf_counter()
            if start.startswith("goal matching"):
                start_from_matching(parts, first, g1, g2)
            elif start != "cold":
                for new, old in zip(parts, first):
                    new.carry(old, previous)
                    if start.endswith("carried"):
                        j = np.flatnonzero(previous >= 0)
                        new.board.price[j] = old.board.price[previous[j]]
                        new.board.version += 1
            rounds = agree(parts, pos)
            lines.append(
                f"| {shift} m | {np.degrees(turn):.1f} deg | {ratio:.2f} | {close} | {start} | "
                f"{sum(p.bids for p in parts)} | {rounds} | {time.perf_counter() - t0:.2f} |"
            )
            print(lines[-1], flush=True)
    lines += ["", CARRY_MATCHING, "", CARRY_RULE, ""]
    if not a.no_paper:
        lines += paper_transition()
    write_results(
        "carry",
        "Consecutive keyframes: the carried assignment (issue 6)",
        ".venv/bin/python -m bench.paper_figures carry",
        lines,
    )
    return 0


COMMANDS = {"figures": main, "fig4": fig4_main, "keyframes": keyframes_main, "carry": carry_main}


if __name__ == "__main__":
    sys.exit(run_subcommand("bench.paper_figures", COMMANDS, "figures"))
