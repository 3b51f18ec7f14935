"""The faulty peer's copies (sim.emulators.faulty_peer), made in process from messages it heard: a
forged tick reaches the receiver's judgement of ticks, a damaged copy is stopped by the codec."""

from __future__ import annotations

import pytest

from sim.emulators.faulty_peer import FaultyPeer, PeerPlan
from transport.codec import DropCounter, State, States, decode
from transport.keys import Keys
from transport.plausible import AHEAD, stamp_agrees
from transport.session import ZenohSettings

HEARD = State(3, 40, 4.0, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL, 2, 9)


def copies(mode: str, count: int = 50) -> list[bytes]:
    """``count`` copies the peer makes in ``mode`` of one state it heard (no session is opened)."""
    peer = FaultyPeer(ZenohSettings(), plan=PeerPlan(mode=mode, seed=1))
    peer.heard["state"].append((Keys("default").state((0, 0), 3), States.one(HEARD).encode()))
    made = [peer.make_copy(now=25.0) for _ in range(count)]
    return [copy[1] for copy in made if copy is not None]


@pytest.mark.parametrize("mode", ["future-state", "restart"])
def test_a_state_forged_with_another_tick_is_intact_and_the_rest_of_it_is_what_was_heard(mode):
    made = copies(mode)
    assert made
    (heard,) = decode(States.one(HEARD).encode(), States).messages()  # its numbers as f32, as sent
    for data in made:
        frame = decode(data, States)
        assert frame is not None  # sealed again: the receiver judges its tick, not its checksum
        (state,) = frame.messages()
        assert (state.tick > HEARD.tick) if mode == "future-state" else (state.tick < HEARD.tick)
        # its stamp moved with its tick (else the stamp check would stop it), the rest as heard
        assert stamp_agrees(state.tick, state.stamp, HEARD.stamp / HEARD.tick)
        assert {**vars(state), "tick": HEARD.tick, "stamp": HEARD.stamp} == vars(heard)
    if mode == "future-state":  # beyond the ticks a receiver's clock allows (only poses come nearer)
        assert all(decode(data, States).messages()[0].tick > HEARD.tick + AHEAD for data in made)


def test_a_state_damaged_at_random_is_dropped_by_the_codec():
    drops = DropCounter()
    made = copies("malformed-all", count=200)
    assert len(made) > 100
    assert all(decode(data, States, drops) is None for data in made)
    assert drops["checksum"] > 0 and set(drops) <= {"truncated", "version", "kind", "checksum"}
