"""A host's neighbour table (agent.neighbour_table): which broadcast states each of its robots steers by."""
from __future__ import annotations

import numpy as np

from agent.core.bidder import bid_position
from agent.neighbour_table import NeighbourTable
from transport.codec import State


def _state(robot: int, x: float, y: float, tick: int = 1) -> State:
    return State(robot, tick, 0.1 * tick, x, y, 0.01 * robot, 0.0, 0.05, 0.0, 0.0, -1, 0, 0, 0)


def test_each_robot_gets_its_nearest_neighbours_in_reach_ties_broken_by_id():
    """For a host's whole batch at once: not itself, only within the neighbour distance, at most
    max_neighbours, nearest first, equal distances in id order (every process must break ties alike,
    or a lock-step run would depend on how robots are spread over hosts)."""
    rng = np.random.default_rng(3)
    table = NeighbourTable()
    points = np.round(rng.uniform(-1.5, 1.5, (120, 2)) * 10) / 10  # a grid: many equal distances
    ids = rng.permutation(400)[:120]
    for robot, (x, y) in zip(ids, points):
        table.update(_state(int(robot), float(x), float(y)))
    own = [int(r) for r in ids[:30]] + [999]
    here = np.vstack([points[:30], [[0.05, 0.05]]])
    reach, m = 0.7, 6
    got = table.gather(own, here, stamp=0.2, tick=2, neighbour_dist=reach, max_neighbours=m)
    by_id = dict(zip(ids.tolist(), points))
    for b, (rid, p) in enumerate(zip(own, here)):
        others = sorted((float(((q - p) ** 2).sum()), int(r)) for r, q in by_id.items() if r != rid)
        expect = [r for d2, r in others if d2 <= reach**2][:m]
        k = int(got.valid[b].sum())
        assert k == len(expect) and got.valid[b, :k].all()
        assert np.allclose(got.position[b, :k], [by_id[r] for r in expect])
        assert np.allclose(got.velocity[b, :k, 0], [0.01 * r for r in expect])  # the states of those robots


def test_bid_positions_of_a_batch_are_those_of_each_robot():
    rng = np.random.default_rng(5)
    position, goal, velocity = rng.uniform(-1, 1, (3, 40, 2))
    goal[0] = position[0]  # on its goal
    velocity[1] = 0.0  # blocked
    batch = bid_position(position, goal, velocity, lead=2.5)
    assert np.array_equal(batch, [bid_position(p, g, v, lead=2.5) for p, g, v in zip(position, goal, velocity)])
