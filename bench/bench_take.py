"""An agent's tick of neighbour states, taken (Inbox.take) beside drained (Inbox.drain), issue 25.

One process: an embedded router, a publisher, and a subscriber with a pulled inbox of 25 cell
subscriptions (an agent's 5 x 5 cells in real time). Each round the publisher puts one state of a
robot alone into each of 16 cells, as neighbours do each tick; once they have arrived, the inbox hands
them over by take() or by drain(), in turn, and the CPU time of that call on this thread is kept.

    .venv/bin/python -m bench.bench_take [--rounds 3000] [--states 16]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from transport.bus import Bus
from transport.codec import State, States
from transport.session import client_of, loopback_router

from .common import write_results

CELLS = 25  # the 5 x 5 cells around a robot, as an agent subscribes in real time
SETTLE = 0.005  # s after the puts: the states are in the subscriber's channels


def measure(rounds: int, states: int) -> dict[str, list[float]]:
    """CPU microseconds of each take() and drain() of ``states`` states, alternating."""
    router = loopback_router()
    spent: dict[str, list[float]] = {"take": [], "drain": []}
    with Bus(router, name="bench-router"), Bus(client_of(router)) as a, Bus(client_of(router)) as b:
        inbox = b.inbox(State, pulled=True)
        for cx in range(CELLS):
            b.subscribe_into(b.keys.state_cell((cx, 0)), inbox)
        time.sleep(0.5)  # subscriptions travel
        for k in range(rounds + 2):
            for robot in range(states):
                state = State(robot, k, 0.1 * k, 0.0, 0.0, 0.0, 0.0, 0.037, 0.0, 0.0, -1, 0, 0, 0)
                a.put(a.keys.state((robot % CELLS, 0), robot), States.one(state).encode())
            time.sleep(SETTLE)
            how = "take" if k % 2 else "drain"
            begin = time.thread_time_ns()
            got = inbox.take() if how == "take" else [m for _, m in inbox.drain()]
            used = (time.thread_time_ns() - begin) / 1000
            if len(got) != states:
                raise RuntimeError(f"{how} handed over {len(got)} states of {states}")
            if k >= 2:  # the first of each warm the path
                spent[how].append(used)
    return spent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_take", description="take() beside drain()")
    parser.add_argument("--rounds", type=int, default=3000, help="calls, half of them each way")
    parser.add_argument("--states", type=int, default=16, help="states a round (an agent hears 13-31 a tick)")
    args = parser.parse_args(argv)
    if args.rounds < 2 or not 1 <= args.states <= CELLS:
        print(f"bench_take: error: --rounds must be at least 2 and --states 1 to {CELLS}", file=sys.stderr)
        return 2
    spent = measure(args.rounds, args.states)
    rows = [
        "| call | calls | CPU µs, median | mean | per state, median |",
        "|---|---|---|---|---|",
    ]
    for how in ("drain", "take"):
        v = spent[how]
        med = statistics.median(v)
        rows.append(f"| {how} | {len(v)} | {med:.0f} | {statistics.mean(v):.0f} | {med / args.states:.1f} |")
    command = " ".join(["python -m bench.bench_take", *(argv if argv is not None else sys.argv[1:])])
    write_results(
        "state_take",
        "Taking a tick's neighbour states: Inbox.take beside Inbox.drain (issue 25)",
        command,
        rows
        + [
            "",
            f"One process, {CELLS} pulled cell subscriptions, {args.states} states of robots alone a round; "
            "take() and drain() in turn on the same inbox, CPU time of the call on its thread (time.thread_time). "
            "drain() is the path before take(): a queue and a key string per state.",
        ],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
