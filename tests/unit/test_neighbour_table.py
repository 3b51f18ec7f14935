"""A host's neighbour table (agent.neighbour_table): which broadcast states each of its robots steers by."""

from __future__ import annotations

import dataclasses
import math
from functools import partial
from types import SimpleNamespace

import numpy as np

from agent.core.control import touch_reach
from agent.core.grid import unheard
from agent.core.params import EPUCK
from agent.core.step import settings_of
from agent.loop import Sensed
from agent.neighbour_table import NeighbourTable, TrackedBodies
from agent.runtime import bid_position
from transport.codec import BEFORE_START, Poses, State


def _sensed(ids, position, stamp: float, tick: int, max_neighbours: int = 10) -> Sensed:
    n, p = len(ids), dataclasses.replace(EPUCK, max_neighbours=max_neighbours)
    return Sensed(np.array(ids), np.asarray(position, float), np.zeros(n), tick, stamp, p, np.zeros(n, bool))


def _gather(table, ids, position, stamp, tick, neighbour_dist, max_neighbours, stopped=None):
    """NeighbourTable.gather for a batch of ``ids`` at ``position`` stepping ``tick`` at ``stamp``."""
    return table.gather(_sensed(ids, position, stamp, tick, max_neighbours), neighbour_dist, stopped or {}, None)


def _state(robot: int, x: float, y: float, tick: int = 1) -> State:
    return State(robot, tick, 0.1 * tick, x, y, 0.01 * robot, 0.0, 0.05, 0.0, 0.0, -1, 0, 0, 0)


def test_each_robot_gets_its_nearest_neighbours_in_reach_ties_broken_by_id():
    """For a host's whole batch at once: not itself, only within the neighbour distance, at most
    max_neighbours, nearest first, equal distances in id order (every process must break ties alike,
    or a lock-step run would depend on how robots are spread over hosts)."""
    rng = np.random.default_rng(3)
    table = NeighbourTable(0.1)
    points = np.round(rng.uniform(-1.5, 1.5, (120, 2)) * 10) / 10  # a grid: many equal distances
    ids = rng.permutation(400)[:120]
    for robot, (x, y) in zip(ids, points):
        table.update(_state(int(robot), float(x), float(y)))
    own = [int(r) for r in ids[:30]] + [999]
    here = np.vstack([points[:30], [[0.05, 0.05]]])
    reach, m = 0.7, 6
    got = _gather(table, own, here, 0.2, 2, reach, m)
    by_id = dict(zip(ids.tolist(), points))
    for b, (rid, p) in enumerate(zip(own, here)):
        others = sorted((float(((q - p) ** 2).sum()), int(r)) for r, q in by_id.items() if r != rid)
        expect = [r for d2, r in others if d2 <= reach**2][:m]
        k = int(got.valid[b].sum())
        assert k == len(expect) and got.valid[b, :k].all()
        assert np.allclose(got.position[b, :k], [by_id[r] for r in expect])
        assert np.allclose(got.velocity[b, :k, 0], [0.01 * r for r in expect])  # the states of those robots


def test_a_large_batch_finds_the_neighbours_each_robot_finds_alone():
    """A host of hundreds of robots gathers for all of them at once (one grid over the states, where
    it once took its candidates from a k-d tree); the pairs, their order and every gathered array
    must be those each robot gets alone, ties (a grid of positions) and pairs at exactly the
    neighbour distance included."""
    rng = np.random.default_rng(11)
    table = NeighbourTable(0.1)
    points = np.round(rng.uniform(-2.0, 2.0, (400, 2)) * 10) / 10
    ids = rng.permutation(1000)[:400]
    for robot, (x, y) in zip(ids, points):
        table.update(_state(int(robot), float(x), float(y)))
    own, here = [int(r) for r in ids[:90]], points[:90]
    names = ("position", "velocity", "radius", "age", "valid", "cooperative")
    got = _gather(table, own, here, 0.2, 2, 0.5, 8)
    assert got.valid.sum() > 500  # many neighbours, many of them at equal distances
    d2 = ((points[:, None, :] - here[None]) ** 2).sum(axis=2)
    assert (np.abs(d2 - 0.25) < 1e-12).any()  # some exactly at the neighbour distance
    for b, (rid, p) in enumerate(zip(own, here)):
        alone = _gather(table, [rid], p[None, :], 0.2, 2, 0.5, 8)
        for name in names:
            np.testing.assert_array_equal(getattr(alone, name), getattr(got, name)[b : b + 1], err_msg=name)


def test_one_robot_gathers_bit_for_bit_what_it_gets_in_a_batch():
    """A process of one robot gathers with a batch of one (agent.core.grid.nearest): every
    array must equal that robot's row of a batch's, ties, dead robots' bodies and dynamic
    obstacles included, so a robot steers alike whatever host it runs in."""
    rng = np.random.default_rng(5)
    table = NeighbourTable(0.1)
    points = np.round(rng.uniform(-1.0, 1.0, (60, 2)) * 10) / 10 + np.float32(1e-3)
    ids = rng.permutation(200)[:60]
    for robot, (x, y) in zip(ids, points):
        s = _state(int(robot), float(np.float32(x)), float(np.float32(y)))
        s.flags = State.DYNAMIC if robot % 7 == 0 else 0
        s.stamp = 0.1 - 0.013 * (robot % 5)
        table.update(s)
    stopped = {int(r): 0.012 for r in ids[::9]}
    own, here = [int(r) for r in ids[:20]], points[:20] + 0.01
    for reach, m in [(0.7, 6), (0.25, 10), (0.01, 4)]:
        batch = _gather(table, own + [999], np.vstack([here, [[9.0, 9.0]]]), 0.2, 2, reach, m, stopped)
        if reach == 0.7:  # many neighbours, dynamic ones among them
            assert batch.valid.sum() > 50 and not batch.cooperative[batch.valid].all()
        for b, (rid, p) in enumerate(zip(own, here)):
            one = _gather(table, [rid], p[None, :], 0.2, 2, reach, m, stopped)
            for name in ("position", "velocity", "radius", "age", "valid", "cooperative"):
                got, expect = getattr(one, name), getattr(batch, name)[b : b + 1]
                assert got.dtype == expect.dtype and got.shape == expect.shape
                np.testing.assert_array_equal(got, expect)


def test_a_robot_whose_states_are_lost_is_seen_where_the_tracker_sees_it():
    """A neighbour never heard, or not heard for longer than stale_after, is taken from the tracker's
    frame (with_bodies): where it was seen, standing, not cooperating and stale by one tick, so robots
    steer around it and stand where it may touch them (agent.core.control); one heard lately keeps
    its state, and a body beyond the neighbour distance is not a neighbour."""
    table = NeighbourTable(0.1)
    table.update(_state(1, 0.3, 0.0, tick=10))  # heard at the tick before: fresh
    table.update(_state(2, 0.0, 0.3, tick=2))  # 0.9 s ago: stale, and since moved
    bodies = np.zeros(5, Poses.RECORD)  # robot 0's own body, 3 never heard, 4 too far
    bodies["robot"] = [0, 1, 2, 3, 4]
    bodies["x"], bodies["y"] = [0.0, 0.31, 0.0, -0.2, 3.0], [0.0, 0.0, 0.2, 0.0, 0.0]
    got = table.gather(_sensed([0], [[0.0, 0.0]], 1.1, 11), 1.0, {}, bodies)
    valid = got.valid[0]
    order = np.lexsort(got.position[0, valid].T[::-1])  # by x
    stale = EPUCK.stale_after + EPUCK.dt
    np.testing.assert_allclose(got.position[0, valid][order], [[-0.2, 0.0], [0.0, 0.2], [0.3, 0.0]], atol=1e-7)
    np.testing.assert_allclose(got.velocity[0, valid][order], [[0.0, 0.0], [0.0, 0.0], [0.01, 0.0]])
    np.testing.assert_allclose(got.age[0, valid][order], [stale, stale, 0.1])
    assert got.cooperative[0, valid][order].tolist() == [False, False, True]
    assert got.age[0, valid].min() <= EPUCK.stale_after < got.age[0, valid].max()  # the core's own rule of stale


def test_a_state_the_tracker_contradicts_or_a_robot_smaller_than_the_display_s_is_not_believed():
    """A robot driven by someone else than its agent, or a forged state, is not where its state says: a
    body farther from its state than it could have driven since (v_max) and a radius is taken from the
    tracker's frame as one whose states were lost; and no state makes a robot smaller than the display's
    robots (a forged radius of 0.1 mm let robots drive into it)."""
    table = NeighbourTable(0.1)
    table.update(_state(1, 0.3, 0.0, tick=10))  # honest: its body 1 cm on (0.1 s at most v_max, and noise)
    table.update(_state(2, 0.0, 0.3, tick=10))  # its body 6.5 cm away after 0.1 s: not where it says
    table.update(dataclasses.replace(_state(3, -0.3, 0.0, tick=10), radius=1e-4))  # where it is, but tiny
    bodies = np.zeros(3, Poses.RECORD)
    bodies["robot"] = [1, 2, 3]
    bodies["x"], bodies["y"] = [0.31, 0.0, -0.3], [0.0, 0.3 - EPUCK.radius - 0.02, 0.0]
    got = table.gather(_sensed([0], [[0.0, 0.0]], 1.1, 11), 1.0, {}, bodies)
    valid = got.valid[0]
    order = np.lexsort(got.position[0, valid].T[::-1])  # by x
    np.testing.assert_allclose(
        got.position[0, valid][order], [[-0.3, 0.0], [0.0, 0.3 - EPUCK.radius - 0.02], [0.3, 0.0]], atol=1e-7
    )
    assert got.cooperative[0, valid][order].tolist() == [True, False, True]
    assert got.radius[0, valid].min() >= EPUCK.radius


def test_the_bodies_a_robot_has_not_heard_are_found_among_a_thousand_in_any_order():
    """The tracker's test (agent.core.grid.unheard), by a robot's first state heard: a body is heard when
    that state is at most stale_after old and the body at most v_max x its age + a radius from it (both
    bounds included); unknown robots, stale or displaced states and a robot never heard are not."""
    rng = np.random.default_rng(7)
    robots = rng.permutation(1000).astype(np.int64)[:900]  # a host's frame: unsorted, some never heard
    position, stamps = rng.uniform(-5, 5, (900, 2)), 2.0 - rng.uniform(0.0, 0.8, 900)
    bodies = np.zeros(1000, Poses.RECORD)
    bodies["robot"] = rng.permutation(1000)
    at = {r: k for k, r in enumerate(robots.tolist())}
    for i, r in enumerate(bodies["robot"].tolist()):  # near where its state says, or a little too far
        k = at.get(r)
        if k is not None:
            drift = EPUCK.v_max * max(2.0 - stamps[k], 0.0) + EPUCK.radius
            bodies["x"][i], bodies["y"][i] = position[k, 0] + rng.uniform(0.5, 1.5) * drift, position[k, 1]
    expected = []
    for r, x, y in zip(bodies["robot"].tolist(), bodies["x"].tolist(), bodies["y"].tolist()):
        k = at.get(r)
        age = None if k is None else 2.0 - stamps[k]
        near = age is not None and age <= EPUCK.stale_after
        near = near and math.hypot(x - position[k, 0], y - position[k, 1]) <= EPUCK.v_max * max(age, 0.0) + EPUCK.radius
        expected.append(not near)
    got = unheard(robots, position, stamps, bodies, 2.0, EPUCK.stale_after, EPUCK.v_max, EPUCK.radius)
    assert got.tolist() == expected and 0 < sum(expected) < len(expected)
    by_id = np.argsort(robots)  # the central engine's states come in id order: the same answer
    args = (robots[by_id], position[by_id], stamps[by_id], bodies, 2.0, EPUCK.stale_after, EPUCK.v_max, EPUCK.radius)
    assert unheard(*args).tolist() == expected
    # the bounds: a state exactly stale_after old, a body exactly as far as it could have driven; a second
    # state of robot 1 (the first row counts)
    edge = np.zeros(2, Poses.RECORD)
    edge["robot"], edge["x"] = [1, 2], [0.5, 0.0]
    heard = np.array([1, 2, 1]), np.array([[0.0, 0.0], [0.0, 0.0], [9.0, 9.0]]), np.array([1.0, 0.5, 1.0])
    assert unheard(*heard, edge, 1.0, 0.5, 1.0, 0.5).tolist() == [False, False]
    in_order = np.array([1, 1, 2]), np.array([[0.0, 0.0], [9.0, 9.0], [0.0, 0.0]]), np.array([1.0, 1.0, 0.5])
    assert unheard(*in_order, edge, 1.0, 0.5, 1.0, 0.5).tolist() == [False, False]
    nobody = np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0)
    assert unheard(*nobody, edge, 1.0, 0.5, 1.0, 0.5).tolist() == [True, True]


def test_a_body_on_the_edge_of_where_its_robot_could_have_driven_is_judged_as_by_hypot():
    """unheard decides from squared distances only where rounding cannot change the answer: states a few ulps
    either side of the bound, and distances and bounds too small or too large to square, are judged as math.hypot
    judges them."""
    rng, body = np.random.default_rng(3), np.zeros(1, Poses.RECORD)  # robot 0's body at the origin
    cases = 0
    for radius in (0.5, 1e-3, 1e-120, 1e-170, 0.0, 1e160):  # v_max = 0: the bound is the radius
        for scale in (1.0 - 1e-15, 1.0 - 1e-10, 1.0, 1.0 + 1e-15, 1.0 + 1e-10, 1e-150, 3e-160):
            angle = rng.uniform(0, 2 * math.pi)
            length = radius * scale if radius else scale * 1e-160
            state = np.array([[length * math.cos(angle), length * math.sin(angle)]])
            heard = unheard(np.array([0]), state, np.array([1.0]), body, 1.0, 0.5, 0.0, radius)[0]
            assert heard == (not math.hypot(*state[0]) <= radius), (radius, scale)
            cases += 1
    assert cases == 42


def test_a_host_keeps_the_trackers_frames_near_the_tick_it_steps_whatever_else_comes():
    """The frames of the last few ticks, none from before the start; copies from far in the future or
    the past (a faulty peer's) cannot push out those of the ticks the robots step."""
    bodies, frame = TrackedBodies(), np.zeros(3, Poses.RECORD)
    bodies.hear(BEFORE_START, frame)
    assert bodies.at(BEFORE_START) is None
    for tick in range(1, 11):
        bodies.hear(tick, frame[: tick % 3])
    assert bodies.at(2) is None and bodies.at(3) is not None and len(bodies.at(10)) == 1
    bodies.hear(10, frame)  # the tick's frame again (a replay, a renewed subscription): the newest stands
    assert len(bodies.at(10)) == 3
    for forged in [10**6 + k for k in range(20)] + list(range(-20, 0)):
        bodies.hear(forged, frame)
    bodies.hear(11, frame[:2])
    assert len(bodies.at(11)) == 2 and len(bodies.at(10)) == 3 and bodies.at(10**6) is None


def test_beyond_the_frames_kept_the_furthest_from_the_tick_stepped_goes_of_two_the_later():
    rng = np.random.default_rng(4)
    bodies, frame = TrackedBodies(), np.zeros(1, Poses.RECORD)
    assert bodies.at(50) is None  # the tick the robots step
    kept: set[int] = set()
    for tick in rng.integers(30, 71, 400).tolist():  # ties on both sides of 50, repeats
        kept.add(tick)
        if len(kept) > TrackedBodies.KEPT:
            kept.remove(max(kept, key=lambda t: (abs(t - 50), t)))
        bodies.hear(tick, frame)
        assert set(bodies._by_tick) == kept


def test_bid_positions_of_a_batch_are_those_of_each_robot():
    rng = np.random.default_rng(5)
    position, goal, velocity = rng.uniform(-1, 1, (3, 40, 2))
    goal[0] = position[0]  # on its goal
    velocity[1] = 0.0  # blocked
    batch = bid_position(position, goal, velocity, lead=2.5)
    assert np.array_equal(batch, [bid_position(p, g, v, lead=2.5) for p, g, v in zip(position, goal, velocity)])


def test_the_table_keeps_each_robots_two_newest_states_whatever_the_arrival_order():
    """States arrive late, twice and out of order (zenoh orders nothing across publishers); a lock-step
    tick steers by each robot's newest state before it, so the table must hold the two newest."""
    rng = np.random.default_rng(9)
    table = NeighbourTable(0.1)
    sent = {r: rng.permutation(np.repeat(np.arange(8), 2)).tolist() for r in range(5)}  # every tick twice
    for _ in range(16):
        for robot, ticks in sent.items():
            table.update(_state(robot, 0.0, 0.0, tick=ticks.pop()))
            kept = table._states[robot]
            assert [s.tick for s in kept] == sorted({s.tick for s in kept}) and len(kept) <= 2
    assert all([s.tick for s in table._states[r]] == [6, 7] for r in range(5))
    assert [s.tick for s in table.latest_before(7)] == [6] * 5


def test_the_body_nodes_standing_body_wins_over_its_agents_state_of_the_tick_in_either_order():
    """A silent agent's body is sent standing by the body node (sim.node.body); a command lost after all
    may leave its agent's state of the same tick too. Kept by arrival, a lock-step run would depend on
    which came first; the body's is kept, as the body is what stands there."""
    agent = _state(1, 0.5, 0.0, tick=3)
    body = State(1, 3, 0.3, 0.5, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, -1, State.DYNAMIC)
    for first, second in [(agent, body), (body, agent)]:
        table = NeighbourTable(0.1)
        table.update(_state(1, 0.4, 0.0, tick=2))
        table.update(first)
        table.update(second)
        assert [s.tick for s in table._states[1]] == [2, 3] and table.latest_before(4) == [body]


def test_robots_whose_newest_state_left_the_cells_heard_are_forgotten():
    table = NeighbourTable(0.1)
    for robot, x in enumerate([0.1, 0.9, 1.1, -0.1, 2.5]):
        table.update(_state(robot, x, 0.2))
    table.update(_state(4, 0.5, 0.2, tick=2))  # robot 4 came into cell (0, 0)
    assert table.forget_outside({(0, 0)}, cell_size=1.0) == 2  # robots 2 (cell 1) and 3 (cell -1)
    assert sorted(s.robot for s in table.latest_before(3)) == [0, 1, 4]


def test_a_robot_whose_agent_died_is_not_forgotten_outside_the_cells_heard():
    # it will never speak again: forgotten, its body would be invisible when we come back near it
    table = NeighbourTable(0.1)
    for robot, x in enumerate([0.1, 1.1, 2.5]):
        table.update(_state(robot, x, 0.2))
    assert table.forget_outside({(0, 0)}, cell_size=1.0, keep={2}) == 1  # robot 1 only
    assert sorted(s.robot for s in table.latest_before(3)) == [0, 2]


def test_a_silent_robot_is_forgotten_only_where_it_can_no_longer_touch_ours():
    """Silent for 2 s, a neighbour may have come 0.29 m (2.2 s at v_max 0.13): one last heard that near a robot of
    ours is kept, so ORCA goes on seeing it (its robot stands), however long its states are lost; one
    farther, or silent briefly, is not; a dead robot's body is never forgotten."""
    params = dataclasses.replace(EPUCK, v_max=0.13)
    reach = partial(touch_reach, settings_of(params), 0.05)
    assert np.allclose(reach(0.05, 2.0), 0.05 + 0.05 + params.noise_bound + 2.2 * 0.13)  # 0.396 m
    table = NeighbourTable(0.1)
    for robot, x in enumerate([0.3, 0.5, 0.5, 2.0]):
        table.update(_state(robot, x, 0.0))
    table.update(_state(4, 0.5, 0.0, tick=20))  # heard 0.1 s ago
    around = np.array([[0.0, 0.0], [5.0, 5.0]])
    assert table.forget_silent(2.1, 2.0, around, reach, keep={2}) == 2  # robots 1 and 3
    assert sorted(s.robot for s in table.latest_before(30)) == [0, 2, 4]
    assert (
        table.forget_silent(2.1, 2.0, np.zeros((0, 2)), reach) == 2
    )  # none of ours near: 0 and 2 (kept no more), not 4


class _Cells:
    """A bus stand-in: which cells a host subscribes to."""

    def __init__(self) -> None:
        self.keys = self
        self.live: set = set()

    def state_cell(self, cell: tuple[int, int]) -> tuple[int, int]:
        return cell

    def subscribe_into(self, cell: tuple[int, int], inbox: object) -> tuple[int, int]:
        self.live.add(cell)
        return cell

    def unsubscribe(self, cell: tuple[int, int]) -> None:
        self.live.remove(cell)


def test_a_host_listens_to_the_square_of_cells_around_each_of_its_robots():
    from agent.runtime import CellSubscriptions
    from transport.keys import cell_of

    rng = np.random.default_rng(4)
    bus = _Cells()
    cells = CellSubscriptions(bus, inbox=None, cell_size=0.7, reach=2)
    for _ in range(3):  # the robots move: cells are added and dropped
        positions = rng.uniform(-3, 3, (25, 2))
        cells.update(positions)
        expect = {
            (cx + dx, cy + dy)
            for cx, cy in (cell_of(x, y, 0.7) for x, y in positions)
            for dx in range(-2, 3)
            for dy in range(-2, 3)
        }
        assert cells.cells == bus.live == expect
        assert all(type(c) is int for cell in cells.cells for c in cell)  # key expressions print ints
        # a host hearing every host's frames: the same cells, none declared; its inbox keeps their records
        inbox = SimpleNamespace(keep=None)
        kept = CellSubscriptions(_Cells(), inbox=inbox, cell_size=0.7, reach=2, listen=False)
        kept.update(positions)
        assert kept.cells == expect and not kept.bus.live and inbox.keep.cells == expect


def test_a_host_keeps_the_records_of_its_cells_and_of_the_robots_its_pursuers_chase():
    """KeepCells picks a frame's records with numpy, and a lone record's view in Python: the same
    records either way, those in the cells (by transport.keys.cell_of) or of a chased robot."""
    from agent.runtime import KeepCells
    from transport.codec import States
    from transport.keys import cell_of

    rng = np.random.default_rng(8)
    records = np.zeros(400, States.RECORD)
    records["robot"] = np.arange(400)
    records["x"], records["y"] = rng.uniform(-4, 4, (2, 400)).astype(np.float32)
    cells = {cell_of(float(x), float(y), 0.7) for x, y in rng.uniform(-4, 4, (30, 2))}
    keep = KeepCells(cells, 0.7, frozenset({3, 7}))
    views = States(5, 0.5, records).messages()
    expect = [v.robot for v in views if cell_of(v.x, v.y, 0.7) in cells or v.robot in (3, 7)]
    assert 3 in expect and 7 in expect and 0 < len(expect) < 200
    assert records["robot"][keep.mask(records)].tolist() == expect
    assert [v.robot for v in views if keep.keeps(v)] == expect
