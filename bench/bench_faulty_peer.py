"""A faulty peer on the open bus (issue 40): the same lock-step run once per damage mode, with
sim.emulators.faulty_peer attached to its router after start-up, and what it cost: contacts, the
deepest overlap, whether (and when) the picture formed, and the messages dropped by reason.

    .venv/bin/python -m bench.bench_faulty_peer [--scene circle --robots 20 --seed 3 --duration 60]
        [--modes none future-pose ...] [-k K] [--rate 350] [--start-after 0.5]

Each run is `pixelswarm run SCENE --clock lockstep -l tcp/127.0.0.1:PORT --no-video --no-plots`
on a free port; the peer connects to that port as a client once the router listens and damages
from --start-after seconds after the run's first tick until the run ends. Runs go one after the
other (never two at once). Progress on stderr, the markdown table on stdout.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sim.emulators.faulty_peer import MODES_AND_ALL
from sim.processes import stop_processes
from transport.session import free_port, listening

from .common import REPO, machine

DEFAULT_MODES = ["none", *MODES_AND_ALL]


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run_command(args: argparse.Namespace, port: int, out: Path) -> list[str]:
    cmd = [sys.executable, "-m", "sim.cli", "run", args.scene, "--clock", "lockstep", "--seed", str(args.seed)]
    if args.robots:
        cmd += ["--robots", str(args.robots)]
    if args.duration:
        cmd += ["--duration", str(args.duration)]
    if args.k:
        cmd += ["-k", str(args.k)]
    return cmd + [
        "-l",
        f"tcp/127.0.0.1:{port}",
        "--display",
        args.display,
        "--out",
        str(out),
        "--no-video",
        "--no-plots",
    ]


def peer_command(args: argparse.Namespace, mode: str, port: int) -> list[str]:
    return [
        sys.executable,
        "-m",
        "sim.emulators.faulty_peer",
        "-e",
        f"tcp/127.0.0.1:{port}",
        "--display",
        args.display,
        "--mode",
        mode,
        "--rate",
        str(args.rate),
        "--start-after",
        str(args.start_after),
        "--seed",
        str(args.peer_seed),
        *(["--damage", args.damage] if args.damage else []),
    ]


def run_one(args: argparse.Namespace, mode: str, where: Path) -> dict[str, Any]:
    """One run, with the peer in this mode ('none': no peer): its metrics, the peer's summary line,
    the wall time."""
    port = free_port()
    out = where / mode
    start = time.monotonic()
    run = subprocess.Popen(
        run_command(args, port, out), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    peer: subprocess.Popen | None = None
    summary = ""
    try:
        if mode != "none":
            while run.poll() is None and not listening(port) and time.monotonic() - start < 60:
                time.sleep(0.1)
            peer = subprocess.Popen(
                peer_command(args, mode, port), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        try:
            _, run_err = run.communicate(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            stop_processes([run], 30)
            _, run_err = run.communicate()
            run_err += f"\n(bench: the run took over {args.timeout} s and was stopped)"
    finally:
        if peer is not None:
            stop_processes([peer], 10.0)
            peer_out, peer_err = peer.communicate()
            summary = (peer_out.strip().splitlines() or [peer_err.strip()[-300:]])[-1]
        stop_processes([run], 30)
    wall = time.monotonic() - start
    metrics_path = out / "metrics.json"
    if not metrics_path.exists():
        return {
            "mode": mode,
            "error": f"exit {run.returncode}: {run_err.strip()[-600:]}",
            "peer": summary,
            "wall": wall,
        }
    return {"mode": mode, "metrics": json.loads(metrics_path.read_text()), "peer": summary, "wall": wall}


def formed(metrics: dict[str, Any]) -> str:
    """'yes (t s)' or 'no', per image for a sequence."""
    steps = metrics.get("steps") or []
    if len(steps) > 1:
        times = [s.get("converged_at") for s in steps]
        shown = ", ".join("never" if t is None else f"{t:.1f}" for t in times)
        return f"{'yes' if all(t is not None for t in times) else 'no'} ({shown} s)"
    t = metrics.get("time_to_converge_s")
    return f"yes ({t:.1f} s)" if metrics.get("converged") and t is not None else "no"


def row(result: dict[str, Any]) -> str:
    peer = result["peer"]
    if result["mode"] == "none":
        sent = "-"
    elif peer.startswith("faulty-peer: mode") and ", sent " in peer:
        sent = peer.split(", sent ", 1)[1].split(" in ", 1)[0]
    else:
        sent = f"peer failed: {peer[-120:]}"
    if "error" in result:
        return f"| {result['mode']} | {sent} | run failed: {result['error'][-200:]} | | | | | | {result['wall']:.0f} |"
    m = result["metrics"]
    overlap = m.get("max_overlap_m") or 0.0
    events = m.get("contact_events") or []
    kinds = {k: sum(e.get("kind") == k for e in events) for k in ("robot", "obstacle", "wall")}
    contacts = str(m["contacts"])
    if kinds["obstacle"] or kinds["wall"]:
        others = [e for e in events if e.get("kind") != "robot"]
        deepest = max((e.get("max_depth") or 0.0 for e in others), default=0.0)
        shown = ", ".join(f"{v} {k}" for k, v in kinds.items() if v)
        contacts += f" ({shown}; past a wall or obstacle up to {deepest:.2f} m)"
    dropped = m.get("dropped_messages") or {}
    drops = ", ".join(f"{k} {v}" for k, v in sorted(dropped.items(), key=lambda kv: -kv[1])) or "-"
    return (
        f"| {result['mode']} | {sent} | {contacts} | {'-' if overlap <= 0 else f'{100 * overlap:.1f}'} "
        f"| {formed(m)} | {drops} | {m.get('missed_ticks', 0)} | {m.get('stopped_ticks', 0)} "
        f"| {m.get('end_reason', '')}{'' if m.get('agents_crashed', 0) == 0 else ', ' + str(m['agents_crashed']) + ' crashed'} "
        f"| {result['wall']:.0f} |"
    )


HEADER = [
    "| faulty peer | copies sent | contacts | deepest robot overlap (cm) | picture formed (after) | dropped messages by reason "
    "| missed ticks | stopped robot-ticks | end | wall s |",
    "|---|---|---|---|---|---|---|---|---|---|",
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="circle")
    parser.add_argument("--robots", type=int, default=20, help="robots (0: the scene's)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--duration", type=float, default=60.0, help="display seconds at most (0: the scene's)")
    parser.add_argument("--modes", nargs="+", default=DEFAULT_MODES, choices=DEFAULT_MODES)
    parser.add_argument("-k", type=int, default=0, help="robots per agent process (0: the scene's)")
    parser.add_argument("--rate", type=float, default=350.0, help="the peer's damaged copies a second")
    parser.add_argument("--start-after", type=float, default=0.5, help="s after the first tick the damage begins")
    parser.add_argument("--peer-seed", type=int, default=0)
    parser.add_argument("--damage", help="the malformed modes' damages (the peer's --damage; default all)")
    parser.add_argument("--display", default="default")
    parser.add_argument("--timeout", type=float, default=900.0, help="wall seconds a run may take")
    parser.add_argument("--keep", type=Path, help="keep the run directories here")
    parser.add_argument("--peer-lines", action="store_true", help="print each peer's summary line under the table")
    args = parser.parse_args(argv)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        where = args.keep or Path(tmp)
        where.mkdir(parents=True, exist_ok=True)
        for mode in args.modes:
            _say(f"bench_faulty_peer: {args.scene} {args.robots or ''} robots, faulty peer {mode} ...")
            result = run_one(args, mode, where)
            results.append(result)
            _say(f"  {row(result)}")
            if result["peer"]:
                _say(f"  {result['peer']}")
    command = " ".join(["python -m bench.bench_faulty_peer", *(argv if argv is not None else sys.argv[1:])])
    print(f"Command: `{command}`  \nMachine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}\n")
    print("\n".join(HEADER + [row(r) for r in results]))
    if args.peer_lines:
        print()
        for r in results:
            if r["peer"]:
                print(f"- {r['mode']}: {r['peer']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
