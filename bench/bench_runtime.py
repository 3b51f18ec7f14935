"""Runtime benchmark (issues 2 and 25): agent processes at 10 Hz beside their floor, in one run.

For each N: N agent processes of `pixelswarm run circle` in real time, then N bare zenoh processes doing
a robot's messages per tick and nothing else (bench.floor_node: the floor), standing so that each hears
nearly as many states per tick as an agent did; per process CPU, RSS and USS, the states heard per tick,
the real-time factor, missed ticks, contacts and start-up; then the circle with every command delayed
0.15 s (``--faults cmd:delay=0.15``) at 20 processes (the least of ``--sizes``), and (without --quick or
--sizes) the lock-step rows and 1000 robots in 4 hosts. Each row waits for a quiet machine and writes
how busy it was beside it: on a shared machine the figures are only as good as it was quiet. ``--repeat
K`` runs the agents K times at each N (missed ticks vary from run to run), each run followed by a floor
of its own (one thread), against which its CPU is set.

``--startup``: only the start-up of 50 agent processes, from launching `pixelswarm run` to the
world's first tick, the code at ``--before REV`` beside the code at ``--after REV`` (each a fresh
git worktree), alternating; the first run in each fresh tree (no bytecode, no JIT cache yet) is
reported apart. Written as the "Start-up" section of runtime.md, the rest kept.

    .venv/bin/python -m bench.bench_runtime [--quick] [--sizes 20,50,100] [--duration 20] [--repeat 1]
    .venv/bin/python -m bench.bench_runtime --startup [--before 7ff7048^] [--after HEAD] [--pairs 3]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import psutil

from agent.runtime import interpreter
from coordinator.scene import load_scene
from sim.bodies.tracker import world_of
from transport.bus import Bus
from transport.codec import Command, Commands, State, States
from transport.keys import Keys, cell_of, cells_of
from transport.session import client_of, loopback_router

from .common import REPO, RESULTS, first_tick, last_tick, machine, run_and_sample, stepping_cpu, write_results

REACH = 2  # cells on each side of a robot's own it hears: the agent's 5 x 5 in real time
WARM_UP = 3.0  # s of ticks before the floor is measured (subscriptions travel, processes settle)
DELAYED = "cmd:delay=0.15"  # every command a tick and a half late: bodies must stop, never touch
DELAYED_AT = 20
STARTUP_BEFORE = "7ff7048^"  # the code before issue 25's work
STARTUP_HEADING = "## Start-up"


QUIET = 10.0  # % of the machine's CPU busy, over a second, below which a row may start
QUIET_WAIT = 60.0  # s a row waits for that at most


def load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def settle() -> str:
    """Wait (at most QUIET_WAIT s) until less than QUIET % of the machine's CPU was busy over a
    second, so that a row does not pay for the one before it (its processes exiting): the load
    average lags a minute behind. Returns that second's busy share and the load average."""
    deadline = time.monotonic() + QUIET_WAIT
    while True:
        busy = psutil.cpu_percent(interval=1.0)
        if busy < QUIET or time.monotonic() >= deadline:
            return f"{busy:.0f} ({load()})"


def heard_per_tick(xy: np.ndarray, cell_size: float, reach: int = REACH) -> float:
    """States a floor process at these positions hears per tick (the median, as reported): those put in the
    (2 reach + 1)^2 cells around its own, its own included, as bench.floor_node (and an agent)
    subscribes."""
    cells = cells_of(xy, cell_size)
    near = (np.abs(cells[:, None, :] - cells[None, :, :]) <= reach).all(axis=2)
    return float(np.median(near.sum(axis=1)))


def drawn_together(xy: np.ndarray, cell_size: float, heard: float) -> np.ndarray:
    """The positions drawn towards their centre until a floor process hears nearly ``heard`` states
    per tick, never more (a floor that hears more costs more, and flatters the agent): the agents'
    robots cross the circle's crowded middle and hear more than robots standing at its start, and
    the floor must take in as many as an agent does."""
    centre = xy.mean(axis=0)
    if not np.isfinite(heard) or heard_per_tick(xy, cell_size) >= heard:
        return xy
    low, high = 0.0, 1.0  # scale: at ``low`` everyone hears everyone
    for _ in range(30):
        mid = (low + high) / 2
        if heard_per_tick(centre + (xy - centre) * mid, cell_size) >= heard:
            low = mid
        else:
            high = mid
    return centre + (xy - centre) * high


def cpu_seconds(process: psutil.Process) -> float:
    """User and system CPU seconds so far: psutil's cpu_percent rounds to 0.1 %, a tenth of a floor."""
    times = process.cpu_times()
    return times.user + times.system


def floor_args(robot: int, x: float, y: float, cell_size: float, keys: Keys) -> list[str]:
    """bench.floor_node's arguments for a robot standing at (x, y): the keys an agent there hears and
    puts to, and the state and command it puts, encoded here so that the floor imports no numpy."""
    cx, cy = cell_of(x, y, cell_size)
    state = States.one(State(robot, 0, 0.0, x, y, 0.0, 0.0, 0.037, 0.0, 0.0, -1, 0, 0, 0)).encode()
    command = Commands.one(Command(robot, 0, 0.0, Command.HOLONOMIC, 0.0, 0.0, 40, 40, 40)).encode()
    hear = [keys.state_cell((cx + dx, cy + dy)) for dx in range(-REACH, REACH + 1) for dy in range(-REACH, REACH + 1)]
    return [
        *("--pose-key", keys.pose(robot), "--state-key", keys.state((cx, cy), robot), "--cmd-key", keys.cmd(robot)),
        *(arg for key in hear for arg in ("--hear", key)),
        *("--state", state.hex(), "--command", command.hex()),
    ]


def floor_row(
    n: int, duration: float, callbacks: str = "direct", heard: float = float("nan"), with_numpy: bool = False
) -> dict:
    """N floor processes, clocked at 10 Hz from here as the world clocks agents: the cost of a
    robot's messages alone. ``heard``: the states per tick an agent heard; the floor processes
    stand closer together until they hear as many (drawn_together). ``with_numpy``: each imports
    numpy too, which it does not use. Returns CPU (% of a core, each process's mean over the
    measured window), RSS and USS (MB), and the share of ticks answered."""
    scene = load_scene("circle", robots=n, seed=3, clock="realtime")
    params, _ = world_of(scene)
    at = drawn_together(np.asarray(scene.poses)[:, :2], params.cell_size, heard)
    router, keys = loopback_router(), Keys()
    procs: list[subprocess.Popen] = []
    with Bus(router, name="floor-clock") as bus:
        cmds = bus.commands_inbox()
        try:
            for i, (x, y) in enumerate(at):
                procs.append(
                    subprocess.Popen(
                        [*interpreter(1), "-m", "bench.floor_node", *floor_args(i, x, y, params.cell_size, keys)]
                        + ["--duration", str(duration + WARM_UP + 30), "--callbacks", callbacks]
                        + (["--numpy"] if with_numpy else [])
                        + client_of(router).to_args(),
                        cwd=REPO,
                        stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE,
                        text=True,
                    )
                )
            for p in procs:  # each says ready once subscribed
                if p.stdout is None or p.stdout.readline().strip() != "ready":
                    raise RuntimeError(f"a floor process failed: {p.communicate()[1][-500:]}")
            watched = [psutil.Process(p.pid) for p in procs]
            ticks = round((duration + WARM_UP) / params.dt)
            start = next_tick = time.monotonic()
            answered, busy, since = 0, [0.0] * n, start
            for tick in range(ticks):
                if tick == round(WARM_UP / params.dt):  # the measured window starts
                    busy, since = [cpu_seconds(w) for w in watched], time.monotonic()
                    answered = 0
                poses = np.column_stack([at, np.zeros(n)])
                bus.publish_poses(tick, tick * params.dt, np.arange(n), poses, frame=False)
                next_tick += params.dt
                time.sleep(max(0.0, next_tick - time.monotonic()))
                answered += len(cmds.drain())
            wall = time.monotonic() - start
            cpu = [100 * (cpu_seconds(w) - b) / (time.monotonic() - since) for w, b in zip(watched, busy)]
            memory = [w.memory_full_info() for w in watched]
        finally:
            for p in procs:
                p.send_signal(signal.SIGTERM)
            outputs = [p.communicate(timeout=30)[0] for p in procs]
    states = [json.loads(o.strip().splitlines()[-1])["states_received"] for o in outputs if o.strip()]
    return {
        "cpu": float(np.median(cpu)),
        "rss": float(np.median([m.rss for m in memory])) / 2**20,
        "uss": float(np.median([m.uss for m in memory])) / 2**20,
        "answered": answered / (n * round(duration / params.dt)),
        "rtf": ticks * params.dt / wall,
        "states_per_tick": float(np.median(states)) / ticks if states else float("nan"),
    }


def floor_line(n: int, what: str, load_before: str, f: dict) -> str:
    """A table row of floor_row's figures."""
    return (
        f"| {n} | {what} | {load_before} | {f['rtf']:.2f} | {100 * (1 - f['answered']):.2f}% unanswered | "
        f"- | {f['cpu']:.2f} | 1 | {f['states_per_tick']:.1f} | {f['rss']:.1f} | {f['uss']:.1f} | - |"
    )


def agent_line(n: int, what: str, load_before: str, a: dict, x_floor: str = "-") -> str:
    """A table row of agent_row's figures."""
    return (
        f"| {n} | {what} | {load_before} | {a['rtf']:.2f} | {a['missed']} ({100 * a['missed_share']:.2f}%) | "
        f"{a['contacts']} ({a['overlap']:.3f}) | {a['cpu']:.2f} | {x_floor} | {a['states_per_tick']:.1f} | "
        f"{a['rss']:.1f} | {a['uss']:.1f} | {a['start_and_stop']:.1f} |"
    )


def agent_row(n: int, duration: float, clock: str = "realtime", faults: str = "") -> dict:
    args = ["circle", "--robots", str(n), "--clock", clock, "--duration", str(duration), "--seed", "3"]
    m, samples = run_and_sample(args + (["--faults", faults] if faults else []), agents=n)
    ticks = max(m["samples"] - 1, 1) * n  # robot-ticks the world stepped
    per_process: dict[int, list[dict]] = {}
    for s in samples:  # each process's memory readings (an exiting process reports none)
        if s["rss"]:
            per_process.setdefault(s["pid"], []).append(s)
    # The stepping alone, its first second left out (the first goal set's auction): the CPU an
    # agent costs at 10 Hz, as the floor's is measured after its warm-up.
    start = m["first_tick_wall"] + WARM_UP
    cpu = stepping_cpu(samples, start, start + m["stepping_wall_s"] - WARM_UP)
    return {
        "cpu": float(np.median(cpu)) if cpu else float("nan"),
        "rss": float(np.median([np.median([s["rss"] for s in ss]) for ss in per_process.values()])) / 2**20,
        "uss": float(np.median([np.median([s["uss"] for s in ss]) for ss in per_process.values()])) / 2**20,
        "rtf": m["stepping_realtime_factor"] or 0.0,
        "missed": m["missed_ticks"],
        "missed_share": m["missed_ticks"] / ticks,
        "contacts": m["contacts"],
        "overlap": m["max_overlap_m"],
        "stopped": m["stopped_ticks"],
        "start_and_stop": m["wall_s"] - m["stepping_wall_s"],
        "converged": m["converged"],
        # messages of neighbours' states an agent took in per tick (nan: code that does not report it)
        "states_per_tick": float(
            np.median(
                [s["states_heard"] / s["ticks"] for s in m["agent_stats"] if s.get("ticks") and "states_heard" in s]
            )
            if any("states_heard" in s for s in m["agent_stats"])
            else float("nan")
        ),
    }


def startup_run(tree: Path, robots: int) -> dict:
    """`sim.cli run circle` from ``tree``: wall seconds from its launch to the coordinator alive,
    the world alive, the last agent alive and the world's first tick; and from its last tick to its exit."""
    args = ["circle", "--robots", str(robots), "--clock", "realtime", "--duration", "5", "--seed", "3"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        load_before = load()
        launched = time.time()
        proc = subprocess.run(
            [sys.executable, "-m", "sim.cli", "run", *args, "--no-video", "-q", "--out", str(out)],
            cwd=tree,
            capture_output=True,
            text=True,
        )
        exited = time.time()
        if proc.returncode != 0:
            raise RuntimeError(f"run from {tree} failed: {proc.stderr[-2000:]}")
        walls = first_tick(out / "log.mcap")
        shutdown = exited - last_tick(out / "log.mcap")
        end = json.loads((out / "metrics.json").read_text())["end_reason"]
    return {"load": load_before, "end": end, "shutdown": shutdown} | {k: wall - launched for k, wall in walls.items()}


def clear_caches(tree: Path, suffixes: set[str]) -> None:
    """Delete the files of these suffixes in the tree's __pycache__ folders (.pyc: bytecode;
    .nbi/.nbc: the on-disk cache of numba, which revisions before the compiled core used)."""
    for f in tree.rglob("__pycache__/*"):
        if f.suffix in suffixes:
            f.unlink()


def worktree(rev: str, where: Path, build: bool = True) -> str:
    """A fresh detached git worktree of ``rev`` at ``where``, its compiled core built (where it has
    one: setup.py, and unless ``build`` is false: the goal pipeline needs none); its short commit.
    Its code, not this checkout's, is what runs from it (the children start from the launcher's
    folder)."""
    subprocess.run(["git", "worktree", "add", "--detach", str(where), rev], cwd=REPO, check=True, capture_output=True)
    if build and (where / "setup.py").exists():
        build = [sys.executable, "setup.py", "build_ext", "--inplace", "-q"]
        subprocess.run(build, cwd=where, check=True, capture_output=True)
    found = subprocess.run(
        [sys.executable, "-B", "-c", "import agent, sim; print(agent.__file__, sim.__file__)"],
        cwd=where,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    if not all(Path(f).is_relative_to(where) for f in found):
        raise RuntimeError(f"code from {where} imports {found}, not its own")
    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=where, check=True, capture_output=True, text=True
    ).stdout.strip()


@contextlib.contextmanager
def worktree_at(rev: str, build: bool = True) -> Iterator[tuple[Path, str]]:
    """`worktree` of ``rev`` in a temporary folder, removed afterwards: (its folder, its short commit)."""
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(tmp) / "tree"
        try:
            yield where, worktree(rev, where, build)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(where)], cwd=REPO, capture_output=True)
            subprocess.run(["git", "worktree", "prune"], cwd=REPO, capture_output=True)


# After the alternating runs, one run of each tree without one of its on-disk caches.
NO_CACHE = [("no JIT cache (bytecode kept)", {".nbi", ".nbc"}), ("no bytecode (JIT cache kept)", {".pyc"})]


def startup(before: str, after: str, pairs: int, robots: int) -> list[str]:
    """Start-up of ``robots`` agent processes, the code at ``before`` beside the code at ``after``:
    the first run of each fresh worktree, ``pairs`` runs each alternating, then a run without each
    of the on-disk caches."""
    warm: dict[str, list[float]] = {"before": [], "after": []}
    shutdown: dict[str, list[float]] = {"before": [], "after": []}
    first: dict[str, float] = {}
    commits: dict[str, str] = {}
    rows = [
        "| run | code | load avg | coordinator alive s | world alive s | last agent alive s | first tick s "
        "| last tick to exit s | end |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    schedule = [("first in a fresh tree", set())] + [(str(k), set()) for k in range(1, pairs + 1)] + NO_CACHE
    with contextlib.ExitStack() as stack:
        trees: dict[str, Path] = {}
        for what, rev in (("before", before), ("after", after)):
            trees[what], commits[what] = stack.enter_context(worktree_at(rev))
        for name, cleared in schedule:
            for what, tree in trees.items():
                clear_caches(tree, cleared)
                r = startup_run(tree, robots)
                if name.isdigit():
                    warm[what].append(r["tick"])
                    shutdown[what].append(r["shutdown"])
                elif not cleared:
                    first[what] = r["tick"]
                shown = {
                    k: "-" if r[k] != r[k] else f"{r[k]:.{2 if k == 'shutdown' else 1}f}"
                    for k in ("coordinator", "world", "agent", "tick", "shutdown")
                }
                rows.append(
                    f"| {name} | {commits[what]} ({what}) | {r['load']} | {shown['coordinator']} | {shown['world']} | "
                    f"{shown['agent']} | {shown['tick']} | {shown['shutdown']} | {r['end']} |"
                )
                print(rows[-1], flush=True)
    median = {what: float(np.nanmedian(ticks)) for what, ticks in warm.items()}  # nan: a run that never ticked
    ending = {what: float(np.nanmedian(seconds)) for what, seconds in shutdown.items()}
    return rows + [
        "",
        f"Median to the first tick over runs 1-{pairs}: {median['before']:.1f} s before ({commits['before']}), "
        f"{median['after']:.1f} s after ({commits['after']}); the first run in a fresh tree: "
        f"{first['before']:.1f} s before, {first['after']:.1f} s after. Median from the last tick to the "
        f"command's exit: {ending['before']:.2f} s before, {ending['after']:.2f} s after.",
        "",
        f"Scene: `pixelswarm run circle --robots {robots} --clock realtime --duration 5 --seed 3 --no-video -q`, "
        "a robot per agent process, run from a fresh git worktree of each revision (the same Python), before and "
        "after alternating. Seconds from launching the command to what the run's log (log.mcap, the launcher's "
        "recorder) heard: the coordinator alive, the world alive, the last agent alive, the world's first tick "
        "(its first truth message: the world ticks once every agent is alive, and an agent comes alive once it "
        "heard the world); and from the last tick it heard to the command's exit (stopping the processes and "
        "writing the run directory). A fresh tree's first run also writes the project's bytecode (__pycache__/*.pyc) and, "
        "in revisions before the compiled core, the world's numba cache (*.nbi, *.nbc); later runs read both. The last two runs "
        "of each tree go without one of them. '-': never reached (end: the run's end_reason). Load avg: the "
        "machine's 1-minute load before the run (a shared machine; it still counts the previous run's processes).",
    ]


def split_startup(text: str) -> tuple[str, str]:
    """runtime.md without its Start-up section, and that section ('' if none)."""
    head, heading, tail = text.partition("\n" + STARTUP_HEADING)
    if not heading:
        return text, ""
    cut = tail.find("\n## ")
    section = heading.lstrip("\n") + (tail if cut < 0 else tail[: cut + 1])
    return head + ("" if cut < 0 else tail[cut:]), section


def append_section(path: Path, section: str) -> None:
    path.write_text(path.read_text().rstrip("\n") + "\n\n" + section.rstrip("\n") + "\n")


def write_startup(command: str, lines: list[str]) -> None:
    """The Start-up section of runtime.md, in place of the old one; the rest of the file kept."""
    path = RESULTS / "runtime.md"
    others, _ = split_startup(path.read_text() if path.exists() else "")
    path.write_text(others)
    section = [
        f"{STARTUP_HEADING}: from `pixelswarm run` to the first tick (issue 25)",
        "",
        f"Command: `{command}`",
        f"Machine: {machine()}; measured {time.strftime('%Y-%m-%d', time.gmtime())}.",
        "",
        *lines,
    ]
    append_section(path, "\n".join(section))
    print("\n".join(section))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 20 only, no lock-step or hosted rows")
    parser.add_argument("--sizes", default="", help="comma-separated N (default 20,50,100; --quick: 20)")
    parser.add_argument("--duration", type=float, default=20.0, help="s of display per run")
    parser.add_argument("--repeat", type=int, default=1, help="agent runs at each N (missed ticks vary run to run)")
    parser.add_argument(
        "--startup",
        action="store_true",
        help="only the start-up to the first tick and the shutdown after the last, before/after",
    )
    parser.add_argument("--before", default=STARTUP_BEFORE, help="--startup: the git revision before")
    parser.add_argument("--after", default="HEAD", help="--startup: the git revision after")
    parser.add_argument("--pairs", type=int, default=3, help="--startup: before/after runs, alternating")
    parser.add_argument("--robots", type=int, default=50, help="--startup: agent processes")
    args = parser.parse_args()
    command = " ".join(["python -m bench.bench_runtime", *sys.argv[1:]])
    if args.startup:
        if args.pairs < 1 or args.robots < 1:
            print("bench_runtime: error: --pairs and --robots must be at least 1", file=sys.stderr)
            sys.exit(2)
        write_startup(command, startup(args.before, args.after, args.pairs, args.robots))
        return
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s] or ([20] if args.quick else [20, 50, 100])
        if min(sizes) < 1 or args.duration <= 0 or args.repeat < 1:
            raise ValueError
    except ValueError:
        print(
            "bench_runtime: error: --sizes takes whole numbers >= 1, --duration a positive number, --repeat >= 1",
            file=sys.stderr,
        )
        sys.exit(2)
    rows = [
        "| N | process | busy before % (load avg) | RTF | missed ticks (share) | contacts (max overlap m) | CPU per process "
        "(% of a core, median) | x floor | states heard per tick | RSS MB (median) | USS MB (median) | start + stop s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n in sizes:
        # Each agent run is followed by its own floor (one thread), which hears as many states per tick:
        # the floor moves with the machine as much as the agents do, so each run's x floor is a pair's.
        runs = []
        for _ in range(args.repeat):
            before = settle()
            a = agent_row(n, args.duration)
            before_floor = settle()
            runs.append((before, a, before_floor, floor_row(n, args.duration, "direct", a["states_per_tick"])))
        heard = float(np.median([a["states_per_tick"] for _, a, _, _ in runs]))
        for callbacks, with_numpy, what in [
            ("direct", True, "floor with numpy imported (unused)"),
            ("thread", False, "floor: bare zenoh, a thread per subscription"),
        ]:
            before = settle()
            rows.append(floor_line(n, what, before, floor_row(n, args.duration, callbacks, heard, with_numpy)))
            print(rows[-1], flush=True)
        for i, (before, a, before_floor, f) in enumerate(runs):
            run = "" if args.repeat == 1 else f", run {i + 1}"
            rows.append(floor_line(n, f"floor: one thread{run}", before_floor, f))
            rows.append(agent_line(n, f"agent{run}", before, a, f"{a['cpu'] / max(f['cpu'], 1e-9):.1f}"))
            print(*rows[-2:], sep="\n", flush=True)
    n = DELAYED_AT if not args.sizes else min(sizes)
    before = settle()
    d = agent_row(n, args.duration, faults=DELAYED)
    rows.append(agent_line(n, f"agent, `--faults {DELAYED}`", before, d))
    print(rows[-1], flush=True)
    extra: list[str] = []
    if not args.quick and not args.sizes:
        for n in sizes:
            before = settle()
            a = agent_row(n, args.duration, clock="lockstep")
            extra.append(agent_line(n, "agent, lock-step", before, a))
            print(extra[-1], flush=True)
        m, samples = run_and_sample(
            ["circle", "--robots", "1000", "--clock", "lockstep", "--duration", "10", "--agents-per-process", "250"],
            agents=4,
        )
        cpu = np.median([s["cpu"] for s in samples if s["cpu"] > 0] or [0])
        extra += [
            "",
            "| N | hosts (K per process) | clock | RTF | CPU per host (%) | RSS per host MB |",
            "|---|---|---|---|---|---|",
            f"| 1000 | 4 (K = 250) | lockstep | {m['stepping_realtime_factor']:.2f} | {cpu:.0f} | "
            f"{np.median([s['rss'] for s in samples if s['rss']]) / 2**20:.0f} |",
        ]
    path = RESULTS / "runtime.md"
    _, kept = split_startup(path.read_text() if path.exists() else "")  # --startup's section outlives a rerun
    write_results(
        "runtime",
        "Runtime: agent processes over zenoh beside the bare-zenoh floor (issues 2, 25)",
        command,
        rows
        + extra
        + [
            "",
            "Floor: bench.floor_node, a bare zenoh session per robot that per tick hears its pose and the states "
            "of its 5 x 5 cells and puts a state and a command, clocked at 10 Hz by this benchmark, run after the "
            "agents of the same N: its robots stand on the circle drawn towards its centre until each hears nearly "
            "as many states per tick as an agent did, never more (an agent's robots cross the crowded middle); its "
            "callbacks on a Python thread per subscription (zenoh-python's default) "
            "or on zenoh's receiving thread; it imports no numpy, and the row with numpy imported shows what numpy "
            "alone adds to a process's memory; CPU over the ticks after the first 3 s. Agent: "
            "`pixelswarm run circle --seed 3` in real time; CPU "
            "over the world's stepping after its first 3 s, from each process's CPU seconds. x floor: the agent's CPU "
            "over that of the floor (one thread) run right after it, hearing as many states per tick. RTF: "
            "simulated seconds per wall second while the world "
            "was stepping. Missed ticks: a live agent's command for tick k had not reached the world when tick k+1 "
            "began (a body without a valid command stops: agent.clocks.Lateness, docs/overload.md). Start + stop: "
            "the run's wall time less its stepping time (start-up to the first tick, and the shutdown). "
            "USS: memory unique to one process. States heard per tick: messages of neighbours' states a process "
            "took in per tick, its own included (median over processes). Busy before: the share of the machine's CPU "
            "busy over the second before the row, which waits (up to a minute) for it to fall below 10 %; the load "
            "average beside it lags a minute behind. CPU times: every process's every 0.5 s; memory: 4 processes' "
            "a round in turn, so that the sampling does not load the machine it measures.",
        ],
    )
    if kept:
        append_section(path, kept)


if __name__ == "__main__":
    main()
