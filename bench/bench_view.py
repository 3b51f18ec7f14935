"""What the live view (`pixelswarm run --view`, sim.outputs.view) costs a central run, side by side in one process.

    .venv/bin/python -m bench.bench_view [--scene paper-sequence-1000] [--duration 30] [--repeats 7]

The same seeded central run (sim.central.engine.simulate) alternately without a view and with one logging
every tick to an .rrd file in a temporary directory (the sink that needs no window). A run's time is
its wall time from the start of the run until the view has written every tick (sim.outputs.view.SwarmView.close),
per recorded tick; the figure is the median over the repeats of each pair's ratio (the two runs of a
pair run back to back, under the same load from other work), with the process's CPU time per tick beside.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from agent.core.params import RobotParams
from coordinator.scene import load_scene
from sim.central.engine import simulate
from sim.outputs.view import SwarmView

from .common import write_results


def one_run(scene, view: bool, tmp: Path) -> tuple[float, float]:
    """(wall, CPU) seconds per recorded tick of one run, the view's writing included."""
    sink = None
    if view:
        params = RobotParams.from_dict(scene.robot)
        sink = SwarmView(
            scene.name, scene.arena, scene.obstacles, params.radius, robots=scene.robots, sink=tmp / "view.rrd"
        )
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        outcome = simulate(scene, progress=None, view=sink)
    finally:
        if sink is not None:
            sink.close()  # every tick in the file: part of the cost
    ticks = len(outcome.arrays["t"])
    return (time.perf_counter() - wall) / ticks, (time.process_time() - cpu) / ticks


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scene", default="paper-sequence-1000")
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    scene = load_scene(args.scene, duration=args.duration, seed=1)
    runs: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        one_run(scene, True, Path(tmp))  # warm: imports and Rerun's start-up, in neither figure
        for k in range(args.repeats):
            for view in (False, True) if k % 2 == 0 else (True, False):  # each first in half the pairs
                runs[view].append(one_run(scene, view, Path(tmp)))
                print(f"view={view}: {runs[view][-1][0] * 1e3:.2f} ms a tick", flush=True)
    ratio = statistics.median(v[0] / w[0] for v, w in zip(runs[True], runs[False]))
    cpu_ratio = statistics.median(v[1] / w[1] for v, w in zip(runs[True], runs[False]))

    def row(name: str, view: bool) -> str:
        wall = statistics.median(r[0] for r in runs[view]) * 1e3
        cpu = statistics.median(r[1] for r in runs[view]) * 1e3
        return f"| {name} | {wall:.2f} | {cpu:.2f} | {', '.join(f'{r[0] * 1e3:.2f}' for r in runs[view])} |"

    lines = [
        "| run | wall ms a tick (median) | CPU ms a tick (median) | wall, each repeat |",
        "|---|---|---|---|",
        row("no view", False),
        row("--view FILE.rrd", True),
        "",
        f"The view costs the run {100 * (ratio - 1):+.1f} % of wall time and {100 * (cpu_ratio - 1):+.1f} % of CPU "
        f"(median of {args.repeats} pairs' ratios; {scene.robots} robots, {args.duration:g} s, central engine).",
    ]
    write_results(
        "view",
        f"The live view's cost: {args.scene}, central engine, side by side",
        f".venv/bin/python -m bench.bench_view --scene {args.scene} --duration {args.duration:g} "
        f"--repeats {args.repeats}",
        lines,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
