"""A limited communication range end to end (issue 23): `pixelswarm run --range R` lets a robot hear
states and auction words only of robots within R. The range-limited auction (agent.core.local_auction)
still forms a picture when the graph is connected, without any process seeing every bid, and a
split graph stays safe and one-to-one within each part, with the split reported. (That agent hosts
run the central engine's rounds bit for bit, through the wire format, is in test_local_auction.)"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import connected_components

from agent.core.params import EPUCK
from coordinator.scene import load_scene, make_goal_sets, scene_goal_set
from tests.conftest import assert_usage_error, run_scene
from tests.support.engines import picture

TOLERANCE = 0.01  # m: every robot within 1 cm of its goal


def _parts(xy: np.ndarray, reach: float) -> np.ndarray:
    xy = np.asarray(xy, np.float32)[:, :2].astype(float)
    near = ((xy[:, None] - xy[None]) ** 2).sum(-1) <= reach * reach
    return connected_components(near, directed=False)[1]


def _diameter(source: str, robots: int, seed: int) -> float:
    scene = make_goal_sets(load_scene(source, robots=robots, seed=seed))
    goals, _ = scene_goal_set(scene, 0, robots)
    return float(np.max(np.hypot(*(goals[:, None] - goals[None]).transpose(2, 0, 1))))


@pytest.mark.slow
def test_a_hundred_robot_picture_in_hosts_forms_with_a_quarter_of_its_diameter_in_reach(tmp_path):
    source = picture(tmp_path)
    reach = _diameter(source, 100, 1) / 4
    flags = ("--robots", "100", "--seed", "1", "--clock", "lockstep", "--range", f"{reach:.6f}")
    # two hosts of fifty: a lock-step run is the same run however its robots are hosted, and every
    # host decodes every other host's words, so fewer hosts cost less
    metrics, traj = run_scene(tmp_path, source, *flags, "-k", "50", name="hosts")
    assert metrics["contacts"] == 0 and metrics["missed_ticks"] == 0
    assert metrics["converged"]
    error = np.hypot(*(traj["pose"][-1, :, :2] - traj["goal"][-1]).T)
    assert error.max() <= TOLERANCE
    assert metrics["range_m"] == pytest.approx(reach, abs=1e-6) and metrics["split_ticks"] == 0
    for k, row in enumerate(traj["assignment"]):
        assert (row >= 0).all() and len(np.unique(row)) == len(row), f"one goal, two robots at tick {k}"
    # the first agreement, on the start positions, against the optimum (checked here only)
    goals = traj["goal"][-1][np.argsort(traj["assignment"][-1])]  # goal g's position
    cost = ((traj["pose"][0, :, None, :2] - goals[None]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    ours = cost[np.arange(100), traj["assignment"][0]].sum()
    assert ours <= cost[rows, cols].sum() + 100 * (EPUCK.assign_eps + EPUCK.assign_hysteresis) + 1e-6


def test_a_split_graph_is_safe_one_to_one_in_each_part_and_reported(tmp_path):
    """Robots whose picture spreads wider than their reach: the graph splits, each part agrees on its
    own, no two robots of one part drive to one goal, and metrics.json counts the split ticks."""
    reach = 0.3
    metrics, traj = run_scene(
        tmp_path,
        picture(tmp_path),
        *("--robots", "30", "--seed", "2", "--clock", "lockstep", "--engine", "central"),
        *("--range", str(reach), "--duration", "15"),
    )
    assert metrics["contacts"] == 0
    assert metrics["split_ticks"] > 0 and metrics["most_parts"] > 1
    for k in range(len(traj["t"])):
        part, row = _parts(traj["pose"][k], reach), traj["assignment"][k]
        for p in np.unique(part):
            mine = row[part == p]
            assert len(np.unique(mine)) == len(mine), f"one goal, two robots of one part at tick {k}"


@pytest.mark.parametrize(
    "flags, message",
    [
        (("--range", "0"), "--range must be a positive distance"),
        (("--range", "0.5", "--clock", "realtime"), "--range needs the lock-step clock"),
    ],
)
def test_a_bad_range_is_one_line_and_exit_2(tmp_path, flags, message):
    assert_usage_error(tmp_path, message, "swap", *flags)
