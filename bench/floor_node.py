"""The floor of an agent process: a bare zenoh session doing a robot's messages and nothing else.

Per tick it receives its robot's pose and its neighbours' states from the spatial cells around it
(the agent's subscriptions in real time: 5 x 5 cells of RobotParams.cell_size), then puts one state
to its cell and one command, as an agent does. No decoding, no control step: what is left is the
cost of the session, the callbacks and the puts, against which bench.bench_runtime sets the agent.

    python -m bench.floor_node --robot 3 --x 0.5 --y 0.1 --cell-size 0.21 -m client -e tcp/127.0.0.1:7447

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

from transport.codec import Command, Commands, State, States
from transport.keys import Keys, cell_of
from transport.session import TransportError, add_zenoh_args, open_session, settings_from_args

REACH = 2  # cells on each side of the robot's own: the agent's 5 x 5 in real time


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.floor_node", description=__doc__.splitlines()[0])
    parser.add_argument("--robot", type=int, required=True)
    parser.add_argument("--x", type=float, required=True, help="position (m): which cells it hears and puts to")
    parser.add_argument("--y", type=float, required=True)
    parser.add_argument("--cell-size", type=float, required=True, help="m (RobotParams.cell_size)")
    parser.add_argument("--display", default="default")
    parser.add_argument("--duration", type=float, default=600.0, help="s at most")
    parser.add_argument(
        "--callbacks",
        choices=["direct", "thread"],
        default="direct",
        help="direct: callbacks on zenoh's receiving thread (as transport.bus); thread: zenoh-python's "
        "default, a Python thread per subscription",
    )
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        keys = Keys(args.display)
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

    cx, cy = cell_of(args.x, args.y, args.cell_size)
    subs = [session.declare_subscriber(keys.pose(args.robot), handler(on_pose))]
    for dx in range(-REACH, REACH + 1):
        for dy in range(-REACH, REACH + 1):
            subs.append(session.declare_subscriber(keys.state_cell((cx + dx, cy + dy)), handler(on_state)))
    # what an agent standing there sends each tick, encoded once (the agent encodes its own each tick)
    state = States.one(State(args.robot, 0, 0.0, args.x, args.y, 0.0, 0.0, 0.037, 0.0, 0.0, -1, 0, 0, 0)).encode()
    command = Commands.one(Command(args.robot, 0, 0.0, Command.HOLONOMIC, 0.0, 0.0, 40, 40, 40)).encode()
    state_key, cmd_key = keys.state((cx, cy), args.robot), keys.cmd(args.robot)
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
            session.put(state_key, state, congestion_control=zenoh.CongestionControl.BLOCK)
            session.put(cmd_key, command, congestion_control=zenoh.CongestionControl.BLOCK)
            ticks += 1
    threads = threading.active_count()
    for sub in subs:
        sub.undeclare()
    session.close()
    print(json.dumps({"robot": args.robot, "ticks": ticks, "states_received": states, "threads": threads}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
