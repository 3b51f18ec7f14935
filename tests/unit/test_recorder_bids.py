"""The recorder keeps where each robot bid from in each auction instance (what the assignment's
optimality is checked against): claims only, from the wire's float32, robots of the run only."""

from __future__ import annotations

import numpy as np

from sim.outputs.recorder import Recorder
from tests.support.fake_bus import RecorderBus
from transport.codec import AuctionRecord, Bid


def bid(sender: int, instance: int, rows: list[tuple]) -> Bid:
    recs = np.array(rows, Bid.RECORD)
    return Bid(1, instance, sender, 1, 0, len(recs), recs)


def f(v: float) -> float:
    return float(np.float32(v))  # as the wire carries it


def test_the_recorder_keeps_each_claims_bid_position_per_instance():
    bus = RecorderBus()
    rec = Recorder(bus, robots=4, tolerance=0.01)
    released = AuctionRecord.RELEASED
    said = [
        bid(
            0, 5, [(0, 2, 1.5, 0, 0.0, 0.1, 0.2), (1, 0, 0.5, 0, 0.25, -0.3, 0.7), (1, 3, 0.4, released, 0.0, 9.0, 9.0)]
        ),
        bid(2, 5, [(2, 1, 0.2, 0, 0.0, 1.1, -1.2), (7, 0, 0.1, 0, 0.0, 5.0, 5.0)]),  # robot 7: not of this run
        bid(0, 6, [(0, 2, 1.6, 0, 0.0, 0.15, 0.2)]),
        bid(0, 5, [(1, 0, 0.6, 0, 0.5, -0.2, 0.6)]),  # a later round's claim of robot 1 in instance 5 stands
    ]
    bus.raw.items = [(bus.keys.auction(1, m.sender), m.encode(), 0.0) for m in said]
    rec.poll()
    nothing = [np.nan] * 3
    expected = {
        (1, 5): [[f(0.1), f(0.2), 0.0], [f(-0.2), f(0.6), 0.5], [f(1.1), f(-1.2), 0.0], nothing],
        (1, 6): [[f(0.15), f(0.2), 0.0], nothing, nothing, nothing],
    }
    assert sorted(rec.bids_from.by_instance) == sorted(expected)
    for key, rows in expected.items():
        np.testing.assert_array_equal(rec.bids_from.of(key), np.array(rows, np.float32))
