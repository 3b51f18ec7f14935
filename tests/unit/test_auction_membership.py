"""Who takes part in a goal set's lock-step auction is the goal set's to say (transport.codec.Lives), the same
for every host, not each host's liveliness view at the moment it takes the set up.

An agent killed and started again once hung a lock-step run: the restart's liveliness reached some hosts
only after they took up the set the coordinator published for it, so they left its robot out of the rounds
while another host, and the agent itself, waited for them in rounds the rest had left."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from agent.runtime import AgentHost, Departures
from transport.codec import Goals, Lives, Timing, life_number

ROBOTS = 5
RESTARTED = 4
OLD, NEW = "0000a001", "0000b002"  # the restarted robot's agent's lives (Bus.incarnation)
OTHERS = [f"0000c00{r}" for r in range(ROBOTS - 1)]


class Liveliness:
    """A LivelinessWatch whose events the test queues."""

    def __init__(self) -> None:
        self.queued: list[tuple[str, str, bool, float, str]] = []

    def drain(self) -> list[tuple[str, str, bool, float, str]]:
        out, self.queued = self.queued, []
        return out


def goal_set(epoch: int, restarted_life: str | None) -> Goals:
    """A set of every robot; ``restarted_life``: the life it lists for RESTARTED (None: no lives listed)."""
    lives = None
    if restarted_life is not None:
        lives = Lives(np.array([life_number(x) for x in [*OTHERS, restarted_life]]))
    return Goals(
        epoch, 0, np.zeros((ROBOTS, 2)), np.zeros((ROBOTS, 3), np.uint8), np.arange(ROBOTS), Timing(), lives=lives
    )


def two_hosts() -> tuple[Departures, Departures, Liveliness]:
    """Two hosts that heard every agent start; the restart (death, new life) reached ``early`` before it took
    a set up and is still queued at ``late``'s, whose events are returned."""
    started = [("agent", str(r), True, 0.0, life) for r, life in enumerate([*OTHERS, OLD])]
    restart = [("agent", str(RESTARTED), False, 0.0, OLD), ("agent", str(RESTARTED), True, 0.0, NEW)]
    hosts, queues = [], []
    for heard_restart in (True, False):
        queue = Liveliness()
        host = Departures(queue)
        queue.queued = list(started)
        host.now()
        queue.queued = list(restart)
        if heard_restart:
            host.now()
        hosts.append(host)
        queues.append(queue)
    return hosts[0], hosts[1], queues[1]


def test_every_host_waits_for_a_restarted_agent_in_the_set_that_lists_its_new_life():
    early, late, _ = two_hosts()
    for host in (early, late):
        host.new_goal_set(goal_set(2, NEW))
    assert early.not_bidding() == late.not_bidding() == set()


def test_no_host_waits_for_it_in_a_set_that_lists_its_old_life():
    early, late, _ = two_hosts()
    for host in (early, late):
        host.new_goal_set(goal_set(2, OLD))
    assert early.not_bidding() == late.not_bidding() == {RESTARTED}


def test_a_set_without_lives_is_taken_up_after_the_liveliness_that_came_before_it():
    """Sets that list no lives (as before them): each host takes in what liveliness told before the set."""
    early, late, queue = two_hosts()
    assert queue.queued, "the restart is still queued at the late host"
    for host in (early, late):
        host.new_goal_set(goal_set(2, None))
    assert early.not_bidding() == late.not_bidding() == set()
    assert early.gone == late.gone == set()


def test_a_robot_that_dies_during_a_set_is_not_waited_for_even_once_back():
    early, _, _ = two_hosts()
    early.new_goal_set(goal_set(2, NEW))
    early.alive.queued = [("agent", str(RESTARTED), False, 0.0, NEW)]
    assert early.not_bidding() == {RESTARTED}
    early.alive.queued = [("agent", str(RESTARTED), True, 0.0, "0000d003")]
    assert early.not_bidding() == {RESTARTED}  # a third life: the set's auction goes on without it
    early.alive.queued = [("agent", str(RESTARTED), True, 0.0, NEW)]
    assert early.not_bidding() == set()  # the life the set lists, back (a blip of its connection)


def test_an_agent_bids_only_in_a_set_that_lists_it_in_this_life():
    host = SimpleNamespace(
        bus=SimpleNamespace(incarnation=NEW),
        robots=SimpleNamespace(ids=np.array([RESTARTED])),
        goal_sets=SimpleNamespace(bid_from=3),
    )
    assert not AgentHost._takes_part(host, goal_set(2, OLD))
    assert AgentHost._takes_part(host, goal_set(2, NEW))
    assert AgentHost._takes_part(host, goal_set(2, "not-a-life"))  # 0: any life
    # a set that lists no lives: as before, only those published after this agent joined
    assert not AgentHost._takes_part(host, goal_set(2, None))
    assert AgentHost._takes_part(host, goal_set(3, None))
