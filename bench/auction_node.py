"""One agent host in the auction benchmark: the real AuctionLink over zenoh, without the control loop.

Its robots sit at given positions; it joins the goal set the benchmark publishes, agrees, then keeps
re-auctioning every 0.1 s (steady state, positions jittered by tracking noise) for --steady seconds,
and reports what it measured as an event.

    python -m bench.auction_node --robots 0,1,2 --positions x0,y0,x1,y1,... [zenoh flags]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import numpy as np

from agent.assignment import AuctionLink
from agent.core.params import HOLONOMIC, RobotParams
from transport.bus import Bus
from transport.codec import Event, Goals
from transport.session import add_zenoh_args, settings_from_args


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.auction_node")
    parser.add_argument("--robots", required=True)
    parser.add_argument("--positions", required=True)
    parser.add_argument("--steady", type=float, default=5.0)
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--faults", default="")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    robots = [int(r) for r in args.robots.split(",")]
    xy = np.array([float(v) for v in args.positions.split(",")]).reshape(-1, 2)
    positions = {r: xy[i] for i, r in enumerate(robots)}
    from transport.faults import parse_faults

    with Bus(
        settings_from_args(args), "bench", faults=parse_faults(args.faults), seed=robots[0], name=f"host{robots[0]}"
    ) as bus:
        agreed_at: list[float] = []
        link = AuctionLink(
            bus,
            robots,
            RobotParams(kinematics=HOLONOMIC),
            lambda e, k, goals, pos, col: agreed_at.append(time.monotonic()),
        )
        goals_inbox = bus.subscribe(bus.keys.all_of("goals"), Goals)
        bus.declare_alive("agent", robots[0])
        end = time.monotonic() + args.timeout
        got = None
        while got is None and time.monotonic() < end:
            got = goals_inbox.get(timeout=0.1)
        if got is None:
            return 1
        t0 = time.monotonic()
        link.on_goals(got[1], positions)
        rng = np.random.default_rng(robots[0])
        bell = threading.Event()
        link.inbox.bell = bell
        while not agreed_at and time.monotonic() < end:
            bell.clear()
            link.poll(positions)
            bell.wait(min(0.2, link.next_due()))
        first = agreed_at[0] - t0 if agreed_at else None
        sent0, bytes0 = bus.sent.messages["auction"], bus.sent.bytes["auction"]
        steady_end = time.monotonic() + args.steady
        stamp = 0.0
        next_tick = time.monotonic()
        while time.monotonic() < steady_end:
            if time.monotonic() >= next_tick:
                stamp += 0.1
                next_tick += 0.1
                noisy = {r: p + rng.normal(0, 0.002, 2) for r, p in positions.items()}
                link.on_tick(stamp, noisy)
            bell.clear()
            link.poll(positions)
            bell.wait(min(link.next_due(), max(0.0, next_tick - time.monotonic())))
        bus.publish(
            bus.keys.event,
            Event(
                {
                    "kind": "auction-bench",
                    "robots": robots,
                    "first_agreement_s": first,
                    "goals": {str(r): g for r, g in (link.part.agreed.items() if link.part else [])},
                    "bids": link.part.bids if link.part else 0,
                    "agreements": link.counts.agreements,
                    "cold_messages": sent0,
                    "cold_bytes": bytes0,
                    "steady_messages": bus.sent.messages["auction"] - sent0,
                    "steady_bytes": bus.sent.bytes["auction"] - bytes0,
                    "steady_s": args.steady,
                    "received": link.counts.received,
                }
            ),
        )
        time.sleep(0.3)
    return 0


if __name__ == "__main__":
    sys.exit(main())
