"""Lock-step: a host that gave up an auction block says so, and the coordinator answers with a new goal set,
cold, for the same robots. The hosts' blocks may have parted for good (one gave up a block the others
finished, or took up a goal set at a tick another never stepped): every tick then waited ROUND_CAP."""

from __future__ import annotations

import time

import numpy as np
import pytest

from coordinator import service
from coordinator.scene import scene_from_dict
from tests.support.fake_bus import Bus
from transport.codec import BLOCK_ABANDONED, Event, Tick
from transport.plausible import GoalSets


def started(clock: str) -> tuple[service.Coordinator, Bus]:
    grid = {"kind": "grid", "spacing": 0.2}
    scene = scene_from_dict(
        {"robots": 4, "seed": 5, "clock": clock, "layout": grid, "steps": [{"shape": "disk", "hold": 30}]}
    )
    bus = Bus()
    coordinator = service.Coordinator(bus, scene)
    bus.alive.items = [("agent", str(r), True, 0.0, "0000000a") for r in range(4)]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    assert coordinator._follow_show() and bus.published[-1].epoch == 1
    return coordinator, bus


def gave_up(epoch: int, robots: list) -> tuple[str, Event]:
    return ("px/default/event/2", Event({"kind": BLOCK_ABANDONED, "epoch": epoch, "robots": robots}))


def test_a_block_given_up_in_the_current_set_brings_a_new_cold_set_once():
    coordinator, bus = started("lockstep")
    bus.events.items = [gave_up(1, [2, 3]), gave_up(1, [0, 1])]  # both hosts gave up
    assert not coordinator._follow_show()  # debounced, as a change in the live robots
    time.sleep(service.SETTLE_S + 0.05)
    # at once, though the world's clock has not gone on (its hosts wait for this set to leave their round)
    assert coordinator._follow_show()
    first, new = bus.published[-2:]
    assert new.epoch == 2 and new.robots.tolist() == [0, 1, 2, 3] and new.warm_start is None
    # the same set, cold, at the same stamp would be refused as a replay: it is stamped just past the first
    believed = GoalSets(newest=0)
    assert believed.admit(first, now=0.0) is None and believed.admit(new, now=0.0) is None
    assert new.timing.stamp == np.nextafter(first.timing.stamp, np.inf)
    assert not coordinator._follow_show()  # one set for both hosts' word
    bus.events.items = [gave_up(1, [2, 3])]  # late word of the set before: that set is gone already
    time.sleep(service.SETTLE_S + 0.05)
    assert not coordinator._follow_show()


@pytest.mark.parametrize(
    "event",
    [
        gave_up(1, [7, 9]),  # robots this run has no agent for
        gave_up(1, "2"),  # not a list
        gave_up(5, [2]),  # an epoch not published
        ("px/default/event/2", Event({"kind": "stats", "epoch": 1, "robots": [2]})),
    ],
)
def test_word_of_no_block_of_the_current_set_brings_no_new_set(event):
    coordinator, bus = started("lockstep")
    bus.events.items = [event]
    time.sleep(service.SETTLE_S + 0.05)
    assert not coordinator._follow_show() and bus.published[-1].epoch == 1


def test_in_real_time_nobody_listens():
    """A real-time auction has no blocks to give up: its instances run on, whatever a message says."""
    coordinator, bus = started("realtime")
    assert coordinator.agent_events is None


def test_a_robot_back_at_a_step_takes_one_more_set_after_the_steps():
    """The world may have sent the step's first tick before the robot was heard back: its host takes the step's
    set up a tick later than the others. A second cold set, named by a tick that every host steps, joins them."""
    coordinator, bus = started("lockstep")
    coordinator.scene = scene_from_dict(
        {
            "robots": 4,
            "seed": 5,
            "clock": "lockstep",
            "layout": {"kind": "grid", "spacing": 0.2},
            "steps": [{"shape": "disk", "hold": 30}, {"shape": "ring", "hold": 30}],
        }
    )
    bus.alive.items = [("agent", "2", False, 0.0, "0000000a"), ("agent", "2", True, 0.0, "0000000a")]
    assert not coordinator._follow_show()
    time.sleep(service.SETTLE_S + 0.05)
    bus.clock.items = [("clock", Tick(k, k * 0.1, 0.1)) for k in range(1, 302)]  # into the second step
    assert coordinator._follow_show() and bus.published[-1].timing.step == 1  # the step's, as ever
    assert coordinator._follow_show() and bus.published[-1].epoch == 3 and bus.published[-1].timing.step == 1
    step_set, cold = bus.published[-2:]
    assert step_set.warm_start is not None and cold.warm_start is None  # else the same set: a replay
    assert not coordinator._follow_show()
