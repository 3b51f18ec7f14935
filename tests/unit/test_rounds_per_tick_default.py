"""The lock-step auction's rounds per tick by default (docs/lockstep_auction.md, "Rounds per tick"):
bounded for a scene made for agent processes, whichever engine runs it (so every engine runs it the
same), unbounded for one made for the central engine, and what a scene or --rounds-per-tick says
wins."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from agent.core.params import BUS_ROUNDS_PER_TICK
from coordinator.scene import parse_scene
from sim.cli import main as cli


def rounds(scene_text: str, tmp_path, flag: int | None = None, engine: str | None = None, reach: float = math.inf):
    path = tmp_path / "scene.toml"
    path.write_text(scene_text)
    args = SimpleNamespace(rounds_per_tick=flag, hardware=None, engine=engine)
    return cli._with_rounds_per_tick(args, parse_scene(str(path)), reach).robot.get("rounds_per_tick")


LOCKSTEP = 'robots = 3\nclock = "lockstep"\n'


@pytest.mark.parametrize("engine", [None, "distributed", "central"])
def test_a_lockstep_scene_for_agent_processes_is_bounded_in_every_engine(tmp_path, engine):
    assert BUS_ROUNDS_PER_TICK >= 1
    assert rounds(LOCKSTEP, tmp_path, engine=engine) == BUS_ROUNDS_PER_TICK


@pytest.mark.parametrize(
    "text, flag, reach, expected",
    [
        (LOCKSTEP + 'engine = "central"\n', None, math.inf, None),  # made for the central engine: paper 5.1
        ('robots = 3\nclock = "realtime"\n', None, math.inf, None),  # real time has no rounds of ticks
        (LOCKSTEP, None, 0.8, None),  # the range-limited auction ends its blocks by hops
        (LOCKSTEP + "[robot]\nrounds_per_tick = 0\n", None, math.inf, 0),  # the scene's word
        (LOCKSTEP + "[robot]\nrounds_per_tick = 5\n", None, math.inf, 5),
        (LOCKSTEP, 3, math.inf, 3),  # --rounds-per-tick
        (LOCKSTEP + 'engine = "central"\n', 0, math.inf, 0),
    ],
)
def test_the_scene_or_the_flag_decides_otherwise(tmp_path, text, flag, reach, expected):
    assert rounds(text, tmp_path, flag, reach=reach) == expected


def test_the_shipped_large_scenes_agree_every_block_within_its_tick_but_ten_thousand_robots_one_round_a_tick():
    args = SimpleNamespace(rounds_per_tick=None, hardware=None, engine=None)
    for name in ("paper-sequence-1000", "leaf-1000"):
        assert "rounds_per_tick" not in cli._with_rounds_per_tick(args, parse_scene(name), math.inf).robot, name
    ten_thousand = cli._with_rounds_per_tick(args, parse_scene("paper-sequence-10000"), math.inf)
    assert ten_thousand.robot["rounds_per_tick"] == 1
