"""What the tick-synchronous auction (issue 21, docs/lockstep_auction.md) costs a lock-step run of a
picture, side by side with the code before it: per engine (a process per robot, agent hosts of K),
runs of the same seed alternate between a checkout of the code before (``--before DIR``, e.g. made
with `git worktree add DIR COMMIT`) and this one; each reports the wall time per tick, whether it
is the central engine's run to 1e-9 m, and the recorded ticks where two robots drive to one goal.

    python -m bench.bench_sync --before ../pixelswarm-before --robots 30 --pairs 2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from .common import REPO, write_results

ENGINES = {"central": ["--engine", "central"], "a process per robot": [], "hosts of 5": ["-k", "5"]}


def picture(folder: Path) -> Path:
    """The test picture (tests/test_sync_auction.py): a disk and a bar."""
    import cv2

    image = np.full((120, 160, 3), 255, np.uint8)
    cv2.circle(image, (55, 60), 35, (0, 0, 200), -1)
    cv2.rectangle(image, (100, 25), (145, 95), (200, 0, 0), -1)
    path = folder / "picture.png"
    cv2.imwrite(str(path), image)
    return path


def run(code: Path, args: list[str], out: Path) -> tuple[dict, dict]:
    """`pixelswarm run` with the code of ``code`` (its folder first on the import path)."""
    cmd = [sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"]
    proc = subprocess.run(cmd, cwd=code, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"run failed ({code}): {proc.stderr[-2000:]}")
    return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))


def shared_ticks(traj: dict) -> int:
    """Recorded ticks where two robots hold one goal."""
    return sum(len(np.unique(row[row >= 0])) != int((row >= 0).sum()) for row in traj["assignment"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_sync")
    parser.add_argument("--before", required=True, type=Path, help="a checkout of the code before")
    parser.add_argument("--robots", type=int, default=30)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--pairs", type=int, default=1)
    parser.add_argument("--results", default="sync", help="name of the results file in bench/results")
    opt = parser.parse_args(argv)
    if not (opt.before / "sim" / "cli.py").is_file():
        print(f"error: {opt.before} is not a checkout of pixelswarm (no sim/cli.py)", file=sys.stderr)
        return 2
    rows = [
        "| engine | pair | code | wall s per tick | ticks | = central (1e-9 m) | ticks with a shared goal |",
        "|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        image = picture(Path(tmp))
        args = [str(image), "--robots", str(opt.robots), "--clock", "lockstep", "--seed", str(opt.seed)]
        codes = {"before": opt.before.resolve(), "now": REPO}
        central = {
            name: run(code, args + ENGINES["central"], Path(tmp) / f"central-{name}")[1] for name, code in codes.items()
        }
        for engine, flags in ENGINES.items():
            if engine == "central":
                continue
            for pair in range(opt.pairs):
                order = list(codes) if pair % 2 == 0 else list(reversed(codes))
                for name in order:
                    m, traj = run(codes[name], args + flags, Path(tmp) / f"{engine}-{pair}-{name}".replace(" ", "-"))
                    ref = central[name]
                    same = (
                        len(traj["t"]) == len(ref["t"])
                        and float(np.abs(traj["pose"][..., :2] - ref["pose"][..., :2]).max()) <= 1e-9
                    )
                    per_tick = m["stepping_wall_s"] / max(m["samples"] - 1, 1)
                    rows.append(
                        f"| {engine} | {pair + 1} | {name} | {per_tick:.3f} | {len(traj['t'])} | {'yes' if same else 'no'} | {shared_ticks(traj)} |"
                    )
                    print(rows[-1], flush=True)
    command = "python -m bench.bench_sync " + " ".join(argv if argv is not None else sys.argv[1:])
    write_results(
        opt.results,
        "The tick-synchronous auction in lock-step, side by side with the code before (issue 21)",
        command,
        [
            f"A picture of a disk and a bar, {opt.robots} robots, seed {opt.seed}; `now` is this code, `before` the checkout given.",
            "",
            *rows,
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
