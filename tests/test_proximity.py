"""The central engine's neighbour search (sim.proximity.nearest_within) against scipy's kd-tree: the same neighbours,
nearest first, strictly within reach, self excluded."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from agent.core.neighbour_grid import nearest_within
from agent.neighbour_table import Heard, nearest_heard
from sim.proximity import nearest_heard_compiled


def kd_tree_neighbours(position: np.ndarray, reach: float, m: int) -> np.ndarray:
    dist, idx = cKDTree(position).query(position, k=m + 1, distance_upper_bound=reach)
    idx = np.where(np.isfinite(dist), idx, -1)[:, 1:]  # the first is the robot itself
    return idx


@pytest.mark.parametrize(
    "seed, n, side, reach, m",
    [(0, 1000, 25.0, 1.2, 16), (1, 300, 3.0, 1.0, 8), (2, 50, 100.0, 5.0, 4), (3, 2, 1.0, 2.0, 1)],
)
def test_the_same_neighbours_as_a_kd_tree(seed, n, side, reach, m):
    position = np.random.default_rng(seed).uniform(0.0, side, (n, 2))
    np.testing.assert_array_equal(nearest_within(position, reach, m), kd_tree_neighbours(position, reach, m))


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


@pytest.mark.parametrize("seed", range(20))
def test_the_compiled_neighbour_choice_is_the_agents_own(seed):
    """The central engine picks neighbours on a compiled grid (sim.proximity.nearest_heard_compiled);
    the agents pick them with agent.neighbour_table.nearest_heard. Same states in, the same
    neighbours out, in the same order, ties in distance included (points on a lattice)."""
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
    numpy_pick = nearest_heard(own, where, 1.5, heard, reach, m)
    compiled = nearest_heard_compiled(own, where, 1.5, heard, reach, m)
    k = numpy_pick.position.shape[1]  # numpy pads only to the states there are
    assert not compiled.valid[:, k:].any()
    np.testing.assert_array_equal(compiled.valid[:, :k], numpy_pick.valid)
    ok = numpy_pick.valid
    for name in ("position", "velocity", "radius", "age", "cooperative"):
        np.testing.assert_array_equal(getattr(compiled, name)[:, :k][ok], getattr(numpy_pick, name)[ok], err_msg=name)
