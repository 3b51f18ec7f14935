"""The paper's 1000-robot sequence (paper 7.5, scene `paper-sequence-1000`) distributed in agent
hosts (issue 6): every robot decides for itself, K robots per process, over zenoh. Reported per
image: when every robot was within 1 cm of its goal (converged_at, display seconds after the image
change) and the largest error at the end; contacts and clearance; the realtime factor; messages per
robot-second by kind; per image, from trajectory.npz, when every robot drove to an agreed goal,
how many instances were agreed and how many sent more than RESHUFFLE robots elsewhere; per agent
host, from log.mcap (runs given with --from), how late its commands came after each tick. The whole
sequence is up to 390 s of display time, 5-6 minutes of wall time on 2 cores at the realtime factors
measured (1.00-1.27), so ``--duration`` runs its first images only.

    .venv/bin/python -m bench.bench_hosted --duration 100            # the first two images (about 2 min)
    .venv/bin/python -m bench.bench_hosted --from RUN_DIR [--from RUN_DIR2]  # summarise finished runs
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import orjson

from sim.mcaplog import logged
from transport.codec import State

from .common import load_run, run_cli_scene, steps_table, write_results

SCENE = "paper-sequence-1000"
RESHUFFLE = 100  # an agreement that sends more than this many robots to other goals is a reshuffle


def reassignments(traj: dict) -> list[str]:
    """Per image, from trajectory.npz: when every robot first drove to a goal of an agreed instance
    of the new goal set (display s after the change), how many instances were agreed, and how many
    of those sent more than RESHUFFLE robots to other goals than the agreed instance before (each
    robot's goal in an instance as recorded while it drove to it)."""
    if "goal_set_epochs" not in traj:
        return []  # a scene without images (circle, swap): goals are the scene's, nothing is auctioned
    t, goal = traj["t"], traj["assignment"]
    epoch, instance = traj["assignment_epoch"], traj["assignment_instance"].astype(np.int64)
    rows = [
        "| image | every robot on an agreed goal, s after the change | agreed instances driven to | "
        f"re-assignments of >{RESHUFFLE} robots |",
        "|---|---|---|---|",
    ]
    for e, step in zip(traj["goal_set_epochs"], traj["goal_set_steps"]):
        e, step = int(e), int(step)
        mine = (epoch == e) & (instance != State.CARRIED)
        seen = np.flatnonzero(mine.any(axis=1))
        if not len(seen):
            rows.append(f"| {step} | never | 0 | 0 |")
            continue
        change = float(t[np.flatnonzero((epoch == e).any(axis=1))[0]])  # the goal set's first sample
        everyone = np.flatnonzero(mine.all(axis=1))
        agreed = sorted(set(instance[mine].tolist()))
        goals_of = {}
        for i in agreed:  # robot -> goal in instance i
            r_idx = np.nonzero(mine & (instance == i))
            goals_of[i] = dict(zip(r_idx[1].tolist(), goal[r_idx].tolist()))
        moved = sum(
            1
            for a, b in zip(agreed, agreed[1:])
            if sum(goals_of[a].get(r, g) != g for r, g in goals_of[b].items()) > RESHUFFLE
        )
        first = f"{t[everyone[0]] - change:.1f}" if len(everyone) else "never"
        rows.append(f"| {step} | {first} | {len(agreed)} | {moved} |")
    return rows


def command_latency(run: Path) -> list[str]:
    """Per agent host, from the run's log.mcap: how long after the world's tick k its command frame
    for tick k arrived (both as the recorder received them), and how many arrived more than one
    control period late, per 10 s of display. In real time a late command is a missed tick: the
    robots drive on with their last one."""
    clock: dict[int, tuple[int, float]] = {}
    sent: dict[str, dict[int, int]] = {}
    for log_time, topic, d in logged(run / "log.mcap", {"/clock", "/cmd"}):
        if topic == "/clock":
            clock.setdefault(d["tick"], (log_time, d["dt"]))
        else:
            sent.setdefault(d["key"].rsplit("/", 1)[-1], {}).setdefault(d["tick"], log_time)
    if not sent:
        return []
    rows = [
        "| host (first robot) | latency ms, median / p90 / max | later than a period | of those, per 100 ticks (10 s) |",
        "|---|---|---|---|",
    ]
    for host, ticks in sorted(sent.items(), key=lambda kv: int(kv[0])):
        tick = np.array([t for t in sorted(ticks) if t in clock])
        latency = np.array([(ticks[t] - clock[t][0]) / 1e9 for t in tick])
        late = latency > np.array([clock[t][1] for t in tick])
        per_10s = np.bincount(tick[late] // 100, minlength=int(tick.max()) // 100 + 1)
        rows.append(
            f"| {host} | {np.median(latency) * 1e3:.0f} / {np.percentile(latency, 90) * 1e3:.0f} / "
            f"{latency.max() * 1e3:.0f} | {int(late.sum())} of {len(tick)} | {' '.join(map(str, per_10s))} |"
        )
    return rows + [""]


def rounds_per_tick(run: Path) -> int:
    """The run's bound on the lock-step auction's rounds a tick (0: none), from its scene.json."""
    scene = orjson.loads((run / "scene.json").read_bytes())
    return int(scene.get("robot", {}).get("rounds_per_tick", 0))


def summary(m: dict, wall: float, k: int, rounds: int = 0) -> list[str]:
    bound = f", {rounds} auction rounds a tick" if rounds else ""
    rows = [
        f"**{m['duration_s']:.0f} s of display** ({m['robots']} robots in {m['agent_processes']} agent hosts of "
        f"{k}, {m.get('clock', 'lockstep')} clock{bound}): wall {wall:.0f} s, realtime factor {m['duration_s'] / wall:.3f} (while stepping "
        f"{m['stepping_realtime_factor']:.3f}: {100 / m['stepping_realtime_factor']:.0f} ms of wall time per "
        f"0.1 s control step); contacts {m['contacts']}; min clearance "
        f"{m['min_clearance_m'] * 1e3:.1f} mm; missed ticks {m['missed_ticks']}; ORCA fallbacks "
        f"{m.get('orca_fallbacks')}.",
        "",
        *steps_table(m),
    ]
    per_kind = ", ".join(f"{kind} {n:.1f}" for kind, n in sorted(m["messages_per_robot_s"].items()) if n >= 0.05)
    rows += [
        "",
        f"Messages per robot-second: {per_kind}; bytes per robot-second, all kinds: "
        f"{sum(m['bytes_per_robot_s'].values()):.0f}.",
        "",
    ]
    return rows


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("-k", type=int, default=250, help="robots per agent process (default 250: 4 hosts)")
    parser.add_argument("--duration", type=float, default=100.0, help="display seconds (default 100)")
    parser.add_argument("--from", dest="runs", action="append", type=Path, help="a finished run directory")
    args = parser.parse_args()
    lines: list[str] = []
    commands = []
    if args.runs:
        for run in args.runs:
            loaded = load_run(run)
            if loaded is None:
                return 2
            m, traj, wall = loaded
            k = m.get("agents_per_process") or args.k
            rounds = rounds_per_tick(run)
            lines += summary(m, wall, k, rounds) + reassignments(traj) + [""] + command_latency(run)
            commands.append(
                f"pixelswarm run {SCENE} --engine distributed -k {k} --clock {m['clock']} "
                + (f"--rounds-per-tick {rounds} " if rounds else "")
                + f"--duration {m['duration_s']:g} --no-video --out RUN"
            )
        commands.append(".venv/bin/python -m bench.bench_hosted --from RUN ...")
    else:
        ran = run_cli_scene([SCENE, "--engine", "distributed", "-k", str(args.k), "--duration", str(args.duration)])
        if ran is None:
            return 1
        m, traj, wall = ran
        lines += summary(m, wall, args.k) + reassignments(traj) + [""]
        commands.append(f".venv/bin/python -m bench.bench_hosted -k {args.k} --duration {args.duration:g}")
    write_results(
        "hosted", "The 1000-robot sequence, distributed in agent hosts (issue 6)", "`; `".join(commands), lines
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
