"""Which calls of a robot's agent process page in numpy's code: every page of a shared library that a
process touches counts in its RSS (the kernel maps a file 64 kB around each fault), so each part of
numpy that a robot's ticks run costs every robot process up to 64 kB (issue 25).

Runs `pixelswarm run circle` in real time with bench.pages_hook loaded into one agent process (a
sitecustomize on PYTHONPATH), then prints what numpy's core held when it loaded, what the imports
added, what the run added after them, and the calls that added it (the first call to touch a page
is the one named). A diagnostic, not a measure of RSS (bench.bench_runtime, bench.pair_runtime):
the tracer slows the agent it watches. ``--tree`` runs the code of another checkout (a git worktree
of another revision) with this checkout's tracer, to compare the two.

    .venv/bin/python -m bench.agent_pages [--robots 20] [--duration 12] [--top 15] [--tree DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import REPO

SITECUSTOMIZE = """import importlib.util, os, sys
if "agent" in sys.orig_argv and os.environ.get("PIXELSWARM_PAGES"):
    spec = importlib.util.spec_from_file_location("pages_hook", {hook!r})
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    hook.install(os.environ["PIXELSWARM_PAGES"])
"""


def read(pages: Path) -> tuple[int, int, list[tuple[int, str]]]:
    """(kB when numpy loaded, kB the imports added, [(kB, call)] of the calls after the imports)."""
    lines = pages.read_text().splitlines()
    if not lines or not lines[0].startswith("START "):
        raise RuntimeError(f"{pages} holds no trace: no agent loaded numpy under the tracer")
    start, imports, after = int(lines[0].split()[1]), 0, []
    for line in lines[1:]:
        kb, call = line.split(" ", 1)
        if "importlib" in call or "<module>" in call:
            imports += int(kb)
        else:
            after.append((int(kb), call))
    return start, imports, after


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.agent_pages", description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=20)
    parser.add_argument("--duration", type=float, default=12.0, help="s of display")
    parser.add_argument("--top", type=int, default=15, help="calls to list")
    parser.add_argument("--tree", type=Path, default=REPO, help="the checkout whose code runs (default: this one)")
    args = parser.parse_args()
    if args.robots < 1 or args.duration <= 0 or args.top < 0 or not (args.tree / "agent").is_dir():
        print(
            "agent_pages: error: --robots must be >= 1, --duration > 0, --top >= 0, --tree a checkout", file=sys.stderr
        )
        return 2
    tree = args.tree.resolve()
    # its robots' optimised bytecode, as make compiles it: they then run as a robot's process does (-OO)
    subprocess.run([sys.executable, "-m", "compileall", "-q", "-o", "0", "-o", "2", "agent", "transport"], cwd=tree)
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "site").mkdir()
        hook = str(Path(__file__).with_name("pages_hook.py"))
        (Path(tmp) / "site" / "sitecustomize.py").write_text(SITECUSTOMIZE.format(hook=hook))
        env = dict(os.environ, PIXELSWARM_PAGES=tmp, PYTHONPATH=os.pathsep.join([f"{tmp}/site", str(tree)]))
        run = [sys.executable, "-m", "sim.cli", "run", "circle", "--robots", str(args.robots), "--clock", "realtime"]
        run += [
            "--duration",
            str(args.duration),
            "--seed",
            "3",
            "--no-video",
            "--no-plots",
            "-q",
            "--out",
            f"{tmp}/run",
        ]
        done = subprocess.run(run, cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            print(f"agent_pages: error: the run failed: {done.stderr.strip()[-500:]}", file=sys.stderr)
            return 1
        start, imports, after = read(Path(tmp) / "pages.txt")
    print(f"numpy's core in one agent of {args.robots}, code from {tree}:")
    print(f"{start} kB mapped when numpy loaded, {imports:+d} kB by the imports, ", end="")
    print(f"{sum(kb for kb, _ in after):+d} kB by the run after them")
    for kb, call in sorted(after, key=lambda c: -c[0])[: args.top]:
        print(f"{kb:+6d} kB  {call}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
