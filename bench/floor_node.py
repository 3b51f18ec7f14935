"""The floor of an agent process: a bare zenoh session doing a robot's messages and nothing else.

Per tick it receives its robot's pose and its neighbours' states from the spatial cells around it
(the agent's subscriptions in real time: 5 x 5 cells of RobotParams.cell_size), then puts one state
to its cell and one command, as an agent does. No decoding, no control step, no numpy: the keys and
the encoded state and command come from its parent (bench.bench_runtime), so what is left is the
cost of the session, the callbacks and the puts, against which the benchmark sets the agent.
``--numpy`` imports numpy too (and uses none of it): what numpy alone adds to a process's memory.

    python -m bench.floor_node --pose-key K --state-key K --cmd-key K --hear K [--hear K ...]
        --state HEX --command HEX -m client -e tcp/127.0.0.1:7447

It says `ready` once subscribed, exits when its parent does, on SIGTERM, or after --duration
seconds, and then prints one line of JSON with what it received and sent.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from transport.session import TransportError, add_zenoh_args, open_session, settings_from_args

DESCRIPTION = "The floor of an agent process: a bare zenoh session doing a robot's messages and nothing else."


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.floor_node", description=DESCRIPTION)
    parser.add_argument("--pose-key", required=True, help="its robot's pose: a tick begins when it comes")
    parser.add_argument("--hear", action="append", required=True, help="a cell's states it takes in (repeated)")
    parser.add_argument("--state-key", required=True, help="where it puts its state each tick")
    parser.add_argument("--cmd-key", required=True, help="where it puts its command each tick")
    parser.add_argument("--state", type=bytes.fromhex, required=True, help="the encoded state it puts, in hex")
    parser.add_argument("--command", type=bytes.fromhex, required=True, help="the encoded command it puts, in hex")
    parser.add_argument("--numpy", action="store_true", help="import numpy (unused): its share of the memory")
    parser.add_argument("--duration", type=float, default=600.0, help="s at most")
    parser.add_argument(
        "--callbacks",
        choices=["direct", "thread"],
        default="direct",
        help="direct: callbacks on zenoh's receiving thread; thread: zenoh-python's default, a Python thread "
        "per subscription (as transport.bus's callback inboxes: poses, goal sets, the auction)",
    )
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    if args.numpy:
        import numpy  # noqa: F401
    try:
        session = open_session(settings_from_args(args))
    except (TransportError, ValueError) as err:
        print(f"floor_node: error: {err}", file=sys.stderr)
        return 2
    parent, running = os.getppid(), threading.Event()
    running.set()
    signal.signal(signal.SIGTERM, lambda *_: running.clear())
    inbox: queue.SimpleQueue[tuple[bool, bytes]] = queue.SimpleQueue()  # (is a pose, payload)
    bell = threading.Event()

    def on_pose(sample: zenoh.Sample) -> None:
        inbox.put((True, sample.payload.to_bytes()))
        bell.set()

    def on_state(sample: zenoh.Sample) -> None:
        inbox.put((False, sample.payload.to_bytes()))

    def handler(callback: Callable[[zenoh.Sample], None]) -> zenoh.handlers.Callback:
        return zenoh.handlers.Callback(callback, indirect=args.callbacks == "thread")

    subs = [session.declare_subscriber(args.pose_key, handler(on_pose))]
    subs += [session.declare_subscriber(key, handler(on_state)) for key in args.hear]
    print("ready", flush=True)  # subscribed: the benchmark's clock may start
    ticks = states = 0
    end = time.monotonic() + args.duration
    while running.is_set() and time.monotonic() < end and os.getppid() == parent:
        bell.wait(0.2)
        bell.clear()
        posed = False
        while True:  # one drain of the inbox per tick
            try:
                is_pose, _ = inbox.get_nowait()
            except queue.Empty:
                break
            posed |= is_pose
            states += not is_pose
        if posed:
            session.put(args.state_key, args.state, congestion_control=zenoh.CongestionControl.BLOCK)
            session.put(args.cmd_key, args.command, congestion_control=zenoh.CongestionControl.BLOCK)
            ticks += 1
    threads = threading.active_count()
    for sub in subs:
        sub.undeclare()
    session.close()
    print(json.dumps({"ticks": ticks, "states_received": states, "threads": threads}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
