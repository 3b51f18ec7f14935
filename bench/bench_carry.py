"""Consecutive keyframes: bids to agree on frame f's goal set when the auction starts cold, from the
previous frame's assignment carried over by the goals' correspondence (agent.core.bidder.carry,
prices zero), from that assignment with the previous prices carried too, or from the goal sets'
own matching and its prices (coordinator.keyframes.goal_matching, sent with the goal set: what the agents do after an agreed
frame).

Robots stand on frame f-1's goals (2 mm noise); frame f is frame f-1 turned and moved, its goals
listed in another order. Hosts exchange their records in lossless rounds (no zenoh: this measures
the protocol, not the transport). `frames_close` is the agents' rule for starting the auction from
the carried claims when the matching cannot be used (the robots changed).

    .venv/bin/python -m bench.bench_carry [--robots 100] [--hosts 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

from agent.assignment import frames_close
from agent.core.bidder import Participant
from coordinator.keyframes import goal_correspondence, goal_matching

from .common import write_results

EPS, HYSTERESIS = 1e-3, 5e-3  # the defaults of agent.core.params
EXPLAIN = (
    "Robots stand on frame f-1's goals; frame f is that frame moved and turned, its goals listed in another "
    "order. Bids and message rounds until every host adopts an agreed final-phase instance of frame f's "
    "auction, starting cold, from the goal sets' matching with its prices (what the agents do), from the carried assignment (each robot claims the goal its last one "
    "corresponds to, prices zero; what the agents do when `frames_close`), or from that assignment with "
    "the previous prices carried too. In every case the robots drive to their carried goals at once; this "
    "measures only how soon the auction confirms or corrects them. Wall times are of this in-process "
    "exchange (no zenoh) and grow with other work on the machine; bids and rounds do not."
)
MATCHING = (
    "What the agents do (`agent.assignment.AuctionLink._warm_start`): after an agreed frame the "
    "coordinator sends with frame f's goal set the matching of frame f-1's goals to frame f's, with prices "
    "in equilibrium for it (`coordinator.keyframes.goal_matching`: scipy's `linear_sum_assignment` as if a "
    "robot stood on each old goal, its dual prices by shortest paths; its wall time is included here), each "
    "robot claims the goal its last one is matched to, and the auction starts from those claims and prices. "
    "The prices are nearly in equilibrium for the real positions, whatever the frames' disparity. "
    "`frames_close` now only decides for a frame whose robots changed (a robot died)."
)
RULE = (
    "The rule (`agent.assignment.frames_close`): start from the carried claims when corresponding goals are on "
    "average at most 1.5 goal spacings apart (the third column). Beyond that the claims skip the coarse "
    "epsilon phases that build the prices, and the fine phases fight a price war that costs more than a "
    "cold start."
)


def agree(parts: list[Participant], positions: np.ndarray, max_rounds: int = 100_000) -> int:
    """Message rounds until every host has adopted a final-phase instance; returns the rounds."""
    for p in parts:
        if not p.started:
            p.begin(0, {r: positions[r] for r in p.own})
    for rounds in range(1, max_rounds):
        for p in parts:
            p.bid_until_quiet()
            before = p.instance
            p.check_agreement()
            if p.instance != before:
                p.bid_until_quiet()
        if all(p.is_agreed and p.final_phase for p in parts):
            return rounds
        sent = [(p.instance, p.outgoing()) for p in parts]
        for i, (instance, (digest, recs)) in enumerate(sent):
            for j, q in enumerate(parts):
                if j != i:
                    if instance > q.instance:
                        q.begin(instance, {r: positions[r] for r in q.own})
                    q.absorb(instance, rounds, digest, recs)
    raise RuntimeError("no agreement")


def start_from_matching(parts: list[Participant], first: list[Participant], g1: np.ndarray, g2: np.ndarray) -> None:
    """What the agents do after an agreed frame (agent.assignment.AuctionLink._warm_start): claims and
    prices from the goal sets' matching."""
    matched, prices = goal_matching(g1, g2)
    for new, old in zip(parts, first):
        new.carry(old, matched, prices=prices)


def paper_transition(n: int = 1000, k: int = 4, steps: tuple[int, int] = (0, 1)) -> list[str]:
    """The paper's sequence at 1000 robots (scene paper-sequence-1000), its first transition (disk to
    disk and line): robots 2 mm off the disk's goals, in 4 hosts of 250, the auction cold and from
    the goal sets' matching."""
    from coordinator.scene import load_scene

    goals = load_scene("paper-sequence-1000").image_goals
    g1, g2 = (np.asarray(goals.goal_set(s, n)[0]) for s in steps)
    pos = g1 + np.random.default_rng(0).normal(0.0, 0.002, g1.shape)
    robots = list(range(n))
    hosts = [robots[h * n // k : (h + 1) * n // k] for h in range(k)]
    first = [Participant(1, g1, robots, h, EPS, HYSTERESIS) for h in hosts]
    agree(first, pos)
    out = [
        f"The paper's sequence with {n} robots in {k} hosts (scene `paper-sequence-1000`), image {steps[0]} to "
        f"image {steps[1]}, robots 2 mm off image {steps[0]}'s goals:",
        "",
        "| start | bids | message rounds | wall s |",
        "|---|---|---|---|",
    ]
    for start in ("cold", "goal matching, its prices"):
        parts = [Participant(2, g2, robots, h, EPS, HYSTERESIS) for h in hosts]
        t0 = time.perf_counter()
        if start != "cold":
            start_from_matching(parts, first, g1, g2)
        rounds = agree(parts, pos)
        out.append(f"| {start} | {sum(p.bids for p in parts)} | {rounds} | {time.perf_counter() - t0:.2f} |")
        print(out[-1], flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--hosts", type=int, default=10)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--no-paper", action="store_true", help="skip the 1000-robot paper transition (about 2 min)")
    a = ap.parse_args(argv)
    n, k = a.robots, a.hosts
    robots = list(range(n))
    hosts = [robots[h::k] for h in range(k)]
    lines = [
        EXPLAIN,
        "",
        f"{n} robots in {k} hosts, epsilon_A {EPS}, Delta C {HYSTERESIS}, seed {a.seed}.",
        "",
        "| frame f moved by | turned by | disparity / spacing | frames_close | start | bids | message rounds | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for shift, turn in ((0.03, 0.02), (0.1, 0.09), (0.3, 0.2), (1.0, 0.5)):
        rng = np.random.default_rng(a.seed)
        g1 = rng.uniform(-1.5, 1.5, (n, 2))
        c, s = np.cos(turn), np.sin(turn)
        g2 = (g1 @ np.array([[c, -s], [s, c]]).T + [shift, 0.0])[rng.permutation(n)]
        pos = g1 + rng.normal(0.0, 0.002, g1.shape)
        first = [Participant(1, g1, robots, h, EPS, HYSTERESIS) for h in hosts]
        agree(first, pos)
        previous = goal_correspondence(g1, g2)
        close = "yes" if frames_close(g1, g2, previous) else "no"
        disparity = np.hypot(*(g2 - g1[previous]).T).mean()
        ratio = disparity / np.median(cKDTree(g2).query(g2, k=2)[0][:, 1])  # as frames_close measures it
        for start in ("cold", "carried, prices zero", "carried, prices carried", "goal matching, its prices"):
            parts = [Participant(2, g2, robots, h, EPS, HYSTERESIS) for h in hosts]
            t0 = time.perf_counter()
            if start.startswith("goal matching"):
                start_from_matching(parts, first, g1, g2)
            elif start != "cold":
                for new, old in zip(parts, first):
                    new.carry(old, previous)
                    if start.endswith("carried"):
                        j = np.flatnonzero(previous >= 0)
                        new.board.price[j] = old.board.price[previous[j]]
                        new.board.version += 1
            rounds = agree(parts, pos)
            lines.append(
                f"| {shift} m | {np.degrees(turn):.1f} deg | {ratio:.2f} | {close} | {start} | "
                f"{sum(p.bids for p in parts)} | {rounds} | {time.perf_counter() - t0:.2f} |"
            )
            print(lines[-1], flush=True)
    lines += ["", MATCHING, "", RULE, ""]
    if not a.no_paper:
        lines += paper_transition()
    write_results(
        "carry",
        "Consecutive keyframes: the carried assignment (issue 6)",
        ".venv/bin/python -m bench.bench_carry",
        lines,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
