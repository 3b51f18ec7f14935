"""Lock-step with the auction's rounds per tick bounded, the run's first goal set is warm-started from
where the robots start (WarmStart.matched_from 0): its robots drive at once to the goals of the
least-distance matching while the auction's first block spans ticks, instead of a cold start whose
tens of rounds (thousands at 1000 robots) all fall in the first tick."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from agent.core.bidder import Participant
from agent.core.params import RobotParams
from coordinator import service
from coordinator.scene import Scene, scene_from_dict
from tests.support.fake_bus import Bus
from transport.codec import Goals, Tick, decode


def _scene(rounds_per_tick: int, clock: str = "lockstep") -> Scene:
    return scene_from_dict(
        {
            "robots": 20,
            "seed": 5,
            "clock": clock,
            "robot": {"rounds_per_tick": rounds_per_tick},
            "layout": {"kind": "grid", "spacing": 0.2},
            "steps": [{"shape": "disk", "hold": 30}],
        }
    )


def _first_set(rounds_per_tick: int, clock: str = "lockstep") -> tuple[Goals, np.ndarray]:
    scene = _scene(rounds_per_tick, clock)
    bus = Bus()
    coordinator = service.Coordinator(bus, scene)
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in range(scene.robots)]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    assert coordinator._follow_show()
    first = decode(bus.published[-1].encode(), Goals)
    return first, np.asarray(scene.poses, float)[first.robots, :2]


def test_the_first_set_is_warm_started_from_the_least_distance_matching_of_the_robots_starts() -> None:
    first, starts = _first_set(rounds_per_tick=1)
    warm = first.warm_start
    assert warm is not None and warm.matched_from == 0
    assert sorted(warm.matched.tolist()) == list(range(len(first.robots)))  # one robot a goal
    cost = ((starts[:, None, :] - first.positions[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    matched_cost = cost[warm.matched, np.arange(len(warm.matched))].sum()
    eps = RobotParams().assign_eps  # the robots' auction, settled once by the coordinator
    assert matched_cost <= cost[rows, cols].sum() + len(cost) * eps + 1e-12  # scipy's optimum, within N eps
    # the prices are in epsilon-equilibrium for it: no robot prefers another goal by more than eps
    value = cost + warm.prices[None, :]
    held = value[warm.matched, np.arange(len(warm.matched))]
    assert (held <= value[warm.matched].min(axis=1) + eps + 1e-9).all()


def test_the_first_sets_matching_is_made_while_the_agents_start(monkeypatch) -> None:
    """The coordinator matches the first set to the robots' starts before the world's first tick
    (at 10,000 robots that takes seconds, and the agents' first tick waits for the set), once."""
    calls = []
    matching = service.goal_matching
    monkeypatch.setattr(service, "goal_matching", lambda *a: calls.append(1) or matching(*a))
    scene = _scene(rounds_per_tick=1)
    bus = Bus()
    coordinator = service.Coordinator(bus, scene)
    coordinator._prepare_next()  # no tick yet: the agents are starting
    coordinator._prepare_next()
    assert len(calls) == 1 and not bus.published
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in range(scene.robots)]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    assert coordinator._follow_show()
    first = decode(bus.published[-1].encode(), Goals)
    assert len(calls) == 1 and first.warm_start is not None  # the prepared one


@pytest.mark.parametrize("rounds, clock", [(0, "lockstep"), (1, "realtime")])
def test_without_bounded_lockstep_rounds_the_first_set_starts_cold(rounds: int, clock: str) -> None:
    first, _ = _first_set(rounds_per_tick=rounds, clock=clock)
    assert first.warm_start is None


def test_a_participant_started_from_a_matching_claims_it_and_drives_to_it() -> None:
    goals = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    part = Participant(1, goals, [3, 5, 8], [5, 8], eps=0.01)
    owner, prices = np.array([8, 3, 5]), np.array([0.0, 0.5, 0.25])
    assert part.start_from(owner, prices) == {5: 2, 8: 0}
    assert part.board.owner.tolist() == [8, 3, 5] and part.board.price.tolist() == [0.0, 0.5, 0.25]
    assert part.goal.tolist() == [2, 0]  # each own robot's claim, in the order of own
