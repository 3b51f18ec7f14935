"""Helpers for benchmarks: run the real command, sample its processes, write a results table."""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import psutil

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "bench" / "results"


def machine() -> str:
    return f"{platform.machine()}, {psutil.cpu_count()} cores, Python {platform.python_version()}"


def revision() -> str:
    """The commit the current code is, and whether the code differs from it (results files aside)."""
    git = ["git", "-C", str(REPO)]
    try:
        commit = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        changed = subprocess.run(
            [*git, "status", "--porcelain", "--untracked-files=no", "--", ".", ":!bench/results"],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "an unknown commit (not a git checkout)"
    return commit.stdout.strip() + (" with uncommitted changes" if changed.stdout.strip() else "")


TRUTH = "/sim/truth"  # the world's truth channel in a run's log.mcap


MEMORY_PER_ROUND = 4  # processes whose memory a round reads: smaps cost 0.5 ms a process, CPU times 0.03


def run_and_sample(args: list[str], period: float = 0.5, agents: int | None = None) -> tuple[dict, list[dict]]:
    """Run `pixelswarm run ...` and sample its agent processes' CPU and memory while it runs.

    Each sample: pid, wall time, CPU % since the last sample, cumulative CPU seconds, and memory
    (None in most: a round reads the memory of MEMORY_PER_ROUND processes in turn, since reading 100
    processes' smaps at once is a burst of 60 ms that makes agents late). ``agents``: how many
    agent processes to look for (none are looked for once that many are found). The metrics gain
    ``first_tick_wall``, the wall time of the world's first tick, so that a sampled window can be
    the stepping alone (``stepping_cpu``)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        samples: list[dict] = []
        tracked: dict[int, psutil.Process] = {}
        turn = 0  # the next process whose memory is read
        while proc.poll() is None:
            if agents is None or len(tracked) < agents:
                try:
                    children = psutil.Process(proc.pid).children(recursive=True)
                except psutil.Error:
                    children = []
                for child in children:  # a child not yet an agent may be one between fork and exec
                    try:
                        if child.pid not in tracked and "agent" in child.cmdline():
                            child.cpu_percent()  # start the CPU counter
                            tracked[child.pid] = child
                    except psutil.Error:
                        pass
            time.sleep(period)
            pids = list(tracked)
            read_memory = {pids[(turn + i) % len(pids)] for i in range(min(MEMORY_PER_ROUND, len(pids)))}
            turn += MEMORY_PER_ROUND
            for pid in pids:
                p = tracked[pid]
                try:
                    with p.oneshot():
                        cpu, times = p.cpu_percent(), p.cpu_times()
                        mem = p.memory_full_info() if pid in read_memory else None
                    samples.append(
                        {
                            "pid": pid,
                            "wall": time.time(),
                            "cpu": cpu,
                            "cpu_s": times.user + times.system,
                            "rss": mem.rss if mem else None,
                            "uss": mem.uss if mem else None,
                            "pss": getattr(mem, "pss", mem.uss) if mem else None,
                        }
                    )
                except psutil.Error:
                    tracked.pop(pid)
        stdout, stderr = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(f"run failed: {stderr[-2000:]}")
        metrics = json.loads((out / "metrics.json").read_text())
        metrics["first_tick_wall"] = first_tick(out / "log.mcap")["tick"]
        metrics["agent_stats"] = agent_stats(out / "log.mcap")
        return metrics, samples


def agent_stats(log: Path) -> list[dict]:
    """Each agent process's report at its end (its ``stats`` event in the run's log)."""
    from sim.outputs.mcaplog import read_mcap

    events = read_mcap(log, ["/event"]).get("/event", [])
    return [e for e in events if e.get("kind") == "stats" and e.get("role") == "agent"]


def stepping_cpu(samples: list[dict], start: float, end: float) -> list[float]:
    """Each process's CPU (% of a core) between wall times ``start`` and ``end``, from its cumulative
    CPU seconds at the first and last of its samples in that window (a 0.5 s sample's own CPU %
    counts whole 10 ms clock ticks: 2 % steps)."""
    per_process: dict[int, list[dict]] = {}
    for s in samples:
        if start <= s["wall"] <= end:
            per_process.setdefault(s["pid"], []).append(s)
    return [
        100 * (ss[-1]["cpu_s"] - ss[0]["cpu_s"]) / (ss[-1]["wall"] - ss[0]["wall"])
        for ss in per_process.values()
        if len(ss) >= 2 and ss[-1]["wall"] > ss[0]["wall"]
    ]


def first_tick(log: Path) -> dict[str, float]:
    """Wall times in a run's log, as the launcher's recorder heard them: the coordinator alive, the
    world alive, the last agent alive, and the world's first tick (its first truth message)."""
    from mcap.reader import make_reader

    seen = {"coordinator": float("nan"), "world": float("nan"), "agent": float("nan")}
    with open(log, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(topics=["/alive", TRUTH], log_time_order=True):
            wall = message.log_time / 1e9
            if channel.topic == TRUTH:
                return seen | {"tick": wall}
            e = json.loads(message.data)
            if e["alive"] and e["role"] in seen and (e["role"] == "agent" or seen[e["role"]] != seen[e["role"]]):
                seen[e["role"]] = wall  # the first coordinator and world, the last agent
    return seen | {"tick": float("nan")}  # the world never ticked


def last_tick(log: Path) -> float:
    """The wall time of the world's last tick in a run's log (its last truth message), as the launcher's
    recorder heard it (nan: it never ticked)."""
    from mcap.reader import make_reader

    last = float("nan")
    with open(log, "rb") as fh:
        for _, _, message in make_reader(fh).iter_messages(topics=[TRUTH]):
            last = message.log_time / 1e9 if last != last else max(last, message.log_time / 1e9)
    return last


def write_results(name: str, title: str, command: str, lines: list[str]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.md"
    text = [
        f"## {title}",
        "",
        f"Command: `{command}`",
        f"Machine: {machine()}; measured {time.strftime('%Y-%m-%d', time.gmtime())}, the current code at {revision()}.",
        "",
        *lines,
        "",
    ]
    path.write_text("\n".join(text))
    print("\n".join(text))
    return path


def load_run(run: Path) -> tuple[dict, dict, float] | None:
    """A finished distributed run directory as run_cli_scene returns it (its wall time from
    metrics.json), or None after a one-line error."""
    import numpy as np

    if not (run / "metrics.json").is_file() or not (run / "trajectory.npz").is_file():
        print(f"error: {run} is not a finished run directory (no metrics.json or trajectory.npz)", file=sys.stderr)
        return None
    m = json.loads((run / "metrics.json").read_text())
    if m.get("engine") != "distributed":
        print(f"error: {run} was run with the {m.get('engine')} engine, not the distributed one", file=sys.stderr)
        return None
    return m, dict(np.load(run / "trajectory.npz")), float(m["wall_s"])


def run_cli_scene(args: list[str]) -> tuple[dict, dict, float] | None:
    """`pixelswarm run ARGS --out TMP --no-video -q` in a child process: (metrics, trajectory
    arrays, wall seconds), or None after printing the run's error output."""
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        start = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "sim.cli", "run", *args, "--out", str(out), "--no-video", "-q"],
            cwd=REPO,
            capture_output=True,
            text=True,
        )
        wall = time.monotonic() - start
        if proc.returncode != 0:
            print(proc.stderr[-2000:], file=sys.stderr)
            return None
        return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz")), wall


def steps_table(m: dict) -> list[str]:
    """Per image of a run's metrics.json: when it was shown, when every robot was within the
    convergence tolerance of a goal of its set (seconds after the change), the largest error at its end."""
    rows = [
        "| image | shown from s | converged s after the change | max goal error at the end mm |",
        "|---|---|---|---|",
    ]
    for s in m["steps"]:
        converged = "not by its end" if s["converged_at"] is None else f"{s['converged_at']:.1f}"
        rows.append(f"| {s['index']} | {s['t_start']:.1f} | {converged} | {1e3 * s['max_goal_error_at_end']:.1f} |")
    return rows


def run_subcommand(
    prog: str, commands: Mapping[str, Callable[[list[str]], object]], default: str | None, argv: list[str] | None = None
) -> int:
    """A module of several benchmarks: its first word names one (``commands``: name -> main(argv)),
    which parses the rest with its own flags; without a name, ``default`` runs (None: the list is
    printed). ``-h`` lists the names before the default's own help."""
    args = sys.argv[1:] if argv is None else list(argv)
    names = ", ".join(commands)
    if args and args[0] in commands:
        got = commands[args[0]](args[1:])
        return got if isinstance(got, int) else 0
    if args[:1] in (["-h"], ["--help"]) or default is None:
        print(f"usage: python -m {prog} {{{names}}} [flags] (python -m {prog} NAME --help)")
        if default is None:
            return 0 if args[:1] in (["-h"], ["--help"]) else 2
        print(f"without a name: {default}\n")
    got = commands[default](args)
    return got if isinstance(got, int) else 0


def parser_for(prog: str, doc: str) -> argparse.ArgumentParser:
    """The flags of one benchmark of a module, its help the benchmark's own description."""
    return argparse.ArgumentParser(
        prog=f"python -m {prog}", description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
