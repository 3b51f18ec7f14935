"""Large-scale display (paper 7.2 / 7.5, Fig. 12 bottom row): the six images of the paper's sequence
with 1000 simulated holonomic robots, stepped by the central engine, with its two goal assignments
side by side in one run:

- `auction` (the engine's default): the agents' auction (agent.core.bidder), one participant holding
  every robot; each `assign_period` the next block of epsilon-scaling phases is settled in-process on
  the measured positions, warm from the last prices (sim.central.engine.auction_assignment);
- `optimal`: scipy's linear_sum_assignment each `assign_period`, kept unless better by Delta C.

    .venv/bin/python -m bench.bench_large                    # the whole sequence, both (about 20 min)
    .venv/bin/python -m bench.bench_large --images 2         # only the first two images (a shorter run)
    .venv/bin/python -m bench.bench_large --robots 200 --assignment auction --results large-trial
    .venv/bin/python -m bench.bench_large --before cf836e5 --pairs 2   # the CLI's run beside revision REV's
    .venv/bin/python -m bench.bench_large --before cf836e5 --before-path DIR   # DIR: `pip install --target DIR numba`
    .venv/bin/python -m bench.bench_large --scale 1000,3000,10000 --seconds 10   # cost per robot-step by size
    .venv/bin/python -m bench.bench_large --scale 1000,3000,10000,30000 --seconds 10 --rounds-per-tick 1

It runs what `pixelswarm run paper-sequence-1000 --no-video` runs (`sim.central.engine.run_central`) in this
process, with a `sim.central.stepclock.StepClock` that times each part of every control step on the engine's
thread: the tracker, the wait for the goal assignment, the preferred velocities, recording, the
neighbour search, the control core (`control_step`, ORCA for every robot), the world (commands and
`World.step`: 10 substeps with contact detection) and the rest; and, apart, the warm auction's own
time on the second thread, where it runs beside the neighbour search, control core and world step. Wall time and this process's CPU time are both kept: on a shared
machine the wall time counts whatever else ran meanwhile, the CPU time does not.

Reported into bench/results/large.md: per assignment the realtime factor (display seconds per wall
second, and per CPU second), the time per control step split by part, the cold starts (a fresh
auction at every new image), contacts and clearance; per image when every robot was within 1 cm of
its goal (`converged_at`, seconds after the image change) and the mean time per control step; and
what bounds the realtime factor, from the measured parts.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from agent.core.params import RobotParams
from coordinator.scene import load_scene, parse_scene
from sim.central.engine import run_central
from sim.central.stepclock import PARTS, StepClock

from .common import write_results

SCENE = "paper-sequence-1000"
ASSIGNMENTS = ("auction", "optimal")
WAR_BIDS = 3000  # a warm block of more bids than this is counted as a price war
TARGET, GOAL_ROBOTS = 30.0, 1000  # the realtime factor issue 6 asks of the central engine, at 1000 robots
PART_NAMES = {
    "tracker": "tracker",
    "assignment": "goal assignment (waiting for the auction; cold starts)",
    "preferred": "preferred velocities",
    "record": "recording",
    "neighbours": "neighbour search (grid)",
    "control": "control core (ORCA, compiled)",
    "world": "world (commands + step)",
    "other": "the rest",
}


@dataclass
class Run:
    """One run of the scene with one assignment: its metrics, step per tick and the clock."""

    assignment: str
    metrics: dict
    step: np.ndarray  # (ticks,) the image shown at each tick
    wall: dict[str, np.ndarray]  # part -> (ticks,) seconds
    cpu: dict[str, np.ndarray]  # this process's CPU time (every thread)
    beside: np.ndarray  # (ticks,) wall seconds of the warm auction on the second thread (0: none)
    bids: np.ndarray  # (ticks,) that auction's bids
    reassigned: np.ndarray  # (ticks,) the robots whose goal it changed

    @property
    def display(self) -> float:
        return float(self.metrics["duration_s"])

    @property
    def cold(self) -> np.ndarray:
        """(ticks,) bool: the ticks that start an image (a fresh auction: its cold start)."""
        return np.r_[True, self.step[1:] != self.step[:-1]]

    def per_tick(self, cpu: bool = False) -> np.ndarray:
        times = self.cpu if cpu else self.wall
        return sum(times[p] for p in PARTS)


class Progress:
    """Stands in for stderr: echoes the engine's once-a-second progress line with the wall clock."""

    def __init__(self, echo: bool, label: str) -> None:
        self.echo, self.label = echo, label

    def write(self, text: str) -> int:
        if self.echo and text.strip():
            print(f"{time.strftime('%H:%M:%S')} [{self.label}] {text.strip()}", file=sys.stderr, flush=True)
        return len(text)

    def flush(self) -> None:
        pass


def scene_for(name: str, robots: int | None, images: int | None) -> tuple[Any, int]:
    """The scene, cut after its first `images` images (their holds); returns it and how many it shows."""
    scene = load_scene(name, robots=robots)
    total = len(scene.steps)
    if images is None or images >= total:
        return scene, total
    k = max(images, 1)
    end = scene.step_starts[k - 1] + scene.steps[k - 1].hold - RobotParams.from_dict(scene.robot).dt  # the last tick
    return load_scene(name, robots=robots, duration=end), k  # shows image k


def timed_run(scene: Any, assignment: str, echo: bool) -> Run:
    scene.assignment = assignment
    clock = StepClock(cpu=True)
    with tempfile.TemporaryDirectory(prefix="bench_large_") as tmp:
        path = run_central(scene, Path(tmp) / "run", video=False, progress=Progress(echo, assignment), clock=clock)
        metrics = json.loads((path / "metrics.json").read_text())
        with np.load(path / "trajectory.npz") as z:
            step = np.array(z["step"])
    beside = np.array(clock.beside), np.array(clock.bids), np.array(clock.reassigned)
    return Run(assignment, metrics, step, clock.arrays(), clock.arrays(cpu=True), *beside)


def ms(x: float) -> str:
    return f"{x * 1e3:.1f}"


def fmt(value: float | None, digits: int = 1) -> str:
    return "not within the hold" if value is None else f"{value:.{digits}f}"


def describe(scene: Any, shown: int) -> list[str]:
    r = scene.robot
    cut = (
        f"**Only the first {shown} of the {len(scene.steps)} images** (`--images {shown}`): the run ends "
        f"at {scene.duration:.0f} s of display."
        if shown < len(scene.steps)
        else f"All {shown} images; the run ends once the last is held (converge_hold {scene.converge_hold:g} s) "
        "or at the end of its hold."
    )
    return [
        f"Scene `{scene.name}`: {scene.robots} {r.get('kinematics', 'diffdrive')} robots (radius {scene.radius} m, "
        f"v_max {r.get('v_max')} m/s, v_pref {r.get('v_pref')} m/s, neighbour_dist {r.get('neighbour_dist')} m, "
        f"max_neighbours {r.get('max_neighbours')}), seed {scene.seed}, arena K_r {scene.image_goals.arena:.2f} m, "
        f"tracking noise {scene.noise.tracking_xy * 1000:.0f} mm / {scene.noise.tracking_theta_deg:.0f} deg, "
        f"actuation noise {scene.noise.actuation * 100:.0f} %, control period {RobotParams.from_dict(r).dt:g} s. "
        f"Each column is `pixelswarm run {scene.name} --engine central --no-video` with the scene's "
        f"`assignment` set as named. {cut}"
    ]


def summary_table(runs: list[Run]) -> list[str]:
    head = "| | " + " | ".join(f"`{r.assignment}`" for r in runs) + " |"
    lines = [head, "|---|" + "---|" * len(runs)]

    def row(name: str, cells: list[str]) -> None:
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    row("display time s (end)", [f"{r.display:.1f} ({r.metrics.get('end_reason')})" for r in runs])
    row("control steps", [str(len(r.step)) for r in runs])
    row("wall time s", [f"{r.metrics['wall_s']:.0f}" for r in runs])
    row("**realtime factor** (display s per wall s)", [f"**{r.display / r.metrics['wall_s']:.2f}**" for r in runs])
    row("realtime factor per CPU s of the control loop", [f"{r.display / r.per_tick(True).sum():.2f}" for r in runs])
    for label, cpu in (("wall", False), ("CPU", True)):
        row(
            f"ms per control step, {label} (median / mean / p90)",
            [
                f"{ms(np.median(t))} / {ms(t.mean())} / {ms(np.percentile(t, 90))}"
                for t in (r.per_tick(cpu) for r in runs)
            ],
        )
    row(
        "cold starts (new image): count, s each (mean, wall / CPU)",
        [
            f"{int(r.cold.sum())}, {r.wall['assignment'][r.cold].mean():.2f} / {r.cpu['assignment'][r.cold].mean():.2f}"
            for r in runs
        ],
    )
    row(
        "assignment ms per warm step, waited for (mean / p90 / max)",
        [
            f"{ms(a.mean())} / {ms(np.percentile(a, 90))} / {ms(a.max())}"
            for a in (r.wall["assignment"][~r.cold] for r in runs)
        ],
    )
    row(
        "auction ms per warm step, its own time on the second thread (mean / p90 / max)",
        [
            f"{ms(a.mean())} / {ms(np.percentile(a, 90))} / {ms(a.max())}" if a.any() else "-"
            for a in (r.beside[~r.cold] for r in runs)
        ],
    )
    row(
        "auction bids per warm step (median / p90 / max); ns of its time per bid",
        [
            f"{np.median(b):.0f} / {np.percentile(b, 90):.0f} / {b.max()}; {1e9 * r.beside.sum() / b.sum():.0f}"
            if b.any()
            else "-"
            for r, b in ((r, r.bids[~r.cold]) for r in runs)
        ],
    )
    row(
        f"warm steps of over {WAR_BIDS} bids: share; bids and robots given another goal, per step (mean); "
        "share of them that gave none another",
        [
            f"{100 * w.mean():.0f} %; {r.bids[w].mean():.0f} and {r.reassigned[w].mean():.1f}; "
            f"{100 * (r.reassigned[w] == 0).mean():.0f} %"
            if w.any()
            else "-"
            for r, w in ((r, (r.bids > WAR_BIDS) & ~r.cold) for r in runs)
        ],
    )
    row(
        "contacts; min clearance m (at 100 Hz)",
        [
            f"{r.metrics['contacts']}; {r.metrics['min_clearance_m']:.4f} ({fmt(r.metrics.get('min_clearance_substep_m'), 4)})"
            for r in runs
        ],
    )
    row("ORCA fallbacks", [str(r.metrics.get("orca_fallbacks")) for r in runs])
    return lines


def split_table(runs: list[Run]) -> list[str]:
    """Mean ms per control step by part, wall and CPU, every tick counted (cold starts included)."""
    lines = [
        "| part | " + " | ".join(f"`{r.assignment}` wall ms | `{r.assignment}` CPU ms" for r in runs) + " |",
        "|---|" + "---|---|" * len(runs),
    ]
    for p in PARTS:
        lines.append(
            f"| {PART_NAMES[p]} | " + " | ".join(f"{ms(r.wall[p].mean())} | {ms(r.cpu[p].mean())}" for r in runs) + " |"
        )
    lines.append(
        "| **total** | "
        + " | ".join(f"**{ms(r.per_tick().mean())}** | **{ms(r.per_tick(True).mean())}**" for r in runs)
        + " |"
    )
    return lines


def image_table(scene: Any, runs: list[Run]) -> list[str]:
    beside = {"auction": " (auction beside)"}  # scipy's optimum runs on the engine's thread
    lines = [
        "| step | image | hold s | "
        + " | ".join(
            f"`{r.assignment}` converged_at s | `{r.assignment}` max error "
            f"at end m | `{r.assignment}` ms per warm step, wall / CPU"
            f"{beside.get(r.assignment, '')}"
            for r in runs
        )
        + " |",
        "|---|---|---|" + "---|---|---|" * len(runs),
    ]
    by_run = [{s["index"]: s for s in r.metrics["steps"]} for r in runs]
    for k in sorted(by_run[0]):
        cells = []
        for r, steps in zip(runs, by_run):
            s = steps.get(k)
            mine = (r.step == k) & ~r.cold
            aside = f" ({ms(r.beside[mine].mean())})" if r.assignment in beside else ""
            spent = (
                f"{ms(r.per_tick()[mine].mean())} / {ms(r.per_tick(True)[mine].mean())}{aside}" if mine.any() else "-"
            )
            cells.append(f"{fmt(s and s['converged_at'])} | {fmt(s and s['max_goal_error_at_end'], 4)} | {spent}")
        lines.append(f"| {k} | {scene.steps[k].name} | {scene.steps[k].hold:.0f} | " + " | ".join(cells) + " |")
    return lines


def bounds(runs: list[Run], dt: float, robots: int) -> list[str]:
    """What bounds the realtime factor, from the measured parts. A warm auction runs on a second
    thread while the engine's thread searches neighbours, steps the control core and the world on
    the goals the robots hold (sim.central.engine): a step takes about the longer of the two, plus the
    parts before the auction starts and after its result is in."""
    lines = [
        f"Realtime factor {TARGET:g} at a {dt:g} s control period leaves {dt / TARGET * 1e3:.1f} ms per "
        "control step. Measured (wall ms per step, mean):"
    ]
    for r in runs:
        total = r.per_tick().mean()
        own = total - r.wall["assignment"].mean()
        auction = r.beside[~r.cold]
        lines.append(
            f"- `{r.assignment}`: {ms(total)} ms per step ({r.display / r.metrics['wall_s']:.2f}x). The engine's "
            f"thread works {ms(own)} ms of it ({dt / own:.1f}x if it never waited)"
            + (
                f"; the auction beside it {ms(auction.mean())} ms (p90 {ms(np.percentile(auction, 90))}), "
                f"longer than that in {100 * np.mean(auction > own):.0f} % of the steps."
                if auction.any()
                else "; its assignment runs on this thread."
            )
        )
    met = [r.assignment for r in runs if r.display / r.metrics["wall_s"] >= TARGET]
    if met:
        verdict = f"met by {', '.join(met)}."
    elif min(r.wall["control"].mean() for r in runs) > dt / TARGET:
        verdict = "**not met**: the control core alone takes longer than the budget per step."
    else:
        verdict = "**not met**."
    if robots == GOAL_ROBOTS:
        lines.append(f"- Goal of {TARGET:g}x at {GOAL_ROBOTS} robots: {verdict}")
    else:
        lines.append(f"- The goal of {TARGET:g}x is for {GOAL_ROBOTS} robots; this trial has {robots}.")
    return lines


def side_by_side(before: str, pairs: int, scene: str, before_path: str | None = None, seed: int = 3) -> list[str]:
    """`pixelswarm run SCENE --engine central` from a git worktree of ``before`` and from this
    checkout, alternating: each run's realtime factor, wall time and contacts (metrics.json).
    ``before_path``: a folder put first on the before runs' PYTHONPATH, for a package the code
    before needs and this checkout does not (cf836e5's numba: `pip install --target DIR numba`)."""
    import subprocess

    from .bench_runtime import worktree_at
    from .common import REPO

    rows = ["| pair | code | realtime factor | wall s | contacts | load avg |", "|---|---|---|---|---|---|"]
    factors: dict[str, list[float]] = {"before": [], "after": []}
    with worktree_at(before) as (old, commit), tempfile.TemporaryDirectory() as tmp:
        for pair in range(1, pairs + 1):
            for what, tree in (("before", old), ("after", REPO)):
                out = Path(tmp) / f"{what}{pair}"
                cmd = [sys.executable, "-m", "sim.cli", "run", scene, "--engine", "central", "--seed", str(seed)]
                env = dict(os.environ)
                if what == "before" and before_path:
                    env["PYTHONPATH"] = os.pathsep.join(filter(None, [before_path, env.get("PYTHONPATH")]))
                run = [*cmd, "--no-video", "-q", "--out", str(out)]
                subprocess.run(run, cwd=tree, env=env, check=True, capture_output=True)
                m = json.loads((out / "metrics.json").read_text())
                factors[what].append(m["realtime_factor"])
                label = f"{commit} (before)" if what == "before" else "current"
                rows.append(
                    f"| {pair} | {label} | {m['realtime_factor']:.1f}x | {m['wall_s']:.1f} | {m['contacts']} | "
                    f"{os.getloadavg()[0]:.1f} |"
                )
                print(rows[-1], flush=True)
    first = f"the first run in a fresh tree: {factors['before'][0]:.1f}x before, {factors['after'][0]:.1f}x now"
    if pairs < 2:
        return [*rows, "", f"Realtime factor, {first}."]
    b, a = float(np.median(factors["before"][1:])), float(np.median(factors["after"][1:]))
    return rows + [
        "",
        f"Realtime factor, {first} (a JIT compiles then); median of the later runs: {b:.1f}x before "
        f"({commit}), {a:.1f}x now ({a / b:.2f}x). Scene: `pixelswarm run {scene} --engine central --seed {seed} "
        "--no-video`, start-up included.",
    ]


def scale_one(scene_name: str, robots: int, seconds: float, rounds: int | None) -> dict:
    """One size of the scaling table: the scene's first image for ``seconds`` of display with
    ``robots`` robots, the auction assigning (at most ``rounds`` a tick when given, as
    ``--rounds-per-tick``); per warm step the wall time per robot by part."""
    t0 = time.perf_counter()
    scene = load_scene(scene_name, robots=robots, duration=seconds)
    if rounds is not None:
        scene = replace(scene, robot={**scene.robot, "rounds_per_tick": rounds})
    made = time.perf_counter() - t0
    run = timed_run(scene, "auction", echo=False)
    warm = ~run.cold
    return {
        "robots": robots,
        "scene_s": made,
        "cold_s": float(run.wall["assignment"][run.cold].sum()),
        "us_per_robot_step": {p: float(run.wall[p][warm].mean()) / robots * 1e6 for p in PARTS},
        "warm_ms_per_step": float(run.per_tick()[warm].mean()) * 1e3,
        "realtime": run.display / run.metrics["wall_s"],
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "contacts": run.metrics["contacts"],
    }


def scale_table(scene_name: str, sizes: list[int], seconds: float, rounds: int | None) -> list[str]:
    """The scaling benchmark (issue 43): each size in a process of its own (its own peak RSS)."""
    import subprocess

    rows = [
        "| robots | scene s | cold start s | warm ms per step | realtime factor (warm) | "
        + " | ".join(f"{p} us" for p in PARTS)
        + " | us per robot-step | x the first | peak RSS MB | contacts |",
        "|---|---|---|---|---|" + "---|" * len(PARTS) + "---|---|---|---|",
    ]
    first = None
    dt = RobotParams.from_dict(parse_scene(scene_name).robot).dt  # no goal sets needed for the period
    for n in sizes:
        cmd = [sys.executable, "-m", "bench.bench_large", "--scene", scene_name, "--scale-one", str(n)]
        cmd += ["--seconds", str(seconds)] + ([] if rounds is None else ["--rounds-per-tick", str(rounds)])
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        r = json.loads(done.stdout.strip().splitlines()[-1])
        per = sum(r["us_per_robot_step"].values())
        first = per if first is None else first
        rows.append(
            f"| {n} | {r['scene_s']:.1f} | {r['cold_s']:.1f} | {r['warm_ms_per_step']:.1f} | "
            f"{dt * 1e3 / r['warm_ms_per_step']:.1f}x | "
            + " | ".join(f"{r['us_per_robot_step'][p]:.2f}" for p in PARTS)
            + f" | {per:.2f} | {per / first:.2f} | {r['rss_mb']:.0f} | {r['contacts']} |"
        )
        print(rows[-1], flush=True)
    bounded = "" if rounds is None else f" (at most {rounds} of its rounds a tick, `--rounds-per-tick {rounds}`)"
    return rows + [
        "",
        f"The first image of `{scene_name}` for {seconds:g} s of display at each size (`--robots N`), the "
        f"auction assigning{bounded}; wall time per robot and warm control step (a cold start at the first tick is "
        "apart), each size in a process of its own. The parts are those of the tables above (`assignment`: "
        "the auction's bounded rounds, or the wait for a block agreed within its tick on the second thread).",
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default=SCENE)
    parser.add_argument("--robots", type=int, help="override the scene's robot count (a trial)")
    parser.add_argument("--images", type=int, help="run only the first K images (default: all)")
    parser.add_argument(
        "--assignment", choices=ASSIGNMENTS, action="append", help="only this assignment (repeatable; default: both)"
    )
    parser.add_argument("--results", default="large", help="bench/results/<name>.md (default large)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--before", help="git revision: its CLI run beside this checkout's, alternating")
    parser.add_argument("--pairs", type=int, default=2, help="--before: runs of each, alternating")
    parser.add_argument("--before-path", help="--before: a folder first on its PYTHONPATH (e.g. numba for cf836e5)")
    parser.add_argument("--scale", help="robot counts, e.g. 1000,3000,10000: the cost per robot-step at each size")
    parser.add_argument("--seconds", type=float, default=10.0, help="--scale: seconds of display at each size")
    parser.add_argument(
        "--rounds-per-tick", type=int, help="--scale: the auction's rounds a tick at most (default: the scene's)"
    )
    parser.add_argument("--scale-one", type=int, help=argparse.SUPPRESS)  # one size of --scale, as JSON
    args = parser.parse_args()
    if args.scale_one:
        print(json.dumps(scale_one(args.scene, args.scale_one, args.seconds, args.rounds_per_tick)))
        return 0
    if args.scale:
        sizes = [int(n) for n in args.scale.split(",")]
        lines = scale_table(args.scene, sizes, args.seconds, args.rounds_per_tick)
        command = f".venv/bin/python -m bench.bench_large --scale {args.scale} --seconds {args.seconds:g}"
        if args.rounds_per_tick is not None:
            command += f" --rounds-per-tick {args.rounds_per_tick}"
        write_results(
            "scale" if args.rounds_per_tick is None else f"scale_rounds{args.rounds_per_tick}",
            f"Central engine: cost per robot-step from {sizes[0]} to {sizes[-1]} robots",
            command,
            lines,
        )
        return 0
    if args.before:
        lines = side_by_side(args.before, args.pairs, args.scene, args.before_path)
        command = f".venv/bin/python -m bench.bench_large --before {args.before} --pairs {args.pairs}"
        command += f" --before-path {args.before_path}" if args.before_path else ""
        write_results("large_before", f"Central engine, {args.scene}: before and after", command, lines)
        return 0

    command = (
        ".venv/bin/python -m bench.bench_large"
        + "".join(
            f" --{k} {v}"
            for k, v in (
                ("scene", args.scene if args.scene != SCENE else None),
                ("robots", args.robots),
                ("images", args.images),
                ("results", args.results if args.results != "large" else None),
            )
            if v is not None
        )
        + "".join(f" --assignment {a}" for a in args.assignment or ())
    )
    scene, shown = scene_for(args.scene, args.robots, args.images)
    runs = [timed_run(scene, a, not args.quiet) for a in args.assignment or ASSIGNMENTS]
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = describe(scene, shown) + [
        "",
        "### Side by side",
        "",
        *summary_table(runs),
        "",
        "### Time per control step by part (mean over every step, cold starts included)",
        "",
        *split_table(runs),
        "",
        "### Per image",
        "",
        *image_table(scene, runs),
        "",
        "### What bounds the realtime factor",
        "",
        *bounds(runs, RobotParams.from_dict(scene.robot).dt, scene.robots),
        "",
        f"Peak memory of the process {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; load "
        f"average at the end {load} (other work on the machine inflates wall times, not CPU times). "
        "converged_at counts from the image change in display time; an assignment's wall time does not "
        "advance display time.",
    ]
    write_results(
        args.results, f"Large-scale display: {scene.robots} robots, central engine (paper 7.5, Fig. 12)", command, lines
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
