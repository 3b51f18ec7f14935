"""One robot controller in every engine (issue 21): with zero impairment, a lock-step run is the same
run whether every robot steps in one process (the central engine), each robot is its own process, or
K robots share an agent host. Same ticks, same positions at every tick, because every engine calls
the same robot policy (agent.core.policy) on the same information: the states of the tick before,
as the wire carries them."""

from __future__ import annotations

import numpy as np
import pytest

from sim.outputs.mcaplog import read_mcap
from tests.conftest import PAPER_E_PUCKS, run_scenes
from tests.support.engines import (
    ENGINES,
    PICTURE_FLAGS,
    assert_same_trajectory,
    assert_waited_for_everyone,
    engine_run,
    picture,
    picture_run,
)


# Only a parameter whose runs another test reads carries that run's xdist group (--dist loadgroup runs a
# group's tests on one worker in turn); the others, whose runs are their own, go to whichever worker is free.
@pytest.mark.slow
@pytest.mark.parametrize(
    "scene, seed", [pytest.param("swap", 1, marks=pytest.mark.xdist_group("swap-seed-1")), ("circle", 2)]
)
def test_central_and_distributed_runs_of_one_seed_are_the_same_run(shared_runs, scene, seed):
    runs = {name: engine_run(shared_runs, scene, seed, name) for name in ENGINES}
    (m_central, central) = runs["central"]
    assert m_central["contacts"] == 0 and m_central["converged"]
    for name in ("a process per robot", "agent hosts"):
        metrics, traj = runs[name]
        assert_waited_for_everyone(metrics, name)  # every agent answered every tick
        assert_same_trajectory(traj, central, name)
        np.testing.assert_allclose(traj["goal"][-1], central["goal"][-1], rtol=0, atol=1e-9)
        assert metrics["time_to_converge_s"] == pytest.approx(m_central["time_to_converge_s"], abs=1e-9)


def short_story(tmp_path) -> str:
    """The shipped story with every keyframe from the second on 13 s earlier: the robots cross to the
    first walker in 12 s instead of 25 (at under half the e-puck's speed), so a run into the second
    keyframe is half as long. The keyframes, the robots and the rest are the story's."""
    from coordinator.scene import SCENE_DIR

    text = (SCENE_DIR / "story.toml").read_text()
    shipped = "times = [0.0, 25.0, 33.0, 41.0, 56.0, 71.0, 79.0]"
    assert shipped in text, "the shipped story's keyframe times changed: change them here too"
    path = tmp_path / "story.toml"
    path.write_text(text.replace(shipped, "times = [0.0, 12.0, 20.0, 28.0, 43.0, 58.0, 66.0]"))
    return str(path)


STORY_FLAGS = ("--seed", "1", "--duration", "13")  # into the second keyframe, which starts at 12 s


def assert_the_same_run(runs: dict[str, tuple[dict, dict]], central: dict) -> None:
    """Every engine's run is the central one: every tick answered, the same ticks, positions and
    assignment, and one-to-one at every tick."""
    for name, (metrics, traj) in runs.items():
        assert_waited_for_everyone(metrics, name)
        assert_same_trajectory(traj, central, name)
        np.testing.assert_array_equal(traj["assignment"], central["assignment"], err_msg=name)
        for k, row in enumerate(traj["assignment"]):
            assert len(np.unique(row[row >= 0])) == int((row >= 0).sum()), f"{name}: one goal, two robots, tick {k}"


@pytest.mark.slow
@pytest.mark.parametrize(
    "scene, flags",
    [
        # an image: the auction settles a block every tick (its runs are test_sync_auction's too)
        pytest.param("picture", PICTURE_FLAGS, marks=pytest.mark.xdist_group("picture-30")),
        ("story", STORY_FLAGS),  # an animation of 14 robots, into its second keyframe
    ],
)
def test_the_auction_is_the_same_in_every_engine(tmp_path, shared_runs, scene, flags):
    """Tick-synchronous auction: every engine adopts the same agreement at the same tick, so the run
    is the same, and every recorded tick is one-to-one."""
    if scene == "picture":
        runs = {name: picture_run(shared_runs, tmp_path, name) for name in ENGINES}
    else:  # with the default rounds per tick of a scene made for agent processes (lockstep_auction.md)
        story = short_story(tmp_path)
        runs = {name: shared_runs.run(story, "--clock", "lockstep", *flags, *ENGINES[name]) for name in ENGINES}
    _, central = runs["central"]
    assert (central["assignment"] >= 0).all()  # every robot holds a goal from the first tick on
    assert len(np.unique(central["step"])) == (2 if scene == "story" else 1)
    assert_the_same_run(runs, central)


@pytest.mark.slow  # its runs are its own (--rounds-per-tick 2): in no xdist group
@pytest.mark.parametrize(
    "scene, flags",
    [
        ("picture", PICTURE_FLAGS),  # a cold start of many rounds, which still agrees within its tick
        ("story", STORY_FLAGS),  # into the second keyframe: its warm blocks span ticks
    ],
)
def test_with_rounds_per_tick_bounded_blocks_span_ticks_and_every_engine_runs_the_same(
    tmp_path, shared_runs, scene, flags
):
    """`--rounds-per-tick 2`: a block of phases goes on over the ticks after its own while the robots
    drive to the last agreement, the next keyframe starts from the coordinator's warm start (its
    robots drive to the matched goals at once), and every engine adopts each agreement at the same
    tick. A cold start, whose robots have nothing to drive to, still agrees within its tick.

    The engines here are the central one and agent hosts: a process per robot is an agent host of
    one robot, the same AuctionLink and block rounds whatever the host holds, and its records cross
    the wire as the hosts' do; test_the_auction_is_the_same_in_every_engine runs it on these scenes."""
    source = picture(tmp_path) if scene == "picture" else short_story(tmp_path)
    lockstep = ("--clock", "lockstep", *flags)
    engines = [name for name in ENGINES if name != "a process per robot"]
    done = run_scenes(  # at once: a lock-step run is the same run beside another
        tmp_path,
        {name.replace(" ", "-"): (source, *lockstep, "--rounds-per-tick", "2", *ENGINES[name]) for name in engines},
    )
    runs = {name: done[name.replace(" ", "-")] for name in engines}
    _, central = runs["central"]
    if scene == "story":  # its robots cross the arena: warm blocks span ticks, agreements come later
        _, unbounded = shared_runs.run(source, *lockstep, "--rounds-per-tick", "0", *ENGINES["central"])
        assert not np.array_equal(central["assignment"], unbounded["assignment"])
    assert (central["assignment"] >= 0).all()  # the cold start agreed at the first tick
    for k in np.flatnonzero(np.diff(central["step"])) + 1:  # the next keyframe: the matched goals at once
        assert (central["assignment"][k] != central["assignment"][k - 1]).any()
    assert all(metrics["contacts"] == 0 for metrics, _ in runs.values())
    assert_the_same_run(runs, central)


# The paper's first three shapes with the second held for half a second: at one auction round a tick
# its warm block cannot agree before the third comes.
UNAGREED_SEQUENCE = (
    'name = "unagreed-image"'
    + PAPER_E_PUCKS
    + """
[[steps]]
shape = "disk"
hold = 2.0
[[steps]]
shape = "disk_and_line"
region_counts = { 0 = 10, 1 = 4 }
hold = 0.5
[[steps]]
shape = "disk_and_line"
region_counts = { 0 = 4, 1 = 10 }
hold = 3.0
"""
)


@pytest.mark.slow
def test_an_image_whose_block_never_agreed_hands_its_warm_board_to_the_next_in_every_engine(tmp_path):
    """The ten-thousand-robot case, at 14: an image's warm block outlasts its hold, so its auction never
    agrees; the next image starts warm from the board the unagreed one started from (a cold start
    would agree within its first tick, every round played in it). The central engine and agent hosts
    take the same path: the same run to the bit, one-to-one at every tick, no contact."""
    flags = ("--clock", "lockstep", "--rounds-per-tick", "1")
    engines = {"central": ENGINES["central"], "agent-hosts": ("--engine", "distributed", "-k", "7")}
    runs = run_scenes(tmp_path, {name: (UNAGREED_SEQUENCE, *flags, *engine) for name, engine in engines.items()})
    _, central = runs["central"]
    assert list(np.unique(central["step"])) == [0, 1, 2]
    assert (central["assignment"] >= 0).all()  # every robot drives to a goal at every tick
    assert all(metrics["contacts"] == 0 for metrics, _ in runs.values())
    assert_the_same_run(runs, central)
    stats = [e for e in read_mcap(tmp_path / "agent-hosts" / "log.mcap", ["/event"])["/event"] if e["kind"] == "stats"]
    assert len(stats) == 2
    # only the first image agreed: the second's block never did, and the third's, warm, not in its 3 s
    for host in stats:
        assert len(host["auction"]["first_agreement_s"]) == 1, host["auction"]


@pytest.mark.slow
def test_a_block_older_than_its_bound_is_dropped_at_the_same_tick_in_every_engine(tmp_path):
    """block_max_age: the third image's warm block, which would not agree within its 3 s, is dropped
    each second and begun again on that tick's positions, by the central engine and by each agent
    host at the same tick (the ticks' stamps): the same run to the bit, one-to-one, no contact."""
    scene = UNAGREED_SEQUENCE.replace("[robot]\n", "[robot]\nblock_max_age = 1.0\n", 1)
    flags = ("--clock", "lockstep", "--rounds-per-tick", "1")
    engines = {"central": ENGINES["central"], "agent-hosts": ("--engine", "distributed", "-k", "7")}
    runs = run_scenes(tmp_path, {name: (scene, *flags, *engine) for name, engine in engines.items()})
    _, central = runs["central"]
    assert all(metrics["contacts"] == 0 for metrics, _ in runs.values())
    assert_the_same_run(runs, central)
    stats = [e for e in read_mcap(tmp_path / "agent-hosts" / "log.mcap", ["/event"])["/event"] if e["kind"] == "stats"]
    assert [host["auction"]["dropped_blocks"] >= 2 for host in stats] == [True, True], stats


# The shipped 100-robot sequence into the end of its fourth image, the line, at its agent hosts' one
# auction round a tick: once the line has formed, a block agreed on positions frozen seconds before
# swapped neighbours' goals, and the next swapped them back.
STALE_FLAGS = ("--engine", "central", "--rounds-per-tick", "1", "--duration", "174.9")


@pytest.mark.slow
def test_a_formed_image_is_not_reshuffled_by_a_stale_block(tmp_path):
    """Every image of paper-sequence-100 ends its hold with every robot on its goal (it was 0.7 m off at
    the line's end while blocks were adopted however old: docs/lockstep_auction.md)."""
    metrics, _ = run_scenes(tmp_path, {"run": ("paper-sequence-100", *STALE_FLAGS)})["run"]
    assert metrics["contacts"] == 0 and len(metrics["steps"]) == 4
    ends = [step["max_goal_error_at_end"] for step in metrics["steps"]]
    assert max(ends) <= metrics["convergence_tolerance_m"], ends
