"""Large-scale display (paper 7.2 / 7.5, Fig. 12 bottom row): the six images of the paper's sequence
with 1000 simulated holonomic robots, stepped by the central engine.

    .venv/bin/python -m bench.bench_large                   # both parts (30 min on 2 quiet cores)
    .venv/bin/python -m bench.bench_large --robots 200      # a smaller swarm, same scene (a trial)
    .venv/bin/python -m bench.bench_large --auction-window 0 --results large-trial   # part 1 only

It runs what `pixelswarm run paper-sequence-1000 --no-video` runs (the scene says engine = "central")
(`sim.central.run_central`), in this process so that the engine's hot calls can be timed from outside
(sim/central.py is not changed): the goal assignment and the control core `control_step` (ORCA for
every robot). The rest of a control step is the neighbour search, the tracker, the world step (10
substeps with contact detection) and recording.

1. The whole sequence with the central engine's optimal assignment (scene `assignment = "optimal"`:
   scipy's linear_sum_assignment each `assign_period`, kept unless better by Delta C), when the
   engine has it: the scene's robots through all six images.
2. The paper's auction (agent.core.auction.solve, the engine's default) on the same scene for the
   first `--auction-window` seconds of display: its cold start (epsilon scaling, at every new image)
   and its warm instances while the robots move. At 1000 robots it is far too slow for the whole
   sequence (see the results), so only this window is measured.

Reported into bench/results/large.md: contacts and minimum clearance; per transition the hold, when
every robot was within 1 cm of its goal (`converged_at`, seconds after the image change), the largest
goal error at the end of the hold and the mean wall time per control step; for the whole run the wall
time, the realtime factor (display seconds per wall second) and the time per control step split into
assignment, control core and the rest.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

import sim.central as central
from coordinator.scene import load_scene

from .common import write_results

SCENE = "paper-sequence-1000"


@dataclass
class Timings:
    """Wall time of the engine's assignment and control-core calls in one run, in call order."""

    control_start: list[float] = field(default_factory=list)  # perf_counter at each control_step (one per tick)
    control_s: list[float] = field(default_factory=list)
    assign_start: list[float] = field(default_factory=list)
    assign_s: list[float] = field(default_factory=list)
    assign_cold: list[bool] = field(default_factory=list)  # an auction without a view: a new image's cold start
    assign_rounds: list[int] = field(default_factory=list)  # auction rounds (0: the optimal assignment)

    def per_tick(self) -> dict[str, np.ndarray]:
        """Per control step k >= 1 (from the control call of tick k-1 to that of tick k): its wall time,
        the assignment time and rounds within it, whether it held a cold start, the control-core time."""
        c = np.array(self.control_start)
        a, s = np.array(self.assign_start), np.array(self.assign_s)
        tick_of = np.searchsorted(c, a)  # assignment calls before control call k belong to tick k
        n = len(c)
        assign = np.bincount(tick_of, weights=s, minlength=n + 1)[:n]
        rounds = np.bincount(tick_of, weights=np.array(self.assign_rounds, float), minlength=n + 1)[:n]
        cold = np.bincount(tick_of, weights=np.array(self.assign_cold, float), minlength=n + 1)[:n] > 0
        return {"wall": np.diff(c), "assign": assign[1:], "rounds": rounds[1:], "cold": cold[1:],
                "control": np.array(self.control_s)[1:], "first_cold": assign[0] if cold[0] else 0.0}


class Progress:
    """Stands in for stderr: echoes the engine's once-a-second progress line with the wall clock."""

    def __init__(self, echo: bool) -> None:
        self.echo = echo

    def write(self, text: str) -> int:
        if self.echo and text.strip():
            print(f"{time.strftime('%H:%M:%S')} {text.strip()}", file=sys.stderr, flush=True)
        return len(text)

    def flush(self) -> None:
        pass


def _timed(fn: Callable[..., Any], starts: list[float], durations: list[float],
           after: Callable[[tuple, dict, Any], None] | None = None) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        result = fn(*args, **kwargs)
        starts.append(t0)
        durations.append(time.perf_counter() - t0)
        if after is not None:
            after(args, kwargs, result)
        return result
    return wrapper


def timed_run(scene: Any, out: Path, echo: bool) -> tuple[Path, Timings, float]:
    """run_central with its assignment and control core timed (patched for this run, then restored)."""
    tm = Timings()
    names = ["solve", "control_step"] + (["optimal_assignment"] if hasattr(central, "optimal_assignment") else [])
    saved = {name: getattr(central, name) for name in names}

    def after_solve(args: tuple, kwargs: dict, result: Any) -> None:
        tm.assign_cold.append(kwargs.get("view") is None)
        tm.assign_rounds.append(int(result[1]))

    def after_optimal(args: tuple, kwargs: dict, result: Any) -> None:
        tm.assign_cold.append(False)
        tm.assign_rounds.append(0)

    central.solve = _timed(saved["solve"], tm.assign_start, tm.assign_s, after_solve)
    central.control_step = _timed(saved["control_step"], tm.control_start, tm.control_s)
    if "optimal_assignment" in saved:
        central.optimal_assignment = _timed(saved["optimal_assignment"], tm.assign_start, tm.assign_s, after_optimal)
    try:
        w0 = time.perf_counter()
        path = central.run_central(scene, out, video=False, progress=Progress(echo))
        total = time.perf_counter() - w0
    finally:
        for name, fn in saved.items():
            setattr(central, name, fn)
    return path, tm, total


def fmt(value: float | None, digits: int = 1, unit: str = "") -> str:
    return "not within the hold" if value is None else f"{value:.{digits}f}{unit}"


def describe(scene: Any, cli: str) -> list[str]:
    r = scene.robot
    return [f"Scene `{scene.name}`: {scene.robots} {r.get('kinematics', 'diffdrive')} robots (radius {scene.radius} m, "
            f"v_max {r.get('v_max')} m/s, v_pref {r.get('v_pref')} m/s, neighbour_dist {r.get('neighbour_dist')} m, "
            f"max_neighbours {r.get('max_neighbours')}), seed {scene.seed}, arena K_r {scene.image_goals.arena:.2f} m, "
            f"tracking noise {scene.noise.tracking_xy * 1000:.0f} mm / {scene.noise.tracking_theta_deg:.0f} deg, "
            f"actuation noise {scene.noise.actuation * 100:.0f} %. Part 1 is "
            f"`pixelswarm run {cli} --engine central --no-video` with the scene's `assignment = \"optimal\"`; "
            f"part 2 the same with `assignment = \"auction\"`."]


def report_full(scene: Any, metrics: dict, step: np.ndarray, tm: Timings, total_wall: float) -> list[str]:
    pt = tm.per_tick()
    display, wall = float(metrics["duration_s"]), float(metrics["wall_s"])
    warm = ~pt["cold"]
    lines = [
        f"- contacts: **{metrics['contacts']}**; minimum clearance {metrics['min_clearance_m']:.4f} m "
        f"(at 100 Hz: {fmt(metrics.get('min_clearance_substep_m'), 4, ' m')}); ORCA fallbacks "
        f"{metrics.get('orca_fallbacks')}",
        f"- display time {display:.1f} s (end: {metrics.get('end_reason')}), {len(pt['wall']) + 1} control steps",
        f"- wall time **{wall:.0f} s** ({total_wall:.0f} s with writing the run directory); realtime factor "
        f"**{display / wall:.3f}** (display s per wall s)",
        f"- per control step (median / mean / p90): {np.median(pt['wall']) * 1e3:.0f} / {pt['wall'].mean() * 1e3:.0f} / "
        f"{np.percentile(pt['wall'], 90) * 1e3:.0f} ms; of the mean: assignment {pt['assign'].mean() * 1e3:.0f} ms, "
        f"control core (ORCA) {pt['control'].mean() * 1e3:.0f} ms, the rest (neighbours, tracker, world step, "
        f"recording) {(pt['wall'] - pt['assign'] - pt['control']).mean() * 1e3:.0f} ms",
        f"- peak memory of the process {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB",
    ]
    if pt["cold"].any() or pt["first_cold"]:
        lines.append(f"- cold-start auctions: {int(pt['cold'].sum()) + (1 if pt['first_cold'] else 0)}, "
                     f"{pt['assign'][pt['cold']].sum() + pt['first_cold']:.0f} s together")
    lines += ["", "| step | image | hold s | converged_at s (all within 1 cm) | max goal error at end m | "
                  "mean ms per control step | path per robot m |", "|---|---|---|---|---|---|---|"]
    step_of_tick = step[1: len(pt["wall"]) + 1].astype(int)
    for s in sorted(metrics["steps"], key=lambda s: s["index"]):
        k = s["index"]
        mine = (step_of_tick == k) & warm
        ms = f"{pt['wall'][mine].mean() * 1e3:.0f}" if mine.any() else "-"
        lines.append(f"| {k} | {scene.steps[k].name} | {scene.steps[k].hold:.0f} | {fmt(s['converged_at'])} | "
                     f"{fmt(s['max_goal_error_at_end'], 4)} | {ms} | {s['path_length_m'] / scene.robots:.1f} |")
    return lines


def report_window(metrics: dict, tm: Timings) -> list[str]:
    pt = tm.per_tick()
    cold = pt["first_cold"] + pt["assign"][pt["cold"]].sum()
    warm = ~pt["cold"]
    rounds = pt["rounds"][warm]
    return [
        f"- cold start (epsilon scaling from scratch, at every new image): **{cold:.0f} s** "
        f"({tm.assign_rounds[0] if tm.assign_cold and tm.assign_cold[0] else '?'} rounds)",
        f"- then per control step while the robots move (mean / max over {int(warm.sum())} steps): "
        f"**{pt['assign'][warm].mean():.2f} / {pt['assign'][warm].max():.2f} s** in the auction "
        f"({rounds.mean():.0f} / {rounds.max():.0f} rounds), control core {pt['control'][warm].mean() * 1e3:.0f} ms, "
        f"the rest {(pt['wall'] - pt['assign'] - pt['control'])[warm].mean() * 1e3:.0f} ms",
        f"- contacts {metrics['contacts']}; realtime factor {metrics['duration_s'] / metrics['wall_s']:.4f} "
        f"over the {metrics['duration_s']:.1f} s window",
    ]


def run_part(scene: Any, echo: bool, keep: Path | None) -> tuple[dict, np.ndarray, Timings, float]:
    with tempfile.TemporaryDirectory(prefix="bench_large_") as tmp:
        out = keep if keep is not None else Path(tmp) / "run"
        path, tm, total = timed_run(scene, out, echo)
        metrics = json.loads((path / "metrics.json").read_text())
        with np.load(path / "trajectory.npz") as z:
            step = np.array(z["step"])
    return metrics, step, tm, total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default=SCENE)
    parser.add_argument("--robots", type=int, help="override the scene's robot count (a trial)")
    parser.add_argument("--duration", type=float, help="part 1: display seconds at most (a trial)")
    parser.add_argument("--auction-window", type=float, default=3.0,
                        help="part 2: display seconds of the paper's auction (0: skip; default 3)")
    parser.add_argument("--results", default="large", help="bench/results/<name>.md (default large)")
    parser.add_argument("--keep", type=Path, help="keep part 1's run directory here")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args()

    cli = args.scene + "".join(f" --{k} {v:g}" for k, v in (("robots", args.robots), ("duration", args.duration))
                               if v is not None)
    command = ".venv/bin/python -m bench.bench_large" + "".join(
        f" --{k} {v}" for k, v in (("scene", args.scene if args.scene != SCENE else None), ("robots", args.robots),
                                   ("duration", args.duration), ("auction-window", args.auction_window
                                                                 if args.auction_window != 3.0 else None))
        if v is not None)
    scene = load_scene(args.scene, robots=args.robots, duration=args.duration)
    lines = describe(scene, cli) + [""]

    if hasattr(scene, "assignment"):
        scene.assignment = "optimal"
        metrics, step, tm, total = run_part(scene, not args.quiet, args.keep)
        period = scene.robot.get("assign_period", 0.1)
        lines += [f"### 1. The whole sequence, optimal assignment (`assignment = \"optimal\"`, every {period} s)", ""]
        lines += report_full(scene, metrics, step, tm, total)
    else:
        lines += ["### 1. The whole sequence: not run",
                  "", "This central engine has no optimal-assignment path (scene `assignment`), and its auction "
                      "is far too slow for 1000 robots through six images (part 2)."]
    lines.append("")

    if args.auction_window > 0:
        window = load_scene(args.scene, robots=args.robots, duration=args.auction_window)
        if hasattr(window, "assignment"):
            window.assignment = "auction"
        metrics, _, tm, _ = run_part(window, not args.quiet, None)
        lines += [f"### 2. The paper's auction (agent.core.auction.solve, the default), first "
                  f"{args.auction_window:g} s of the first transition", ""]
        lines += report_window(metrics, tm)
        lines += ["", "The auction runs its synchronous rounds in Python, every robot's bid in turn (O(N G) per "
                      "round); a cold start needs thousands of rounds at 1000 robots, and while the robots cross the "
                      "arena the warm instance of each control step needs many rounds too. At these rates the six "
                      "images would take hours, so the whole sequence is measured with the optimal assignment."]
    lines += ["", "converged_at counts from the image change in display time; an assignment's wall time does not "
                  "advance display time. The last image ends the run once every robot has held its goal for "
                  "converge_hold (1 s)."]
    write_results(args.results, f"Large-scale display: {scene.robots} robots, central engine (paper 7.5, Fig. 12)",
                  command, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
