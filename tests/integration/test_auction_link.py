"""The goal auction on the bus (agent.assignment.AuctionLink), two hosts over a real zenoh router on
loopback: when another host's message shows that the instance agreed and the next block began, the
agreement reaches the robots before this host freezes the new block's positions.

Regression: a host froze the next block from positions taken before it had handed the agreement
over, so its robots bid from their old goals (their velocity still pointed there), the next
agreement sent them back, and four robots of 100 rotated goals every block (25 s in one run)."""

from __future__ import annotations

import time

import numpy as np

from agent.assignment import AuctionLink
from agent.core.params import RobotParams
from transport.bus import Bus
from transport.codec import Goals, Timing
from transport.session import client_of, loopback_router, open_session

GOALS = np.array([[0.0, 0.0], [4.0, 0.0]])
START = {0: np.array([0.5, 0.0]), 1: np.array([3.5, 0.0])}


class Host:
    """The runtime's side of one host, reduced to what the link asks of it: where its robots bid from
    (at their agreed goal once they have one, as a robot far on its way is led there) and what it is told."""

    def __init__(self, bus: Bus, robot: int, params: RobotParams) -> None:
        self.robot, self.goal = robot, None
        self.told: list[tuple[int, int]] = []  # (instance, goal) handed to the robot
        self.link = AuctionLink(bus, [robot], params, self.on_agreed, where=self.where)

    def where(self) -> dict[int, np.ndarray]:
        return {self.robot: GOALS[self.goal] if self.goal is not None else START[self.robot]}

    def on_agreed(self, epoch: int, instance: int, goals: dict[int, int], positions, colors) -> None:
        self.goal = goals[self.robot]
        self.told.append((instance, self.goal))


def test_the_next_block_freezes_where_the_agreement_sent_the_robots() -> None:
    params = RobotParams(kinematics="holonomic")
    goals = Goals(1, 0, GOALS, np.full((2, 3), 200, np.uint8), np.arange(2), Timing(0.0, 0, 60.0))
    router = loopback_router()
    session = open_session(router)
    try:
        _two_hosts(router, goals, params)
    finally:
        session.close()


def _two_hosts(router, goals: Goals, params: RobotParams) -> None:
    with Bus(client_of(router), "link") as bus_a, Bus(client_of(router), "link") as bus_b:
        a, b = Host(bus_a, 0, params), Host(bus_b, 1, params)
        time.sleep(0.5)  # both subscriptions declared before the first bid
        for h in (a, b):
            h.link.on_goals(goals, h.where())
        first_told = None
        end = time.monotonic() + 20.0
        while first_told is None and time.monotonic() < end:
            for h in (a, b):
                h.link.poll(h.where())
                if h.told:
                    first_told = h
                    break
            time.sleep(0.01)
        assert first_told is not None, "the two hosts did not agree within 20 s"
        # x agreed and starts the next block at once; y has not polled since and learns it from x
        x, y = (a, b) if first_told is a else (b, a)
        phases, agreed = x.link.part.phases, x.link.part.agreed_instance
        assert not y.told and (agreed + 1) % phases == 0
        x.link.on_tick(1.0, x.where())
        stale = {y.robot: START[y.robot]}  # what y's runtime had computed before the agreement reached it
        time.sleep(1.0)  # x's last word on the agreed instance and its first of the next arrive: one poll takes both
        y.link.poll(stale)
        assert y.link.part.instance // phases == agreed // phases + 1, "y is not in the next block"
        assert y.told[:1] == [(agreed, y.robot)], "the agreement was not handed over when the next block began"
        np.testing.assert_allclose(y.link.part.position, [GOALS[y.robot]])  # frozen from where(), after the hand-over
