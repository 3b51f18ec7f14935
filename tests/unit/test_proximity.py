"""The one neighbour search of every engine (agent.core.grid, compiled) against scipy's kd-tree: the
same neighbours, nearest first, within reach, self excluded, equal distances by key then index; and
the world's contact search (sim.bodies.proximity.close_pairs) against the kd-tree's pairs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from agent.core.grid import nearest
from agent.neighbour_table import Heard, nearest_heard
from sim.bodies.proximity import close_pairs, nearest_other


def nearest_within(position: np.ndarray, reach: float, m: int, threads: int = 1) -> np.ndarray:
    """The central engine's (sim.central.rvo) use: every robot among all, strictly within reach."""
    index = np.arange(len(position), dtype=np.int64)
    p = np.ascontiguousarray(position, dtype=float)
    return nearest(p, index, p, index, reach, m, False, threads)


def kd_tree_neighbours(position: np.ndarray, reach: float, m: int) -> np.ndarray:
    dist, idx = cKDTree(position).query(position, k=m + 1, distance_upper_bound=reach)
    idx = np.where(np.isfinite(dist), idx, -1)[:, 1:]  # the first is the robot itself
    return idx


def kd_tree_ranked(query, query_key, points, key, reach, m, inclusive) -> np.ndarray:
    """The documented rule from the kd-tree's candidates (a ball a hair wider than reach): d2 =
    (x - qx)^2 + (y - qy)^2, within reach, not the query's own key, ranked by (d2, key, index)."""
    out = np.full((len(query), m), -1, np.int64)
    if len(points) == 0 or len(query) == 0:
        return out
    ball = cKDTree(points).query_ball_point(query, reach * (1.0 + 1e-9) + 1e-12)
    for i, cand in enumerate(ball):
        j = np.asarray(cand, dtype=np.int64)
        dx, dy = points[j, 0] - query[i, 0], points[j, 1] - query[i, 1]
        d2 = dx * dx + dy * dy
        keep = (d2 <= reach * reach if inclusive else d2 < reach * reach) & (key[j] != query_key[i])
        j, d2 = j[keep], d2[keep]
        ranked = j[np.lexsort((j, key[j], d2))][:m]
        out[i, : len(ranked)] = ranked
    return out


@pytest.mark.parametrize(
    "seed, n, side, reach, m",
    [(0, 1000, 25.0, 1.2, 16), (1, 300, 3.0, 1.0, 8), (2, 50, 100.0, 5.0, 4), (3, 2, 1.0, 2.0, 1)],
)
@pytest.mark.parametrize("threads", [1, 3])  # the central engine shares the queries among its cores
def test_the_same_neighbours_as_a_kd_tree(seed, n, side, reach, m, threads):
    position = np.random.default_rng(seed).uniform(0.0, side, (n, 2))
    np.testing.assert_array_equal(nearest_within(position, reach, m, threads), kd_tree_neighbours(position, reach, m))


def test_a_search_shared_with_the_auction_thread_as_it_ends_gives_the_same_neighbours():
    """The central engine's auction holds a hand of the crew while it settles, and works the rows left of a
    search under way when it ends (agent.core.crew): whichever hands work which rows, the neighbours are
    the kd-tree's. Searches run one after another while blocks settle, so blocks end mid-search."""
    from agent.core.bidder import Participant

    rng = np.random.default_rng(7)
    position = rng.uniform(0.0, 25.0, (2000, 2))
    expected = kd_tree_neighbours(position, 1.2, 16)
    robots = list(range(300))
    part = Participant(0, rng.uniform(0.0, 10.0, (300, 2)), robots, robots, 1e-3)
    for _ in range(8):
        part.settle_beside(rng.uniform(0.0, 10.0, (300, 2)))
        for _ in range(8):  # a block takes a few searches' time
            np.testing.assert_array_equal(nearest_within(position, 1.2, 16, threads=2), expected)
        part.settled()


def test_reach_is_strict_and_ties_go_to_the_lower_index():
    position = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 2.0]])
    got = nearest_within(position, 1.0 + 1e-12, 3)
    assert got[0].tolist() == [1, 2, -1]  # 1 and 2 tie at distance 1; robot 3 is out of reach
    assert nearest_within(position, 1.0, 3)[0].tolist() == [-1, -1, -1]  # exactly at reach: out


def test_a_robot_far_away():
    position = np.array([[0.0, 0.0], [0.5, 0.0], [1e7, 1e7], [0.2, 0.0]])
    got = nearest_within(position, 1.0, 2)
    assert got[0].tolist() == [3, 1]
    assert got[2].tolist() == [-1, -1]  # alone, 10^7 m away (the grid widens its cells)


@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan])
def test_a_point_off_the_map_is_nobody_s_neighbour(bad):
    """An infinite coordinate sized the grid to no number and wrote outside it (a segfault); such a
    point is within no distance of any other, and the rest keep their neighbours."""
    position = np.array([[0.0, 0.0], [0.5, 0.0], [bad, 0.0], [0.2, bad], [0.2, 0.0]])
    got = nearest_within(position, 1.0, 3)
    assert got[0].tolist() == [4, 1, -1] and got[1].tolist() == [4, 0, -1]
    assert got[2].tolist() == got[3].tolist() == [-1, -1, -1]
    other, apart = nearest_other(np.full((3, 2), bad), 1.0)
    assert other.tolist() == [-1, -1, -1] and np.isinf(apart).all()


def test_points_farther_apart_than_a_double_holds_are_refused_not_written_past_the_grid():
    """Two finite points whose difference overflows sized the grid to no number, as an infinite one did (a
    segfault): the search, and the world's, refuse them in a line."""
    position = np.array([[-1.7e308, 0.0], [1.7e308, 0.0]])
    with pytest.raises(ValueError, match="farther apart than a double holds"):
        nearest_within(position, 1.0, 1)
    with pytest.raises(ValueError, match="farther apart than a double holds"):
        nearest_other(position, 1.0)
    assert nearest_within(position / 2, 1.0, 1).tolist() == [[-1], [-1]]  # their difference a double holds


@pytest.mark.parametrize("seed", range(40))
def test_the_documented_ranking_on_a_kd_tree_s_candidates(seed):
    """Random seeded sets, half of them on a lattice (ties everywhere, points exactly at reach),
    queries inside and far outside the points, keys in any order, m beyond the count, both rules."""
    rng = np.random.default_rng(seed)
    n, q = int(rng.integers(0, 300)), int(rng.integers(0, 60))
    lattice = seed % 2 == 0
    points = rng.integers(-8, 8, (n, 2)) * 0.125 if lattice else rng.uniform(-1, 1, (n, 2))
    query = rng.integers(-10, 10, (q, 2)) * 0.125 if lattice else rng.uniform(-1.5, 1.5, (q, 2))
    if q:
        query[0] = (40.0, -3.0)  # far outside the grid
    key = rng.permutation(1000)[:n].astype(np.int64)
    query_key = np.concatenate([key[: q // 2], rng.integers(1000, 2000, q)])[:q].astype(np.int64)
    m = int(rng.integers(0, 12)) if seed % 5 else n + 3  # more than there are
    reach = float(rng.choice([0.125, 0.25, 0.5, 2.0, 100.0]))
    for inclusive in (True, False):
        got = nearest(query, query_key, points, key, reach, m, inclusive)
        want = kd_tree_ranked(query, query_key, points, key, reach, m, inclusive)
        np.testing.assert_array_equal(got, want, err_msg=f"inclusive={inclusive}")
    if lattice and q and n and m:
        assert (nearest(query, query_key, points, key, reach, m) >= 0).sum() > 0


def test_empty_sets_and_no_room():
    none, some = np.zeros((0, 2)), np.array([[0.0, 0.0], [0.1, 0.0]])
    keys = np.array([1, 2], dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    assert nearest(some, keys, none, empty, 1.0, 3).tolist() == [[-1, -1, -1]] * 2  # an empty grid
    assert nearest(none, empty, some, keys, 1.0, 3).shape == (0, 3)
    assert nearest(some, keys, some, keys, 1.0, 0).shape == (2, 0)
    assert nearest(some, keys, some, keys, 1.0, 5).tolist() == [[1, -1, -1, -1, -1], [0, -1, -1, -1, -1]]
    assert nearest(some, np.array([7, 8]), some, keys, np.inf, 2).tolist() == [[0, 1], [1, 0]]  # no own key


def test_a_batch_of_one_is_its_row_of_every_batch():
    """An agent asks for its one robot, a host for K, the central engine for all: the same row."""
    rng = np.random.default_rng(4)
    points = rng.integers(-10, 10, (500, 2)) * 0.05
    key = rng.permutation(500).astype(np.int64)
    everyone = nearest(points, key, points, key, 0.3, 10)
    for size in (1, 7, 120):
        for lo in range(0, 500, 97):
            rows = slice(lo, min(lo + size, 500))
            np.testing.assert_array_equal(nearest(points[rows], key[rows], points, key, 0.3, 10), everyone[rows])


def test_the_closest_valid_neighbours_in_order():
    """Of the valid states, those within reach, nearest first, at most M."""
    npos = np.array([[3.0, 0.0], [1.0, 0.0], [0.5, 0.0], [2.0, 0.0], [9.0, 0.0]])
    valid = np.array([True, True, False, True, True])
    radius = np.arange(5.0)
    heard = Heard(np.arange(5)[valid], npos[valid], np.zeros((4, 2)), radius[valid], np.zeros(4), np.ones(4, bool))
    out = nearest_heard([99], np.zeros((1, 2)), 0.0, heard, 5.0, 3)
    assert np.array_equal(out.position[0, :, 0], [1.0, 2.0, 3.0])
    assert np.array_equal(out.radius[0], [1.0, 3.0, 0.0]) and out.valid.all()


@pytest.mark.parametrize("seed", range(20))
def test_the_agents_neighbour_choice_is_the_documented_rule(seed):
    """The agents and every engine pick neighbours with agent.neighbour_table.nearest_heard (the
    compiled grid): each robot's states are those of the kd-tree's ranking, ties in distance by
    robot id (points on a lattice), whatever order the states come in."""
    rng = np.random.default_rng(seed)
    n, q = int(rng.integers(1, 60)), int(rng.integers(1, 40))
    lattice = seed % 2 == 0
    pos = rng.integers(-5, 5, (n, 2)) * 0.1 if lattice else rng.uniform(-1, 1, (n, 2))
    ids = rng.permutation(200)[:n]
    heard = Heard(
        ids, pos, rng.normal(size=(n, 2)), rng.uniform(0.02, 0.05, n), rng.uniform(0, 1, n), rng.random(n) < 0.8
    )
    own = np.concatenate([ids[: q // 2], rng.integers(200, 300, q)])[:q]  # some of the queries are heard robots
    where = rng.integers(-5, 5, (len(own), 2)) * 0.1 if lattice else rng.uniform(-1.2, 1.2, (len(own), 2))
    m, reach = int(rng.integers(1, 12)), float(rng.choice([0.1, 0.3, 0.6, 2.0]))
    got = nearest_heard(own, where, 1.5, heard, reach, m)
    idx = kd_tree_ranked(where, own, pos, ids, reach, m, True)
    ok = idx >= 0
    np.testing.assert_array_equal(got.valid, ok)
    np.testing.assert_array_equal(got.position[ok], pos[idx[ok]])
    np.testing.assert_array_equal(got.velocity[ok], heard.velocity[idx[ok]])
    np.testing.assert_array_equal(got.radius[ok], heard.radius[idx[ok]])
    np.testing.assert_array_equal(got.age[ok], 1.5 - heard.stamp[idx[ok]])
    np.testing.assert_array_equal(got.cooperative[ok], heard.cooperative[idx[ok]])
    assert (got.radius[~ok] == 1.0).all() and (got.position[~ok] == 0.0).all() and got.cooperative[~ok].all()
    shuffled = rng.permutation(n)  # the states in another order: the same choice
    again = nearest_heard(
        own,
        where,
        1.5,
        Heard(*(a[shuffled] for a in (ids, pos, heard.velocity, heard.radius, heard.stamp, heard.cooperative))),
        reach,
        m,
    )
    for name in ("position", "velocity", "radius", "age", "valid", "cooperative"):
        np.testing.assert_array_equal(getattr(again, name), getattr(got, name), err_msg=name)


@pytest.mark.parametrize("seed", range(5))
def test_each_point_s_nearest_other_is_the_kd_tree_s_within_reach(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 5, (200, 2))
    reach = 0.2
    other, apart = nearest_other(xy, reach)
    d, i = cKDTree(xy).query(xy, k=2, distance_upper_bound=reach)
    found = np.isfinite(d[:, 1])
    assert found.any() and not found.all()
    np.testing.assert_array_equal(other, np.where(found, i[:, 1], -1))
    np.testing.assert_allclose(apart, d[:, 1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(12))
def test_close_pairs_finds_the_kd_tree_s_pairs(seed):
    """sim.bodies.proximity.close_pairs against the pairs a kd-tree finds in reach: the same overlapping
    pairs with the same depths, the same smallest clearance, and a budget that stops it."""
    rng = np.random.default_rng(seed)
    n, rows = int(rng.integers(2, 400)), int(rng.integers(1, 4))
    start = rng.uniform(0.0, float(rng.choice([1.0, 5.0])), (n, 2))
    if seed % 3 == 0:
        start = np.round(start * 10) / 10  # many at equal distances, some on top of each other
    traj = start[None] + np.cumsum(rng.normal(0.0, 0.005, (rows, n, 2)), axis=0) * (np.arange(rows) > 0)[:, None, None]
    radius = rng.uniform(0.01, 0.05, n)
    motion = float(np.abs(traj - traj[0]).max()) * 1.5 + 1e-12
    reach, first_row = 0.12, int(rng.integers(0, rows))
    got = close_pairs(traj, radius, reach, motion, first_row)
    assert got is not None
    pairs = cKDTree(traj[0]).query_pairs(reach * (1 - 1e-9), output_type="ndarray")
    pairs.sort(axis=1)
    i, j = pairs[:, 0], pairs[:, 1]
    s = radius[i] + radius[j]
    d = np.sqrt(((traj[:, i] - traj[:, j]) ** 2).sum(axis=2))  # (rows, pairs)
    overlap = (d[first_row:] < s).any(axis=0)
    want = {(int(a), int(b)): s[k] - d[first_row:, k] for k, (a, b) in enumerate(pairs) if overlap[k]}
    found = {(int(a), int(b)): depth for (a, b), depth in zip(got[3], got[4].T)}
    assert set(want) == set(found) and all(a < b for a, b in found)
    for pair, depth in want.items():
        np.testing.assert_allclose(found[pair], depth, rtol=0, atol=1e-15)
    if len(pairs):
        assert got[0] <= (d.min(axis=0) - s).min() + 1e-15
        a, b = got[1], got[2]
        assert got[0] == pytest.approx(
            np.sqrt(((traj[:, a] - traj[:, b]) ** 2).sum(axis=1)).min() - radius[a] - radius[b]
        )
    if n > 30:
        assert close_pairs(traj, radius, reach, motion, first_row, budget=1) is None
