"""Auction benchmark (issue 5): time to agreement after a new goal set, messages and bytes per robot,
for N robot processes and N robots hosted K per process, next to scipy's centralised solve on the
same instance. Every host is a real OS process running the agents' AuctionLink over zenoh through
an embedded loopback router; no control loop runs (the full-system figures are in the runs).

    .venv/bin/python -m bench.bench_auction [--quick]

With ``--before REV`` the code at REV runs beside the code at ``--after`` (default HEAD), each from a
fresh git worktree with its compiled core built in place, case by case alternating: the hosts'
cases, then the central engine's settling of every robot in one process (``Participant.settle_alone``:
a cold block, then warm blocks while the robots drive to their goals), timed in a fresh process of
each tree (its first block includes any JIT compilation):

    .venv/bin/python -m bench.bench_auction --before cf836e5 [--cases 14x1,50x1,100x1,1000x250] [--central 1000]

With ``--cold SIZES`` instead: the auction's cold start by size (issue 43), the central engine's
settling of a new image's goal set on a fresh board (``Participant.settle_alone``), paper-sequence-
10000's first image at each robot count from the scene's initial poses. Per size: wall and CPU time,
Jacobi rounds and bids, one to one, and with ``--optimal`` the gap to scipy's ``linear_sum_assignment``
on the same positions against the bound N (epsilon_A + Delta C) (a dense N x N cost matrix: the
benchmark's, never the run's):

    .venv/bin/python -m bench.bench_auction --cold 1000,3000,10000 [--optimal]

With ``--warm-start SIZES --before REV``: the coordinator's warm start (``goal_matching``: the first
image matched to the robots' starts, and the second to the first) in this checkout beside REV's, in a
fresh process of each tree, paper-sequence-10000's images at each robot count; per case its wall
time and the total squared distance over scipy's optimum (up to 3000 robots: a dense matrix):

    .venv/bin/python -m bench.bench_auction --warm-start 1000,3000,10000 --before a559cd5~1
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from agent.core.bidder import Participant
from agent.core.params import RobotParams
from coordinator.scene import load_scene, scene_goal_set
from transport.bus import Bus
from transport.codec import Event, Goals, Timing, as_sent
from transport.session import client_of, loopback_router

from .bench_runtime import worktree_at
from .common import REPO, write_results


def instance(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Robots on a grid (as they start), goals spread over a disk of the same area."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    spacing = 0.2
    grid = np.array([(i % side, i // side) for i in range(n)], float) * spacing
    grid -= grid.mean(axis=0)
    radius = spacing * side / np.sqrt(np.pi)
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    goals = np.column_stack([r * np.cos(a), r * np.sin(a)]) + [0.3, 0.2]
    return grid, goals


def run(n: int, per_process: int, steady: float, faults: str = "", seed: int = 1, tree: Path = REPO) -> dict:
    """One case: N robots, ``per_process`` per host process, the hosts running the code in ``tree``."""
    positions, goals = instance(n, seed)
    router = loopback_router()
    with Bus(router, "bench", name="bench") as bus:
        events = bus.subscribe(bus.keys.event, Event)
        alive = bus.watch_alive("agent")
        procs = []
        hosts = [list(range(h, min(h + per_process, n))) for h in range(0, n, per_process)]
        for robots in hosts:
            xy = ",".join(f"{v:.6f}" for v in positions[robots].ravel())
            cmd = [
                sys.executable,
                "-m",
                "bench.auction_node",
                "--robots",
                ",".join(map(str, robots)),
                f"--positions={xy}",
                "--steady",
                str(steady),
                *client_of(router).to_args(),
            ]
            if faults:
                cmd += ["--faults", faults]
            procs.append(
                subprocess.Popen(cmd, cwd=tree, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)
            )
        try:
            seen: set[str] = set()
            end = time.monotonic() + 120
            while len(seen) < len(hosts) and time.monotonic() < end:
                seen.update(ident for _, ident, up, _, _ in alive.drain() if up)
                time.sleep(0.05)
            time.sleep(1.0)  # subscriptions settle
            t = time.perf_counter()
            cost = ((positions[:, None] - goals[None]) ** 2).sum(-1)
            rows, cols = linear_sum_assignment(cost)
            scipy_s = time.perf_counter() - t
            bus.publish(
                bus.keys.goals(1), Goals(1, 0, goals, np.zeros((n, 3), np.uint8), np.arange(n), Timing(0.0, 0, 10.0))
            )
            reports = []
            end = time.monotonic() + 120 + steady
            while len(reports) < len(hosts) and time.monotonic() < end:
                got = events.get(timeout=0.5)
                if got and got[1].data.get("kind") == "auction-bench":
                    reports.append(got[1].data)
        finally:
            for p in procs:
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
    firsts = [r["first_agreement_s"] for r in reports if r["first_agreement_s"] is not None]
    assigned = {int(k): v for r in reports for k, v in r["goals"].items()}
    agreed_cost = float(sum(cost[r, g] for r, g in assigned.items())) if len(assigned) == n else float("nan")
    return {
        "n": n,
        "k": per_process,
        "hosts": len(hosts),
        "reports": len(reports),
        "agreement_s": max(firsts) if len(firsts) == len(hosts) else float("nan"),
        "scipy_s": scipy_s,
        "cost_ratio": agreed_cost / float(cost[rows, cols].sum()),
        "one_to_one": len(set(assigned.values())) == len(assigned) == n,
        "bids_per_robot": sum(r["bids"] for r in reports) / n,
        "cold_msgs_per_robot": sum(r["cold_messages"] for r in reports) / n,
        "cold_kb_per_robot": sum(r["cold_bytes"] for r in reports) / n / 1024,
        "steady_msgs_per_robot_s": sum(r["steady_messages"] for r in reports) / n / steady,
        "steady_bytes_per_robot_s": sum(r["steady_bytes"] for r in reports) / n / steady,
        "received_per_host": np.mean([r["received"] for r in reports]) if reports else 0,
    }


# Run with ``python -c`` in a tree (its own code: the old revision has no function of this file):
# the central engine's auction alone, N robots from a grid to a disk, each warm block after the
# robots drove a tenth of the way to their goals. Prints JSON.
CENTRAL = """
import json, sys, time
import numpy as np
from agent.core.bidder import Participant
n, blocks, seed = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
rng = np.random.default_rng(seed)
side = int(np.ceil(np.sqrt(n)))
pos = np.array([(i % side, i // side) for i in range(n)], float) * 0.2
r, a = 0.2 * side / np.sqrt(np.pi) * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
goals = np.column_stack([r * np.cos(a), r * np.sin(a)]) + pos.mean(axis=0)
part = Participant(1, goals, range(n), range(n), 1e-3, 5e-3)
times = []
for block in range(blocks):
    t = time.perf_counter()
    goal = part.settle_alone(pos)
    times.append(time.perf_counter() - t)
    pos = pos + 0.1 * (goals[goal] - pos) + rng.normal(0, 0.002, pos.shape)
digest = part.board.digest()
print(json.dumps({"times": times, "bids": part.bids, "rounds": part.rounds, "digest": digest}))
"""


def in_tree(tree: Path, snippet: str, *args: object) -> dict:
    """What a snippet prints last (JSON), run in a fresh process of ``tree``'s code."""
    out = subprocess.run(
        [sys.executable, "-c", snippet, *map(str, args)], cwd=tree, check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.splitlines()[-1])


def central(tree: Path, n: int, blocks: int, seed: int = 1) -> dict:
    """The central engine's settling in a fresh process of ``tree``'s code."""
    return in_tree(tree, CENTRAL, n, blocks, seed)


def side_by_side(args: argparse.Namespace, cases: list[tuple[int, int]]) -> None:
    """The code at --before beside the code at --after, alternating case by case, in one run."""
    with contextlib.ExitStack() as stack:
        made = {
            what: stack.enter_context(worktree_at(rev))
            for what, rev in (("before", args.before), ("after", args.after))
        }
        trees = {what: tree for what, (tree, _) in made.items()}
        commits = {what: commit for what, (_, commit) in made.items()}
        rows = [
            "| N robots | robots per process (processes) | code | time to agreement s (slowest host) | "
            "agreed cost / optimum | one-to-one | bids per robot |",
            "|---|---|---|---|---|---|---|",
        ]
        for n, k in cases:
            for _ in range(args.pairs):
                for what in ("before", "after"):
                    r = run(n, k, args.steady, tree=trees[what])
                    rows.append(
                        f"| {n} | {k} ({r['hosts']}) | {what} {commits[what]} | {r['agreement_s']:.3f} | "
                        f"{r['cost_ratio']:.5f} | {r['one_to_one']} | {r['bids_per_robot']:.1f} |"
                    )
                    print(rows[-1], flush=True)
        rows += [
            "",
            f"Central engine (one process settles every robot, `Participant.settle_alone`): {args.blocks} blocks, a cold "
            "start then warm blocks while the robots drive a tenth of the way to their goals per block; a fresh "
            "process per run (its first block includes any JIT compilation).",
            "",
            "| N robots | code | first block s | warm block median ms | warm block max ms | bids | rounds | same board |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for n in args.central:
            for _ in range(args.pairs):
                got = {what: central(trees[what], n, args.blocks) for what in ("before", "after")}
                same = got["before"]["digest"] == got["after"]["digest"]
                for what, r in got.items():
                    warm = np.array(r["times"][1:]) * 1e3
                    rows.append(
                        f"| {n} | {what} {commits[what]} | {r['times'][0]:.3f} | {np.median(warm):.2f} | "
                        f"{warm.max():.2f} | {r['bids']} | {r['rounds']} | {same} |"
                    )
                    print(rows[-1], flush=True)
    write_results(
        "auction_before_after",
        f"Auction: the code at {args.before} beside {args.after}",
        ".venv/bin/python -m bench.bench_auction " + " ".join(sys.argv[1:]),
        rows,
    )


# Run with ``python -c`` in a tree: its goal_matching (coordinator.warm_start, or coordinator.keyframes
# before) on paper-sequence-10000's images at N robots, each case in at most LIMIT s, with the total
# squared distance over scipy's optimum up to OPTIMUM robots (a dense matrix, outside the timing).
# Prints JSON: per case [s, gap] (gap None above OPTIMUM), or None if given up.
WARM = """
import json, multiprocessing, sys, time
import numpy as np
from scipy.optimize import linear_sum_assignment
from coordinator.scene import load_scene, scene_goal_set
from transport.codec import as_sent
import coordinator.keyframes
goal_matching = getattr(coordinator.keyframes, "goal_matching", None)  # before a559cd5 (the editable
if goal_matching is None:  # install would find this checkout's coordinator.warm_start from any tree)
    from coordinator.warm_start import goal_matching
n, limit, optimum = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
scene = load_scene("paper-sequence-10000", robots=n)
g0, g1 = (as_sent(scene_goal_set(scene, k, n)[0]) for k in (0, 1))
cases = {"starts to image 1": (np.asarray(scene.poses, float)[:, :2], g0), "image 1 to 2": (g0, g1)}
def timed(a, b, out):
    t = time.perf_counter()
    matched, _ = goal_matching(a, b)
    out.put((time.perf_counter() - t, float(((b - a[matched]) ** 2).sum())))
found = {}
for name, (a, b) in cases.items():
    out = multiprocessing.Queue()
    p = multiprocessing.Process(target=timed, args=(a, b, out))
    p.start()
    p.join(limit)
    if p.is_alive():
        p.kill()
        found[name] = None
        continue
    seconds, cost = out.get()
    gap = None
    if n <= optimum:
        c = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(c)
        gap = cost - float(c[rows, cols].sum())
    found[name] = [seconds, gap]
print(json.dumps(found))
"""
WARM_LIMIT = 120.0  # s a case may take before it is given up (the dense matching at 10,000 robots takes longer)
WARM_OPTIMUM = 3000  # robots up to which the table gives the gap to scipy's optimum


def warm_starts(sizes: str, before: str) -> None:
    """The warm start's matching by size, this checkout beside ``before``."""
    rows = [
        "| robots | case | code | s | total squared distance - optimum (m^2) |",
        "|---|---|---|---|---|",
    ]
    with worktree_at(before) as (tree, commit):
        for n in (int(v) for v in sizes.split(",")):
            for what, where in (("before " + commit, tree), ("after", REPO)):
                for name, got in in_tree(where, WARM, n, WARM_LIMIT, WARM_OPTIMUM).items():
                    seconds = f"{got[0]:.2f}" if got else f"> {WARM_LIMIT:.0f}"
                    gap = f"{got[1]:.3g}" if got and got[1] is not None else "-"
                    rows.append(f"| {n} | {name} | {what} | {seconds} | {gap} |")
                    print(rows[-1], flush=True)
    command = f".venv/bin/python -m bench.bench_auction --warm-start {sizes} --before {before}"
    write_results("warm_start", "The coordinator's warm start by size", command, rows)


def cold_start(robots: int, optimal: bool) -> str:
    """One size's row of the table."""
    scene = load_scene("paper-sequence-10000", robots=robots)
    params = RobotParams.from_dict(scene.robot)
    pixels = np.arange(robots)
    goals = as_sent(scene_goal_set(scene, 0, robots)[0])  # as the robots hear them
    position = as_sent(scene.poses)[:, :2]
    wall, cpu = time.perf_counter(), time.process_time()
    part = Participant(0, goals, pixels.tolist(), pixels.tolist(), params.assign_eps, params.assign_hysteresis)
    goal = part.settle_alone(position)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    one_to_one = len(set(goal.tolist())) == robots and bool((goal >= 0).all())
    gap = bound = "-"
    if optimal:
        cost = ((position[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(cost)
        gap = f"{cost[pixels, goal].sum() - cost[rows, cols].sum():.4g}"
        bound = f"{robots * (params.assign_eps + params.assign_hysteresis):.4g}"
    return f"| {robots} | {wall:.2f} | {cpu:.2f} | {part.rounds} | {part.bids} | {one_to_one} | {gap} | {bound} |"


def cold_starts(sizes: str, optimal: bool) -> None:
    lines = [
        "| robots | settle wall s | CPU s | rounds | bids | one to one | cost - optimum | N (eps_A + Delta C) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for robots in (int(n) for n in sizes.split(",")):
        lines.append(cold_start(robots, optimal))
        print(lines[-1], flush=True)
    command = f".venv/bin/python -m bench.bench_auction --cold {sizes}" + " --optimal" * optimal
    write_results("cold_auction", "The auction's cold start by size (central engine)", command, lines)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 14 only")
    parser.add_argument("--steady", type=float, default=5.0)
    parser.add_argument("--cases", default="", help="e.g. 100x1,1000x250 (robots x robots per process)")
    parser.add_argument("--before", default="", help="a git revision to run beside --after (side by side)")
    parser.add_argument("--after", default="HEAD")
    parser.add_argument("--pairs", type=int, default=1, help="side by side: runs of each tree per case")
    parser.add_argument("--central", default="1000", help="side by side: robots of the central engine's cases")
    parser.add_argument("--blocks", type=int, default=30, help="side by side: blocks per central case")
    parser.add_argument("--cold", metavar="SIZES", help="only the cold start at these robot counts, e.g. 1000,10000")
    parser.add_argument("--optimal", action="store_true", help="with --cold: scipy's optimum too (minutes at 10,000)")
    parser.add_argument("--warm-start", metavar="SIZES", help="only the warm start's matching, beside --before")
    args = parser.parse_args()
    if args.warm_start:
        warm_starts(args.warm_start, args.before or "HEAD")
        return
    if args.cold:
        cold_starts(args.cold, args.optimal)
        return
    args.central = [int(v) for v in args.central.split(",") if v]
    # SIGTERM unwinds like Ctrl-C, so the finally blocks stop every node process this bench started
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    cases = [(14, 1)] if args.quick else [(14, 1), (50, 1), (100, 1), (1000, 250)]
    if args.cases:
        cases = [(int(c.split("x")[0]), int(c.split("x")[1])) for c in args.cases.split(",")]
    if args.before:
        side_by_side(args, cases)
        return
    rows = [
        "| N robots | robots per process (processes) | time to agreement s (slowest host) | scipy solve s | "
        "agreed cost / optimum | one-to-one | bids per robot | cold-start msgs / robot (KB) | "
        "steady msgs / robot-s | steady bytes / robot-s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n, k in cases:
        r = run(n, k, args.steady)
        rows.append(
            f"| {n} | {k} ({r['hosts']}) | {r['agreement_s']:.3f} | {r['scipy_s'] * 1e3:.2f} ms | "
            f"{r['cost_ratio']:.5f} | {r['one_to_one']} | {r['bids_per_robot']:.1f} | "
            f"{r['cold_msgs_per_robot']:.1f} ({r['cold_kb_per_robot']:.2f}) | "
            f"{r['steady_msgs_per_robot_s']:.1f} | {r['steady_bytes_per_robot_s']:.0f} |"
        )
        print(rows[-1], flush=True)
    lossy = run(14, 1, args.steady, faults="auction:drop=0.1,delay=0.05")
    notes = [
        "",
        f"With 10% loss and 50 ms delay on auction messages (N = 14 processes): agreement in "
        f"{lossy['agreement_s']:.2f} s, one-to-one {lossy['one_to_one']}, cost / optimum "
        f"{lossy['cost_ratio']:.5f}.",
        "",
        "nan: not every host saw an agreement within the hosts' 60 s limit (agreed goals, when any, are "
        "those reported at the end of the steady phase).",
        "Time to agreement: from the goal set's arrival at a host to its first agreed instance (after "
        "the epsilon-scaling phases of the cold start), slowest host. Steady state: one instance per "
        "0.1 s (paper 5.1: re-assign every iteration) on positions with 2 mm noise. Targets: 1 s at "
        "N = 100 processes, 5 s at N = 1000 hosted, 2 KB/s per robot.",
    ]
    write_results(
        "auction",
        "Distributed auction: agreement time and traffic (issue 5)",
        ".venv/bin/python -m bench.bench_auction",
        rows + notes,
    )


if __name__ == "__main__":
    main()
