"""Lock-step auction rounds over a bus that also carries damaged copies of the hosts' bids.

Every host must merge the same records in every round (agent.core.rounds): one damaged record merged
by one host and not by another splits their boards, and every block of that goal set then waits
for a round that never completes (ROUND_CAP, 30 s) before its robots hold their positions. A faulty
peer's copies (sim.emulators.faulty_peer: 1-4 random bytes overwritten) decode as well-formed bids
often enough that a 7-host paper run stalled at an image change. A bid carries a checksum, so such a
copy is dropped on arrival; and a bid whose sender is faulty (its checksum intact) naming a goal
outside the set is dropped too rather than crash the host that indexes its board with it.
"""

from __future__ import annotations

import random
import threading
import time

import numpy as np

from agent.assignment import AuctionLink, LockStepRounds
from agent.core.params import RobotParams
from transport.bus import Bus
from transport.codec import Bid, Goals, Timing, decode, with_checksum
from transport.session import client_of, loopback_router, open_session

HOSTS, PER_HOST = 4, 4
N = HOSTS * PER_HOST
TICKS = 6
FIXED = 30  # header and a bid's fixed part: its records follow


def _damage(data: bytes, rng: random.Random) -> bytes:
    """1 to 4 bytes of a bid's records overwritten, as the faulty peer's random damage does."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        at = rng.randrange(FIXED, len(out))
        out[at] = (out[at] + rng.randint(1, 255)) % 256
    return bytes(out)


def _damaging_peer(bus: Bus, stop: threading.Event, copies: list[int]) -> None:
    """Re-publish every bid heard (not our own copies) damaged, on the key it came on."""
    rng, ours = random.Random(1), set()
    inbox = bus.subscribe_raw(bus.keys.all_of("auction"))
    while not stop.is_set():
        for key, data, _ in inbox.drain():
            if data in ours or len(data) <= FIXED + 4:
                continue
            copy = _damage(data, rng)
            ours.add(copy)
            bus.put(key, copy)
            copies[0] += 1
        time.sleep(0.001)


def _hosts(router, params: RobotParams, told: dict[int, int]) -> tuple[list[Bus], list[AuctionLink]]:
    buses = [Bus(client_of(router), "integrity") for _ in range(HOSTS)]
    links = [
        AuctionLink(
            bus,
            list(range(h * PER_HOST, (h + 1) * PER_HOST)),
            params,
            lambda e, i, g, p, c: told.update(g),
            lockstep=LockStepRounds(),
        )
        for h, bus in enumerate(buses)
    ]
    return buses, links


def test_damaged_copies_of_bids_are_dropped_and_every_host_keeps_the_same_board():
    rng = np.random.default_rng(2)
    goals, position = rng.uniform(-3.0, 3.0, (N, 2)), rng.uniform(-3.0, 3.0, (N, 2))
    params = RobotParams(kinematics="holonomic")
    message = Goals(1, 0, goals, np.full((N, 3), 200, np.uint8), np.arange(N), Timing(0.0, 0, 60.0))
    router = loopback_router()
    session = open_session(router)
    stop, copies, told = threading.Event(), [0], {}
    try:
        with Bus(client_of(router), "integrity") as peer_bus:
            peer = threading.Thread(target=_damaging_peer, args=(peer_bus, stop, copies), daemon=True)
            peer.start()
            buses, links = _hosts(router, params, told)
            try:
                time.sleep(0.5)  # every subscription declared before the first round
                for link in links:
                    link.on_goals(message, {})
                for tick in range(TICKS):
                    where = {r: position[r] for r in range(N)}
                    threads = [
                        threading.Thread(target=link.on_tick, args=(tick * params.assign_period, where))
                        for link in links
                    ]
                    for t in threads:
                        t.start()
                    for t in threads:
                        t.join(timeout=60.0)
                    assert not any(t.is_alive() for t in threads), f"a host still waits in tick {tick}"
                    assert [link.counts.abandoned for link in links] == [0] * HOSTS, f"tick {tick}"
                    for link in links[1:]:
                        np.testing.assert_array_equal(link.part.board.owner, links[0].part.board.owner)
                        np.testing.assert_array_equal(link.part.board.price, links[0].part.board.price)
                    for robot, goal in told.items():  # the robots move toward their goals between blocks
                        position[robot] += 0.5 * (goals[goal] - position[robot])
                assert sorted(told) == list(range(N)) and len(set(told.values())) == N  # one-to-one
                checksum_drops = sum(link.inbox.drops["checksum"] for link in links)
                assert copies[0] > 0 and checksum_drops > 0, (copies, checksum_drops)
            finally:
                for bus in buses:
                    bus.close()
            stop.set()
            peer.join(timeout=5.0)
    finally:
        session.close()


def test_a_bid_naming_a_goal_outside_the_set_is_dropped_before_and_after_its_set_arrives():
    """A faulty host's bid, intact on the wire: goal 59146 of 16 indexed the board (IndexError in
    BlockRounds.quiet: the host's process died). It is counted and dropped whether it came before the
    goal set (filed, then weeded out when the set arrives) or after."""
    params = RobotParams(kinematics="holonomic")
    rng = np.random.default_rng(3)
    message = Goals(
        1, 0, rng.uniform(-3.0, 3.0, (N, 2)), np.full((N, 3), 200, np.uint8), np.arange(N), Timing(0.0, 0, 60.0)
    )
    records = np.zeros(1, Bid.RECORD)
    records["robot"], records["goal"], records["price"] = 4, 59146, 1.0
    wire = with_checksum(Bid(1, 0, 4, 1, 0, 1, records).encode()[:-4])
    forged = decode(wire, Bid)
    assert forged is not None  # intact: only the goal set can tell it is wrong
    router = loopback_router()
    session = open_session(router)
    try:
        with Bus(client_of(router), "integrity") as bus:
            link = AuctionLink(bus, [0, 1, 2, 3], params, lambda *_: None, lockstep=LockStepRounds())
            link.exchange.file([("key", forged)])  # before the goal set: no way to tell yet
            assert link.exchange.records[(1, 0, 1)] == {4: forged}
            link.on_goals(message, {})
            assert link.exchange.records[(1, 0, 1)] == {} and link.inbox.drops["inconsistent"] == 1
            link.exchange.file([("key", forged)])
            assert link.exchange.records[(1, 0, 1)] == {} and link.inbox.drops["inconsistent"] == 2
    finally:
        session.close()
