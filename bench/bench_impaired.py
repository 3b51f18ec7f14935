"""Safe is not enough (issue 23): over the real bus, lost and late neighbour states must cost time,
not the picture. Lock-step runs of the 20-robot circle and the 14-robot paper sequence, one agent
process per robot, with and without `--faults state:drop=0.2,delay=0.1,jitter=0.02` (the faults
count in ticks, drawn per message: the same figures on any machine); per image, the time every
robot took to come within 1 cm of its goal, impaired over clear.

    .venv/bin/python -m bench.bench_impaired [--seeds 4 5 6]
"""

from __future__ import annotations

import argparse

import numpy as np

from sim.metrics import step_metrics, time_to_converge

from .common import run_cli_scene, write_results

FAULTS = "state:drop=0.2,delay=0.1,jitter=0.02"
TOLERANCE = 0.01  # m: every robot within 1 cm of its goal
CASES = [("circle", 20), ("paper-sequence", 14)]


def formed(traj: dict) -> list[float | None]:
    """Per image: seconds from its change until every robot was within TOLERANCE (None: never)."""
    if "step" in traj and len(np.unique(traj["step"])) > 1:
        steps = step_metrics(traj["t"], traj["pose"], traj["goal"], traj["step"], TOLERANCE)
        return [s["converged_at"] for s in steps]
    return [time_to_converge(traj["t"], traj["pose"], traj["goal"], TOLERANCE)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[4])
    args = parser.parse_args()
    lines = [
        "| scene | seed | image | clear: formed after s | impaired: formed after s | impaired / clear | contacts (clear, impaired) | wall s (clear, impaired) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene, robots in CASES:
        for seed in args.seeds:
            common = [scene, "--robots", str(robots), "--seed", str(seed), "--clock", "lockstep"]
            runs = {}
            for name, extra in (("clear", []), ("impaired", ["--faults", FAULTS])):
                got = run_cli_scene(common + extra)
                if got is None:
                    return 1
                runs[name] = got
                print(f"{scene} seed {seed} {name}: formed {formed(got[1])}", flush=True)
            (m_clear, t_clear, w_clear), (m_bad, t_bad, w_bad) = runs["clear"], runs["impaired"]
            for k, (a, b) in enumerate(zip(formed(t_clear), formed(t_bad), strict=True)):
                ratio = "-" if a is None or b is None or a == 0 else f"{b / a:.2f}"
                lines.append(
                    f"| {scene} {robots} | {seed} | {k} | {'never' if a is None else f'{a:.1f}'} "
                    f"| {'never' if b is None else f'{b:.1f}'} | {ratio} "
                    f"| {m_clear['contacts']}, {m_bad['contacts']} | {w_clear:.0f}, {w_bad:.0f} |"
                )
    seeds = " ".join(map(str, args.seeds))
    write_results(
        "impaired",
        "Safe is not enough: lost and late states over the bus cost time, not the picture",
        f".venv/bin/python -m bench.bench_impaired --seeds {seeds}",
        [
            *lines,
            "",
            f"Impaired: `--faults {FAULTS}` (20 % of state messages lost per receiver, the rest 100 ms "
            "late with up to 20 ms jitter: a tick or two at 10 Hz), one agent process per robot, lock-step. "
            "Formed: every robot within 1 cm of its goal, seconds after the image changed "
            "(sim.metrics.step_metrics). Contacts from the world's true poses.",
        ],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
