"""Where an agent process's CPU goes, thread by thread: its main thread, zenoh-python's callback
threads and zenoh's own (rx, tx, ...), in a real run of the circle in real time.

Launches `pixelswarm run circle`, waits ``--warm`` seconds (start-up and the first ticks), then reads
each agent process's threads' CPU time (/proc/PID/task/TID/stat, user + system) twice, ``--span``
seconds apart, and prints the mean per agent process by thread name (% of a core). Run it from a
worktree of another revision to compare two versions of the code.

    .venv/bin/python -m bench.agent_threads [--robots 20] [--warm 9] [--span 12]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import psutil

from .common import REPO

TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def agent_threads(launcher: psutil.Process) -> dict[tuple[int, int], tuple[str, float]]:
    """(pid, tid) -> (thread name, CPU seconds) of every agent process below ``launcher``; an agent's
    main thread is named MAIN (Python's threads are all named after the interpreter)."""
    out = {}
    for child in launcher.children(recursive=True):
        try:
            if "agent" not in child.cmdline():
                continue
            for tid in os.listdir(f"/proc/{child.pid}/task"):
                task = Path(f"/proc/{child.pid}/task/{tid}")
                name = "MAIN" if int(tid) == child.pid else (task / "comm").read_text().strip()
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
                out[(child.pid, int(tid))] = (name, (int(fields[11]) + int(fields[12])) / TICKS_PER_S)
        except (psutil.Error, OSError):
            continue  # gone meanwhile
    return out


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.agent_threads", description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=20)
    parser.add_argument("--warm", type=float, default=9.0, help="s after launching before the first reading")
    parser.add_argument("--span", type=float, default=12.0, help="s between the two readings")
    args = parser.parse_args()
    if args.robots < 1 or args.warm < 0 or args.span <= 0:
        print("agent_threads: error: --robots must be >= 1, --warm >= 0 and --span > 0", file=sys.stderr)
        return 2
    duration = args.warm + args.span + 30  # display seconds enough to outlast the readings
    with tempfile.TemporaryDirectory() as tmp:
        run = [sys.executable, "-m", "sim.cli", "run", "circle", "--robots", str(args.robots), "--clock", "realtime"]
        run += ["--duration", str(duration), "--seed", "3", "--no-video", "--no-plots", "-q", "--out", f"{tmp}/run"]
        proc = subprocess.Popen(run, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            time.sleep(args.warm)
            first, start = agent_threads(psutil.Process(proc.pid)), time.monotonic()
            time.sleep(args.span)
            second, span = agent_threads(psutil.Process(proc.pid)), time.monotonic() - start
        finally:
            proc.terminate()
            proc.communicate(timeout=60)
    by_name: Counter[str] = Counter()
    for key, (name, cpu) in second.items():
        if key in first:
            by_name[name] += cpu - first[key][1]
    agents = len({pid for pid, _ in second if (pid, pid) in first})
    if not agents:
        print("agent_threads: error: no agent process ran through the readings (try a smaller --warm)", file=sys.stderr)
        return 1
    print(f"{agents} agent processes, {span:.1f} s; % of a core per agent process, by thread")
    for name, cpu in by_name.most_common():
        print(f"{100 * cpu / span / agents:7.2f}  {name}")
    print(f"{100 * sum(by_name.values()) / span / agents:7.2f}  total")
    return 0


if __name__ == "__main__":
    sys.exit(main())
