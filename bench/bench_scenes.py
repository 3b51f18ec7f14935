"""Benchmark of loading a scene in a distributed run: each child running the image pipeline (before)
against each child reading the resolved scene from the run directory (now), side by side in one run.

- CPU seconds a fresh world / coordinator process spends from its start until it holds the scene
  (interpreter, imports and loading; user + system time of the process), median of --repeat;
- wall seconds from `pixelswarm run SCENE --clock lockstep` to its first tick's progress line.

Both load paths live in this tree (``load_scene``: parse + image pipeline, what each child did; and
``load_resolved``: what each child does now). ``--before DIR`` (a checkout of the code before the
change, e.g. `git archive <commit> | tar -x -C DIR`) also times that tree's own children and start-up.

    .venv/bin/python -m bench.bench_scenes                     # writes bench/results/scenes.md
    .venv/bin/python -m bench.bench_scenes --before /tmp/old --repeat 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .common import REPO, write_results

# A child's start: its module's imports, then the scene as it loads it; prints its CPU and wall time.
CHILD = """
import json, resource, sys, time
t0 = time.perf_counter()
import {module}
{load}
u = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({{"cpu": u.ru_utime + u.ru_stime, "wall": time.perf_counter() - t0,
                  "cv2": "cv2" in sys.modules, "pipeline": "coordinator.goals.pipeline" in sys.modules}}))
"""
PARSE = "from coordinator.scene import load_scene; load_scene({scene!r}, robots={robots}, seed={seed})"
RESOLVED = "from coordinator.resolved import load_resolved; load_resolved({run_dir!r})"
CHILDREN = {"world": "sim.world_node", "coordinator": "coordinator.service"}


def child_load(tree: Path, module: str, load: str) -> dict:
    code = CHILD.format(module=module, load=load)
    out = subprocess.run([sys.executable, "-c", code], cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def first_tick(tree: Path, scene: str, out: Path) -> float | None:
    """Seconds from `pixelswarm run` to its first progress line with a display time (None: no tick)."""
    start = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "run", scene, "--clock", "lockstep", "--duration", "1"]
        + ["--no-video", "--out", str(out)],
        cwd=tree,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen = None
    assert proc.stderr is not None
    for line in proc.stderr:
        if seen is None and " t=" in line:
            seen = time.monotonic() - start
    proc.wait()
    return seen


def _median(values: list[float]) -> str:
    return f"{statistics.median(values):.2f}" if values else "-"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_scenes")
    parser.add_argument("--scene", nargs="+", default=["paper-sequence"], help="scenes to time (start-up: the first)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--before", type=Path, help="a checkout of the code before the change, to time too")
    parser.add_argument("--no-startup", dest="startup", action="store_false", help="skip the start-up runs")
    args = parser.parse_args(argv)
    if args.before is not None and not (args.before / "sim" / "cli.py").is_file():
        print(f"error: {args.before} is not a pixelswarm checkout (no sim/cli.py)", file=sys.stderr)
        return 2

    from coordinator.resolved import save_resolved
    from coordinator.scene import load_scene

    rows: dict[str, list[dict]] = {}
    startup: dict[str, list[float | None]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        ways: dict[str, tuple[Path, str]] = {}
        for name in args.scene:
            scene = load_scene(name)
            run_dir = Path(tmp) / f"resolved-{name}"
            run_dir.mkdir()
            save_resolved(scene, run_dir)
            label = f"{name} ({scene.robots} robots, {len(scene.steps)} images)"
            parse = PARSE.format(scene=name, robots=scene.robots, seed=scene.seed)
            ways[f"{label}|each child runs the pipeline (this tree)"] = (REPO, parse)
            ways[f"{label}|each child reads the run directory (this tree)"] = (
                REPO,
                RESOLVED.format(run_dir=str(run_dir)),
            )
            if args.before is not None:
                ways[f"{label}|each child runs the pipeline (--before tree)"] = (args.before, parse)
        for _ in range(args.repeat):  # interleaved: the shared machine's load falls on every way alike
            for way, (tree, load) in ways.items():
                for child, module in CHILDREN.items():
                    rows.setdefault(f"{way}|{child}", []).append(child_load(tree, module, load))
            if args.startup:
                trees = {"this tree": REPO} | ({"--before tree": args.before} if args.before else {})
                for name, tree in trees.items():
                    out = Path(tmp) / f"run-{name.strip('-').split()[0]}-{len(startup.get(name, []))}"
                    startup.setdefault(name, []).append(first_tick(tree, args.scene[0], out))

    lines = [
        "CPU and wall seconds of a fresh world / coordinator process from its start until it holds the",
        f"scene (interpreter and imports included), median of {args.repeat}, interleaved.",
        "",
        "| scene | how it loads the scene | process | CPU s | wall s | OpenCV loaded | image pipeline loaded |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, samples in rows.items():
        label, way, child = key.split("|")
        lines.append(
            f"| {label} | {way} | {child} | {_median([s['cpu'] for s in samples])} | "
            f"{_median([s['wall'] for s in samples])} | "
            f"{'yes' if samples[0]['cv2'] else 'no'} | {'yes' if samples[0]['pipeline'] else 'no'} |"
        )
    if startup:
        lines += [
            "",
            f"`pixelswarm run {args.scene[0]} --clock lockstep --duration 1`: wall seconds to the first tick's",
            "progress line (each run; '-': the run never ticked).",
            "",
            "| code | seconds to the first tick |",
            "|---|---|",
        ]
        for name, values in startup.items():
            lines.append(f"| {name} | {', '.join('-' if v is None else f'{v:.1f}' for v in values)} |")
    command = "python -m bench.bench_scenes " + " ".join(argv if argv is not None else sys.argv[1:])
    write_results("scenes", "Loading a scene: per child, or once per run", command.strip(), lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
