"""The coordinator's first goal set is for every robot: an agent heard a moment late must not make a
second epoch at a tick the machine's load decides (lock-step runs would then differ by engine)."""

from __future__ import annotations

from coordinator import service
from coordinator.scene import load_scene
from tests.support.fake_bus import Bus
from transport.codec import Goals, Tick, decode


def _coordinator_hearing(robots: list[int]) -> tuple[service.Coordinator, Bus]:
    bus = Bus()
    coordinator = service.Coordinator(bus, load_scene("paper-sequence"))
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in robots]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    return coordinator, bus


def test_the_first_goal_set_waits_for_every_robots_agent() -> None:
    coordinator, bus = _coordinator_hearing([0, 1, 10, 11, 13])
    robots = coordinator.scene.robots
    assert not coordinator._follow_show()  # 5 of 14 agents heard at the first tick: no goal set yet
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in range(robots)]
    assert coordinator._follow_show()
    first = decode(bus.published[-1].encode(), Goals)
    assert first.epoch == 1 and first.robots.tolist() == list(range(robots))


def test_after_its_patience_the_first_goal_set_is_for_the_agents_heard(monkeypatch) -> None:
    monkeypatch.setattr(service, "FIRST_SET_PATIENCE", 0.0)  # an agent that never starts
    coordinator, bus = _coordinator_hearing([0, 1, 10, 11, 13])
    assert coordinator._follow_show()
    assert decode(bus.published[-1].encode(), Goals).robots.tolist() == [0, 1, 10, 11, 13]
