"""Whole `pixelswarm run`s too long for the test suite, in agent hosts and beside the code before: the
1000-robot sequence in hosts of 250 (the default), the 100-robot sequence and the 100-robot leaf
against their acceptance (issues 5 and 6), lock-step engines beside a checkout of the code before,
and loading a scene at start-up. One module, a benchmark per name; each writes bench/results/<name>.md:

    .venv/bin/python -m bench.bench_hosted [--duration 100] [-k 250] [--from RUN_DIR ...]
    .venv/bin/python -m bench.bench_hosted sequence [--scene paper-sequence-100] [-k 10]
    .venv/bin/python -m bench.bench_hosted animation [--scene leaf] [-k 10] [--from RUN_DIR]
    .venv/bin/python -m bench.bench_hosted sync --before DIR [--robots 30] [--pairs 1]
    .venv/bin/python -m bench.bench_hosted processes [--circle 100] [--animation 40] [--repeat 2]
    .venv/bin/python -m bench.bench_hosted beside SCENE [pixelswarm run flags] [--repeat 1]
    .venv/bin/python -m bench.bench_hosted scenes [--scene paper-sequence ...] [--before DIR]
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import orjson

from agent.core.params import RobotParams
from coordinator.scene import load_scene
from tests.support.assignment_quality import agreements
from tests.support.outputs import keyframe_errors, logged
from transport.codec import State

from .common import REPO, load_run, parser_for, run_cli_scene, run_subcommand, steps_table, write_results

# --- 1000 robots in agent hosts (the default) -------------------------------------------------
HOSTED_DOC = """The paper's 1000-robot sequence (paper 7.5, scene `paper-sequence-1000`) distributed in agent
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


def hosted_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted", HOSTED_DOC)
    parser.add_argument("-k", type=int, default=250, help="robots per agent process (default 250: 4 hosts)")
    parser.add_argument("--duration", type=float, default=100.0, help="display seconds (default 100)")
    parser.add_argument("--from", dest="runs", action="append", type=Path, help="a finished run directory")
    args = parser.parse_args(argv)
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


# --- the 100-robot sequence against issue 5's acceptance (sequence) ---------------------------
SEQUENCE_DOC = """The paper's image sequence with 100 robots in agent hosts, distributed, checked against issue 5's
acceptance: zero contacts, every robot within 1 cm of its goal at the end of each hold, no
unresolved deadlock, every agreed assignment within N (epsilon_A + Delta C) + penalties of scipy's
optimum on the positions the robots bid from. Too long for the test suite (about 6 minutes on 2
cores), so it lives here; the suite runs its first two images (test_image_display_distributed.py).

    .venv/bin/python -m bench.bench_hosted sequence [--scene paper-sequence-100] [-k 10]
"""


EPS_A, DELTA_C = 1e-3, 5e-3  # agent.core.params defaults


def sequence_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted sequence", SEQUENCE_DOC)
    parser.add_argument("--scene", default="paper-sequence-100")
    parser.add_argument("-k", type=int, default=10, help="robots per agent process")
    args = parser.parse_args(argv)
    ran = run_cli_scene([args.scene, "-k", str(args.k)])
    if ran is None:
        return 1
    m, traj, wall = ran
    rep = agreements(traj)
    complete = [a for a in rep.agreements if np.isfinite(a.cost)]
    beyond = [a for a in complete if a.cost > a.optimum + len(a.members) * (EPS_A + DELTA_C) + a.penalties + 1e-6]
    gaps = rep.gaps()
    ok_steps = all(s["converged_at"] is not None and s["max_goal_error_at_end"] <= 0.01 for s in m["steps"])
    passed = m["contacts"] == 0 and ok_steps and not beyond and rep.inconsistent == 0 and rep.shared_goals == 0
    rows = steps_table(m)
    notes = [
        "",
        f"Scene `{args.scene}`, {m['robots']} robots, {args.k} per agent process; wall {wall:.0f} s for "
        f"{m['duration_s']:.0f} s of display time; contacts {m['contacts']}; min clearance "
        f"{m['min_clearance_m'] * 1e3:.1f} mm.",
        f"Agreements: {len(complete)} complete, {len(beyond)} beyond N (eps_A + Delta C) + penalties, "
        f"{np.mean(gaps <= 1e-9) * 100:.1f} % equal to scipy's optimum, largest gap {np.max(gaps):.4f} m^2; "
        f"a robot announcing two goals for one instance: {rep.inconsistent}; two robots on one goal: "
        f"{rep.shared_goals}.",
        f"Acceptance (issue 5): {'PASS' if passed else 'FAIL'}.",
    ]
    write_results(
        "sequence",
        "The paper's sequence with 100 robots, distributed in agent hosts (issue 5)",
        f".venv/bin/python -m bench.bench_hosted sequence --scene {args.scene} -k {args.k}",
        rows + notes,
    )
    return 0 if passed else 1


# --- the 100-robot leaf against issue 6's acceptance (animation) ------------------------------
ANIMATION_DOC = """An animation with 100 robots in agent hosts, distributed (issue 6's acceptance): zero contacts,
and robots reach each keyframe's goals within its frame time when the speed allows. On each
keyframe the robots drive on at once to the goal their last one corresponds to (carried by the
goals' correspondence, coordinator.keyframes.goal_correspondence), while the auction agrees on the
new goal set (agent.core.bidder.Participant.carry).

Reported per keyframe: K_f dt, how long after the keyframe began the hosts first agreed, how many
robots' moves the speed allowed and their worst and mean distance to the goal when K_f dt was
over. Too long for the test suite (minutes on 2 cores); the suite plays four keyframes with 14
robots (tests/unit/test_animation.py).

    .venv/bin/python -m bench.bench_hosted animation [--scene leaf] [-k 10]
    .venv/bin/python -m bench.bench_hosted animation --from RUN_DIR   # a finished `pixelswarm run leaf --engine distributed -k 10`
"""


WITHIN = 0.03  # m: "reached" (tracking noise, actuation noise and ORCA's yielding on the way)


def first_agreement(traj: dict, step: int, start: float) -> float | None:
    """Seconds from the keyframe's start to the first sample with an agreed (not carried) goal of it."""
    epochs = [int(e) for e, s in zip(traj["goal_set_epochs"], traj["goal_set_steps"]) if int(s) == step]
    if not epochs:
        return None
    agreed = (traj["assignment_epoch"] == epochs[-1]) & (traj["assignment_instance"] != State.CARRIED)
    rows = np.flatnonzero(agreed.any(axis=1))
    return float(traj["t"][rows[0]] - start) if len(rows) else None


def animation_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted animation", ANIMATION_DOC)
    parser.add_argument("--scene", default="leaf")
    parser.add_argument("-k", type=int, default=10, help="robots per agent process")
    parser.add_argument(
        "--from", dest="run", type=Path, help="summarise this finished run of the scene instead of running it"
    )
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    args_run = [args.scene, "--engine", "distributed", "-k", str(args.k)]
    ran = load_run(args.run) if args.run else run_cli_scene(args_run)
    if ran is None:
        return 2 if args.run else 1
    m, traj, wall = ran
    periods = [s.frame_period for s in scene.steps]
    per_frame = keyframe_errors(traj, scene.step_starts, periods, RobotParams.from_dict(scene.robot).v_max)
    rows = [
        "| keyframe | K_f dt s | first agreement s after its start | moves the speed allows | "
        "worst mm | mean mm | within 3 cm |",
        "|---|---|---|---|---|---|---|",
    ]
    reached = allowed = 0
    for f, (errors, period) in enumerate(zip(per_frame, periods)):
        ok = errors[np.isfinite(errors)]
        agreed = first_agreement(traj, f, scene.step_starts[f])
        allowed += len(ok)
        reached += int((ok <= WITHIN).sum())
        rows.append(
            f"| {f} | {period:.1f} | {'never' if agreed is None else f'{agreed:.1f}'} | {len(ok)} | "
            f"{1e3 * ok.max():.1f} | {1e3 * ok.mean():.1f} | {int((ok <= WITHIN).sum())} |"
            if len(ok)
            else f"| {f} | {period:.1f} | {agreed} | 0 | | | |"
        )
    passed = m["contacts"] == 0 and allowed > 0 and reached == allowed
    notes = [
        "",
        f"Scene `{args.scene}`, {m['robots']} robots, {args.k} per agent process ({m['clock']}); wall "
        f"{wall:.0f} s for {m['duration_s']:.0f} s of display time (realtime factor "
        f"{m['duration_s'] / wall:.2f}); contacts {m['contacts']}; min clearance "
        f"{m['min_clearance_m'] * 1e3:.1f} mm; ORCA fallbacks {m.get('orca_fallbacks')}.",
        f"Robots within {WITHIN * 100:.0f} cm of their goal when K_f dt was over, of those whose move the "
        f"speed allowed: {reached} of {allowed}.",
        f"Acceptance (issue 6, animation, distributed): {'PASS' if passed else 'FAIL'}.",
    ]
    write_results(
        "animation",
        f"Animation `{args.scene}` with {m['robots']} robots, distributed in agent hosts",
        " ".join([".venv/bin/python -m sim.cli run", *args_run, "--no-video"]),
        rows + notes,
    )
    return 0 if passed else 1


# --- lock-step engines beside the code before (sync) ------------------------------------------
SYNC_DOC = """What the tick-synchronous auction (issue 21, docs/lockstep_auction.md) costs a lock-step run of a
picture, side by side with the code before it: per engine (a process per robot, agent hosts of 5),
runs of the same seed alternate between a checkout of the code before (``--before DIR``, e.g. made
with `git worktree add DIR COMMIT`) and this one; each reports the wall time per tick, whether it
is the central engine's run (poses to 1e-9 m and assignments, as `beside`), and the recorded ticks
where two robots drive to one goal.

    python -m bench.bench_hosted sync --before ../pixelswarm-before --robots 30 --pairs 2
"""


ENGINES = {"central": ["--engine", "central"], "a process per robot": [], "hosts of 5": ["-k", "5"]}


def picture(folder: Path) -> Path:
    """The test picture (tests/support/engines.py: picture): a disk and a bar."""
    import cv2

    image = np.full((120, 160, 3), 255, np.uint8)
    cv2.circle(image, (55, 60), 35, (0, 0, 200), -1)
    cv2.rectangle(image, (100, 25), (145, 95), (200, 0, 0), -1)
    path = folder / "picture.png"
    cv2.imwrite(str(path), image)
    return path


def run_in_tree(code: Path, args: list[str], out: Path, arrays: bool = True) -> tuple[dict, dict]:
    """`pixelswarm run` with the code of ``code`` (its folder first on the import path): its metrics,
    and (``arrays``) its trajectory.npz loaded."""
    cmd = [sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"]
    proc = subprocess.run(cmd, cwd=code, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"run failed ({code}): {proc.stderr[-2000:]}")
    return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz")) if arrays else {}


def shared_ticks(traj: dict) -> int:
    """Recorded ticks where two robots hold one goal."""
    return sum(len(np.unique(row[row >= 0])) != int((row >= 0).sum()) for row in traj["assignment"])


def sync_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted sync", SYNC_DOC)
    parser.add_argument("--before", required=True, type=Path, help="a checkout of the code before")
    parser.add_argument("--robots", type=int, default=30)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--pairs", type=int, default=1)
    parser.add_argument("--results", default="sync", help="name of the results file in bench/results")
    opt = parser.parse_args(argv)
    if not (opt.before / "sim" / "cli").exists() and not (opt.before / "sim" / "cli.py").exists():
        print(f"error: {opt.before} is not a checkout of pixelswarm (no sim/cli)", file=sys.stderr)
        return 2
    rows = [
        "| engine | pair | code | wall s per tick | ticks | = central (poses to 1e-9 m, assignment) | ticks with a shared goal |",
        "|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        image = picture(Path(tmp))
        args = [str(image), "--robots", str(opt.robots), "--clock", "lockstep", "--seed", str(opt.seed)]
        codes = {"before": opt.before.resolve(), "now": REPO}
        for name, code in codes.items():
            run_in_tree(code, args + ENGINES["central"], Path(tmp) / f"central-{name}", arrays=False)
        for engine, flags in ENGINES.items():
            if engine == "central":
                continue
            for pair in range(opt.pairs):
                order = list(codes) if pair % 2 == 0 else list(reversed(codes))
                for name in order:
                    out = Path(tmp) / f"{engine}-{pair}-{name}".replace(" ", "-")
                    m, traj = run_in_tree(codes[name], args + flags, out)
                    same = parted_at(out / "trajectory.npz", Path(tmp) / f"central-{name}" / "trajectory.npz")
                    per_tick = m["stepping_wall_s"] / max(m["samples"] - 1, 1)
                    rows.append(
                        f"| {engine} | {pair + 1} | {name} | {per_tick:.3f} | {len(traj['t'])} | {same} | {shared_ticks(traj)} |"
                    )
                    print(rows[-1], flush=True)
    command = "python -m bench.bench_hosted sync " + " ".join(argv if argv is not None else sys.argv[1:])
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


# --- loading a scene at start-up (scenes) -----------------------------------------------------
SCENES_DOC = """Benchmark of loading a scene in a distributed run: each child running the image pipeline (before)
against each child reading the resolved scene from the run directory (now), side by side in one run.

- CPU seconds a fresh world / coordinator process spends from its start until it holds the scene
  (interpreter, imports and loading; user + system time of the process), median of --repeat;
- wall seconds from `pixelswarm run SCENE --clock lockstep` to its first tick's progress line.

Both load paths live in this tree (``load_scene``: parse + image pipeline, what each child did; and
``load_resolved``: what each child does now). ``--before DIR`` (a checkout of the code before the
change, e.g. `git archive <commit> | tar -x -C DIR`) also times that tree's own children and start-up.

    .venv/bin/python -m bench.bench_hosted scenes                     # writes bench/results/scenes.md
    .venv/bin/python -m bench.bench_hosted scenes --before /tmp/old --repeat 3
"""


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
CHILDREN = {"world": "sim.node.world", "coordinator": "coordinator.service"}


def child_load(tree: Path, module: str, load: str) -> dict:
    code = CHILD.format(module=module, load=load)
    out = subprocess.run([sys.executable, "-c", code], cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def seconds_to_first_tick(tree: Path, scene: str, out: Path) -> float | None:
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


def median_or_dash(values: list[float]) -> str:
    return f"{statistics.median(values):.2f}" if values else "-"


def scenes_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted scenes", SCENES_DOC)
    parser.add_argument("--scene", nargs="+", default=["paper-sequence"], help="scenes to time (start-up: the first)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--before", type=Path, help="a checkout of the code before the change, to time too")
    parser.add_argument("--no-startup", dest="startup", action="store_false", help="skip the start-up runs")
    args = parser.parse_args(argv)
    if args.before is not None and not any((args.before / "sim" / p).exists() for p in ("cli", "cli.py")):
        print(f"error: {args.before} is not a pixelswarm checkout (no sim/cli)", file=sys.stderr)
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
                    startup.setdefault(name, []).append(seconds_to_first_tick(tree, args.scene[0], out))

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
            f"| {label} | {way} | {child} | {median_or_dash([s['cpu'] for s in samples])} | "
            f"{median_or_dash([s['wall'] for s in samples])} | "
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
    command = "python -m bench.bench_hosted scenes " + " ".join(argv if argv is not None else sys.argv[1:])
    write_results("scenes", "Loading a scene: per child, or once per run", command.strip(), lines)
    return 0


# --- distributed runs beside the central engine's (beside, processes) -----------------------------
BESIDE_DOC = """A distributed run beside the central engine's run of the same flags: `pixelswarm run SCENE
[flags]` with `--engine central`, then as given (flags that run the distributed engine) --repeat
times. Per run: the stepping realtime factor (display seconds over wall seconds between the first and
last recorded tick), contacts, missed ticks, when each image formed, and whether the trajectories are
the central engine's: poses to 1e-9 m and the assignment at every recorded tick, or the first display
time where they part. Written to bench/results/<--results>.md.

    python -m bench.bench_hosted beside paper-sequence-10000 --engine distributed -k 1000 --clock lockstep \
        --rounds-per-tick 1 --duration 247.5
"""
BESIDE_HEADER = [
    "| scene | robots | run | code | stepping realtime factor | wall s | CPU s | contacts | missed ticks | images formed, s after each began | = central (poses to 1e-9 m, assignment) |",
    "|---|---|---|---|---|---|---|---|---|---|---|",
]


def formed(m: dict) -> str:
    """When each image step of a run formed (every robot within 1 cm: metrics' converged_at), '-' for
    one that did not; '' for a scene of no image steps."""
    return ", ".join("-" if s["converged_at"] is None else f"{s['converged_at']:.1f}" for s in m.get("steps", []))


def parted_at(traj: Path, central: Path) -> str:
    """'yes' if two runs' trajectory.npz hold the same ticks, poses to 1e-9 m and assignments; else
    the display time from which they part (read key by key: a 10,000-robot run's arrays are large)."""
    with np.load(traj) as a, np.load(central) as b:
        t, n = a["t"], min(len(a["t"]), len(b["t"]))
        apart = np.abs(a["pose"][:n, :, :2] - b["pose"][:n, :, :2]).max(axis=(1, 2)) > 1e-9
        if "goal_set_epochs" in b.files:  # scenes of per-robot goals: the central engine records each its own
            apart |= (a["assignment"][:n] != b["assignment"][:n]).any(axis=1)
        if not apart.any():
            return "yes" if len(a["t"]) == len(b["t"]) else f"no: {len(a['t'])} ticks, central {len(b['t'])}"
        return f"no: from t = {t[int(np.argmax(apart))]:.1f} s"


def beside_central(name: str, args: list[str], out: Path, repeat: int, before: Path | None = None) -> list[str]:
    """The rows of BESIDE_HEADER: ``args`` run --repeat times beside the central engine's run of them;
    with ``before`` (a checkout of the code before), each time by both codes, in alternating order.
    CPU s: of every process of the run (the launcher waits for each)."""
    run_in_tree(REPO, [*args, "--engine", "central"], out / f"{name}-central", arrays=False)
    codes = {"now": REPO} | ({"before": before.resolve()} if before is not None else {})
    rows = []
    for k in range(repeat):
        for code in list(codes) if k % 2 == 0 else list(reversed(codes)):
            run = out / f"{name}-{k}-{code}"
            cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
            m, _ = run_in_tree(codes[code], args, run, arrays=False)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu_s = after.ru_utime + after.ru_stime - cpu.ru_utime - cpu.ru_stime
            if m["engine"] != "distributed":
                raise ValueError(f"{name} ran in the {m['engine']} engine: give --engine distributed")
            same = parted_at(run / "trajectory.npz", out / f"{name}-central" / "trajectory.npz")
            rows.append(
                f"| {name} | {m['robots']} | {k + 1} | {code} | {m['stepping_realtime_factor']:.2f} | {m['wall_s']:.1f} | "
                f"{cpu_s:.1f} | {m['contacts']} | {m['missed_ticks']} | {formed(m)} | {same} |"
            )
            print(rows[-1], flush=True)
    return rows


def beside_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted beside", BESIDE_DOC)
    parser.add_argument("scene", help="a scene, picture or folder, as `pixelswarm run` takes it")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--results", default="beside", help="bench/results/<name>.md (default beside)")
    opt, flags = parser.parse_known_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            rows = beside_central(Path(opt.scene).name, [opt.scene, *flags, "--no-plots"], Path(tmp), opt.repeat)
        except ValueError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    command = "python -m bench.bench_hosted beside " + " ".join(argv if argv is not None else sys.argv[1:])
    write_results(opt.results, "A distributed run beside the central engine", command.strip(), BESIDE_HEADER + rows)
    return 0


PROCESSES_DOC = """Issue 43's robot-per-process rows (as `beside`): a lock-step run with an agent process per robot
beside the central engine's run of the same flags, --repeat times. Two scenes: `circle` with --circle
robots for --duration s, and an animation of four keyframes (a disk crossing a bar, drawn into a
temporary folder) with --animation robots, whole: 30 s to form the first keyframe, then 5 s per keyframe.

    python -m bench.bench_hosted processes [--circle 100] [--animation 40] [--duration 20] [--repeat 2] [--before DIR]

``--before DIR``: each run also by a checkout of the code before (`git worktree add DIR COMMIT`, its
compiled core built or copied in), alternating; ``--circle 0`` or ``--animation 0`` leaves a scene out.
"""


def keyframes(folder: Path, count: int = 4) -> Path:
    """``count`` PNGs of a disk moving across a fixed bar, in ``folder``/frames."""
    import cv2

    frames = folder / "frames"
    frames.mkdir()
    for i in range(count):
        image = np.full((120, 160, 3), 255, np.uint8)
        cv2.circle(image, (35 + 30 * i, 60), 28, (0, 0, 200), -1)
        cv2.rectangle(image, (70, 10), (90, 110), (200, 0, 0), -1)
        cv2.imwrite(str(frames / f"frame{i}.png"), image)
    return frames


def processes_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_hosted processes", PROCESSES_DOC)
    parser.add_argument("--circle", type=int, default=100, help="robots (and agent processes) on the circle")
    parser.add_argument("--animation", type=int, default=40, help="robots (and agent processes) of the animation")
    parser.add_argument("--duration", type=float, default=20.0, help="s of display of the circle")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--before", type=Path, help="a checkout of the code before, run beside this one")
    opt = parser.parse_args(argv)
    if opt.before is not None and not (opt.before / "sim" / "cli").exists():
        print(f"error: {opt.before} is not a checkout of pixelswarm (no sim/cli)", file=sys.stderr)
        return 2
    rows = list(BESIDE_HEADER)
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {}  # a count of 0 leaves its scene out
        if opt.circle:
            scenes["circle"] = ["circle", "--robots", str(opt.circle), "--duration", f"{opt.duration:g}"]
        if opt.animation:
            scenes["animation"] = [str(keyframes(Path(tmp))), "--robots", str(opt.animation)]
        for name, scene in scenes.items():
            args = [*scene, "--clock", "lockstep", "--seed", str(opt.seed), "--no-plots"]
            rows += beside_central(name, args, Path(tmp), opt.repeat, opt.before)
    command = "python -m bench.bench_hosted processes " + " ".join(argv if argv is not None else sys.argv[1:])
    write_results("processes", "A robot per process in lock-step, beside the central engine", command.strip(), rows)
    return 0


COMMANDS = {
    "beside": beside_main,
    "processes": processes_main,
    "hosted": hosted_main,
    "sequence": sequence_main,
    "animation": animation_main,
    "sync": sync_main,
    "scenes": scenes_main,
}


if __name__ == "__main__":
    sys.exit(run_subcommand("bench.bench_hosted", COMMANDS, "hosted"))
