"""The goal auction over a limited communication range (agent.core.local_auction, issue 23): a robot
hears only robots within reach, prices and owners spread over the graph by max-consensus, and each
robot learns for itself that the auction ended. Checked here in one process and through the wire
format the agent hosts exchange (transport.codec.Boards)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import connected_components

from agent.assignment import _boards, _words
from agent.core.local_auction import LocalAuction, Words
from sim.central.engine import settle_in_process
from transport.codec import Boards, decode

EPS = 1e-3


def _instance(seed: int, n: int, side: float = 1.6) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(0, side, (n, 2)), rng.uniform(0, side, (n, 2))


def _parts(position: np.ndarray, reach: float) -> np.ndarray:
    xy = position.astype(np.float32).astype(float)
    near = ((xy[:, None] - xy[None]) ** 2).sum(-1) <= reach * reach
    return connected_components(near, directed=False)[1]


def _cost(position: np.ndarray, goals: np.ndarray) -> np.ndarray:
    return ((position[:, None] - goals[None]) ** 2).sum(-1)


def _agreed(auction: LocalAuction) -> np.ndarray:
    return np.array([auction.agreed[r] for r in sorted(auction.agreed)])


@pytest.mark.parametrize("seed, n, reach", [(1, 30, 0.45), (2, 60, 0.4), (3, 20, 0.6)])
def test_a_connected_graph_agrees_one_to_one_within_n_epsilon_of_the_optimum(seed, n, reach):
    position, goals = _instance(seed, n)
    assert len(np.unique(_parts(position, reach))) == 1  # the instance is connected at this reach
    auction = LocalAuction(1, goals, list(range(n)), list(range(n)), EPS, 0.0, reach)
    settle_in_process(auction, position)
    goal = _agreed(auction)
    assert len(np.unique(goal)) == n
    cost = _cost(position, goals)
    rows, cols = linear_sum_assignment(cost)
    assert cost[np.arange(n), goal].sum() <= cost[rows, cols].sum() + n * EPS + 1e-9


def test_nobody_hears_anyone_out_of_reach():
    """Two robots out of each other's reach never merge each other's records: on a graph of two
    isolated robots, each takes the goal best for itself, the same one."""
    goals = np.array([[0.0, 0.0], [5.0, 5.0]])
    position = np.array([[0.1, 0.0], [-0.1, 0.0]])
    auction = LocalAuction(1, goals, [0, 1], [0, 1], EPS, 0.0, reach=0.1)
    settle_in_process(auction, position)
    assert auction.agreed == {0: 0, 1: 0}
    auction = LocalAuction(1, goals, [0, 1], [0, 1], EPS, 0.0, reach=0.25)  # in reach: one each
    settle_in_process(auction, position)
    assert sorted(auction.agreed.values()) == [0, 1]


def test_a_split_graph_is_one_to_one_within_each_part():
    position, goals = _instance(4, 40)
    reach = 0.15
    part = _parts(position, reach)
    assert len(np.unique(part)) > 5
    auction = LocalAuction(1, goals, list(range(40)), list(range(40)), EPS, 5e-3, reach)
    settle_in_process(auction, position)
    goal = _agreed(auction)
    for p in np.unique(part):
        assert len(np.unique(goal[part == p])) == int((part == p).sum()), p


def test_a_part_keeps_its_goals_when_the_graph_splits_and_the_robots_move():
    """After a connected agreement the robots drift apart: each part trades only its own goals, so
    the swarm stays one-to-one although no part hears the others."""
    position, goals = _instance(5, 30)
    auction = LocalAuction(1, goals, list(range(30)), list(range(30)), EPS, 5e-3, 0.5)
    settle_in_process(auction, position)
    first = _agreed(auction)
    assert len(np.unique(first)) == 30
    rng = np.random.default_rng(5)
    for _ in range(5):
        position = position + 0.3 * (goals[first] - position) + rng.normal(0, 0.05, position.shape)
        auction.reach = 0.2  # the graph falls apart
        settle_in_process(auction, position)
        assert len(np.unique(_parts(position, 0.2))) > 1
        assert len(np.unique(_agreed(auction))) == 30


def test_a_reach_that_covers_the_swarm_agrees_as_everyone_hearing_everyone():
    position, goals = _instance(6, 25)
    cost = _cost(position, goals)
    rows, cols = linear_sum_assignment(cost)
    auction = LocalAuction(1, goals, list(range(25)), list(range(25)), EPS, 0.0, reach=100.0)
    settle_in_process(auction, position)
    goal = _agreed(auction)
    assert len(np.unique(goal)) == 25
    assert cost[np.arange(25), goal].sum() <= cost[rows, cols].sum() + 25 * EPS + 1e-9


def test_hosts_exchanging_boards_on_the_wire_agree_as_one_process():
    """The robots split over four hosts, each saying its words as the Boards message an agent host
    publishes and hearing the others' decoded: every round, every board and the agreement are the
    central engine's (one process holding every robot)."""
    position, goals = _instance(7, 24)
    reach, robots = 0.5, list(range(24))
    central = LocalAuction(3, goals, robots, robots, EPS, 5e-3, reach)
    hosts = [LocalAuction(3, goals, robots, robots[h::4], EPS, 5e-3, reach) for h in range(4)]
    for block in range(3):
        at = position + 0.1 * block
        rounds = settle_in_process(central, at)
        for host in hosts:
            host.begin_block(at)
        while not all(h.done for h in hosts):
            said = [(h, h.say()) for h in hosts]
            sent = [decode(_boards(h, w, h.own[0]).encode(), Boards) for h, w in said]
            for i, (host, words) in enumerate(said):
                if host.ended.all() and host.done:
                    continue
                theirs = [_words(m, host) for j, m in enumerate(sent) if j != i and m is not None]
                host.hear(Words.join([words, *theirs]))
        assert max(h.round for h in hosts) == rounds
        agreed = {r: g for h in hosts for r, g in h.agreed.items()}
        assert agreed == central.agreed
        for h in hosts:
            rows = np.searchsorted(central.own_ids, h.own_ids)
            np.testing.assert_array_equal(h.price, central.price[rows])
            np.testing.assert_array_equal(h.owner, central.owner[rows])


def test_a_malformed_boards_message_is_dropped():
    position, goals = _instance(8, 6)
    auction = LocalAuction(1, goals, list(range(6)), list(range(6)), EPS, 0.0, 1.0)
    auction.begin_block(position)
    payload = _boards(auction, auction.say(), 0).encode()
    assert decode(payload, Boards) is not None
    assert decode(payload[:-3], Boards) is None  # truncated
    msg = decode(payload, Boards)
    assert msg is not None and len(msg.records) > 0
    for goal in (99, -1):  # a goal the set does not have
        msg.records["goal"][0] = goal
        assert decode(msg.encode(), Boards) is None
    msg.records["goal"][0] = 0
    msg.records["price"][0] = np.nan
    assert decode(msg.encode(), Boards) is None


def test_more_robots_than_goals_is_refused():
    with pytest.raises(ValueError, match="one to one"):
        LocalAuction(1, np.zeros((2, 2)), [0, 1, 2], [0], EPS, 0.0, 1.0)
