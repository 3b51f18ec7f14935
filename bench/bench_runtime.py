"""Runtime benchmark (issue 2): per-agent-process CPU and memory at 10 Hz, missed ticks in real
time, lock-step real-time factor, and messages and bytes per robot-second.

    .venv/bin/python -m bench.bench_runtime [--quick]
"""

from __future__ import annotations

import argparse

import numpy as np

from .common import run_and_sample, write_results


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 20 only")
    parser.add_argument("--duration", type=float, default=20.0)
    args = parser.parse_args()
    sizes = [20] if args.quick else [20, 50, 100]
    rows = [
        "| N processes | clock | RTF | missed ticks (share of robot-ticks) | CPU per agent (% of a core, median) | RSS per agent MB (median) | USS per agent MB | msgs / robot-s (pose, state, cmd) | bytes / robot-s (all kinds) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for clock in ["realtime", "lockstep"]:
        for n in sizes:
            m, samples = run_and_sample(
                ["circle", "--robots", str(n), "--clock", clock, "--duration", str(args.duration)]
            )
            cpu = np.median([s["cpu"] for s in samples if s["cpu"] > 0] or [0])
            rss = np.median([s["rss"] for s in samples]) / 2**20
            uss = np.median([s["uss"] for s in samples]) / 2**20
            mps = m["messages_per_robot_s"]
            total_bytes = sum(m["bytes_per_robot_s"].values())
            ticks = max(m["samples"] - 1, 1) * n  # robot-ticks the world stepped
            rows.append(
                f"| {n} | {clock} | {m['stepping_realtime_factor']:.2f} | {m['missed_ticks']} "
                f"({100 * m['missed_ticks'] / max(ticks, 1):.2f}%) | {cpu:.1f} | {rss:.1f} | {uss:.1f} | "
                f"{mps.get('pose', 0):.1f}, {mps.get('state', 0):.1f}, {mps.get('cmd', 0):.1f} | {total_bytes:.0f} |"
            )
            print(rows[-1], flush=True)
    hosted = []
    if not args.quick:
        m, samples = run_and_sample(
            ["circle", "--robots", "1000", "--clock", "lockstep", "--duration", "10", "--agents-per-process", "250"]
        )
        cpu = np.median([s["cpu"] for s in samples if s["cpu"] > 0] or [0])
        hosted = [
            "",
            "| N | hosts (K per process) | clock | RTF | CPU per host (%) | RSS per host MB |",
            "|---|---|---|---|---|---|",
            f"| 1000 | 4 (K = 250) | lockstep | {m['stepping_realtime_factor']:.2f} | {cpu:.0f} | "
            f"{np.median([s['rss'] for s in samples]) / 2**20:.0f} |",
        ]
    write_results(
        "runtime",
        "Runtime: agent processes over zenoh (issue 2)",
        ".venv/bin/python -m bench.bench_runtime",
        rows
        + hosted
        + [
            "",
            "RTF: simulated seconds per wall second while the world was stepping (start-up excluded). "
            "Missed ticks: a live agent's command for tick k had not reached the world when tick k+1 began. "
            "USS is memory unique to one process (shared libraries counted once across processes).",
        ],
    )


if __name__ == "__main__":
    main()
