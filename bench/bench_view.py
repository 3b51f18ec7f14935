"""What the live view (`pixelswarm run --view`, sim.view) costs a central run, side by side in one process.

    .venv/bin/python -m bench.bench_view [--scene paper-sequence-1000] [--duration 20] [--repeats 3]

The same seeded central run (sim.central.simulate) alternately without a view and with one logging
every tick to an .rrd file in a temporary directory (the sink that needs no window); the figure is
the run's wall time per tick, median over the repeats, and the ratio of the two.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from agent.core.params import RobotParams
from coordinator.scene import load_scene
from sim.central import simulate
from sim.view import SwarmView

from .common import write_results


def one_run(scene, view: bool, tmp: Path) -> float:
    """Wall seconds per recorded tick of one run."""
    sink = None
    if view:
        params = RobotParams.from_dict(scene.robot)
        sink = SwarmView(
            scene.name, scene.arena, scene.obstacles, params.radius, robots=scene.robots, sink=tmp / "view.rrd"
        )
    try:
        outcome = simulate(scene, progress=None, view=sink)
    finally:
        if sink is not None:
            sink.close()  # every tick in the file: part of the cost
    return outcome.wall_s / len(outcome.arrays["t"])


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scene", default="paper-sequence-1000")
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    scene = load_scene(args.scene, duration=args.duration, seed=1)
    times: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for view in (False, True):
                times[view].append(one_run(scene, view, Path(tmp)))
                print(f"view={view}: {times[view][-1] * 1e3:.2f} ms a tick", flush=True)
    without, with_view = (statistics.median(times[v]) for v in (False, True))
    lines = [
        "| run | ms a tick (median) | each repeat |",
        "|---|---|---|",
        f"| no view | {without * 1e3:.2f} | {', '.join(f'{t * 1e3:.2f}' for t in times[False])} |",
        f"| --view FILE.rrd | {with_view * 1e3:.2f} | {', '.join(f'{t * 1e3:.2f}' for t in times[True])} |",
        "",
        f"The view costs the run {100 * (with_view / without - 1):+.0f} % ({scene.robots} robots, "
        f"{args.duration:g} s, central engine, ticks logged on the view's own thread).",
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
