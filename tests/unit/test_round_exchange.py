"""Lock-step rounds on the bus (agent.assignment.RoundExchange): a host keeps its messages of the last
block while it begins the next. With rounds per tick bounded a block's final round is heard at the
next tick, where a host that lost a message of it still waits, asking again, while the others, who
heard everything, may begin the next block at that very tick: forgotten, the message it asks for
never comes and every host waits out ROUND_CAP (30 s) at every such block."""

from __future__ import annotations

import time

from agent.assignment import ROUND_RESEND, AuctionCounts, RoundExchange
from tests.support.fake_bus import Bus, Inbox
from transport.codec import Bid

EPOCH = 1


def _bid(sender: int, block: int, round_: int) -> Bid:
    return Bid(EPOCH, block, sender, round_, 0, 0)


def test_a_host_that_began_the_next_block_still_answers_for_the_last_blocks_final_round() -> None:
    bus = Bus()
    exchange = RoundExchange(bus, [0], Inbox(), AuctionCounts(), keeps=lambda msg: True)
    exchange.open((EPOCH, 2, 1), _bid(0, 2, 1), speak=True)  # block 2's first and final round
    exchange.close((EPOCH, 2, 1), {0}, lambda msg: [msg.sender], ROUND_RESEND)  # heard: agreed
    exchange.open((EPOCH, 5, 1), _bid(0, 5, 1), speak=True)  # the next block, at the same tick
    sent = len(bus.published)
    time.sleep(ROUND_RESEND)  # an answer waits this long after our last sending
    exchange.file([("auction", _bid(1, 2, 1))])  # host 1 lost our block-2 message: it asks again
    assert len(bus.published) == sent + 1
    assert (bus.published[-1].instance, bus.published[-1].serial) == (2, 1)  # our block-2 message again
    # two blocks back is forgotten: hosts are at most one block apart
    exchange.close((EPOCH, 5, 1), {0}, lambda msg: [msg.sender], ROUND_RESEND)
    exchange.open((EPOCH, 8, 1), _bid(0, 8, 1), speak=True)
    assert {key[1] for key in exchange.said} == {5, 8}
