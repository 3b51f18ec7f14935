"""The central engine assigns goals by the agents' own auction (paper 5.1, agent.core.bidder): one
participant holds every robot, and each assign_period the next block of epsilon-scaling phases is
settled in-process on the measured positions, warm from the last prices. Every assignment it makes
must be one-to-one and within N (epsilon_A + Delta C) of scipy's optimum for the positions it bid
from; a new image starts a fresh auction."""

from __future__ import annotations

import json

import numpy as np
import pytest

import sim.central.engine as central
from agent.core.params import RobotParams
from coordinator.scene import load_scene
from tests.support.assignment_quality import optimum


@pytest.fixture
def auctions(monkeypatch) -> list[dict]:
    """Every call of the engine's auction: the positions bid from, the goal set, the result."""
    calls: list[dict] = []
    real = central.auction_assignment

    def spy(auction, position):
        out = real(auction, position)
        calls.append(
            {
                "position": position.copy(),
                "goals": auction.goals.copy(),
                "assignment": out.copy(),
                "block": auction.instance // auction.phases,
            }
        )
        return out

    monkeypatch.setattr(central, "auction_assignment", spy)
    return calls


def test_every_auction_assignment_is_one_to_one_and_within_the_bound_of_the_optimum(tmp_path, auctions):
    scene = load_scene("paper-sequence", duration=33.0)  # the first image, then 3 s of the second
    assert scene.assignment == "auction"
    params = RobotParams.from_dict(scene.robot)
    out = central.run_central(scene, tmp_path / "run", video=False, progress=None)
    n = scene.robots
    ticks = len(np.load(out / "trajectory.npz")["t"])
    # assign_period = dt: every control iteration, but the last tick (a pose; no command follows it)
    assert len(auctions) == ticks - 1
    for call in auctions:
        a = call["assignment"]
        assert sorted(a.tolist()) == list(range(n))
        cost = float(((call["position"] - call["goals"][a]) ** 2).sum())
        assert (
            cost <= optimum(call["position"], call["goals"]) + n * (params.assign_eps + params.assign_hysteresis) + 1e-9
        )
    # a cold start (the first block of a fresh participant) at each image, warm blocks in between
    assert [i for i, c in enumerate(auctions) if c["block"] == 0] == [0, round(30.0 / params.dt)]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["contacts"] == 0 and metrics["steps"][0]["converged_at"] is not None


def test_the_auction_runs_every_assign_period(tmp_path, auctions):
    scene = load_scene("paper-sequence", duration=5.0)
    scene.robot["assign_period"] = 0.5
    out = central.run_central(scene, tmp_path / "run", video=False, progress=None)
    traj = np.load(out / "trajectory.npz")
    assert len(auctions) == int(np.ceil((len(traj["t"]) - 1) / 5))  # none at the last tick
    # between auctions every robot keeps its goal, and at the last tick too
    for k, a in enumerate(traj["assignment"]):
        np.testing.assert_array_equal(a, auctions[min(k // 5, len(auctions) - 1)]["assignment"])
