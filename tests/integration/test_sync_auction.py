"""The tick-synchronous auction (issue 21): in lock-step a block of phases starts at tick k on tick k's
positions, every host bids in numbered Jacobi rounds against the board as merged after the round
before, and everyone adopts the agreement at tick k. The rounds are the central engine's
(Participant.settle_alone) bid for bid, so the boards are equal to the bit; over the bus two hosts
settle a block that way; and two lock-step runs of a 30-robot picture are the same run, one-to-one at
every tick, while two busy processes load both cores."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from agent.assignment import AuctionLink, LockStepRounds
from agent.core.bidder import Participant
from agent.core.params import RobotParams
from agent.core.rounds import BlockRounds
from sim.central.engine import play
from tests.conftest import assert_usage_error, reap, run_scene
from tests.support.engines import ENGINES, PICTURE_FLAGS, picture, picture_run
from transport.bus import Bus
from transport.codec import Goals, Timing
from transport.session import client_of, loopback_router, open_session

EPS, HYSTERESIS = 1e-3, 5e-3  # epsilon_A and Delta C, m^2 (agent.core.params defaults)


def hosts_settle(hosts: list[Participant], positions: np.ndarray) -> int:
    """One block in lock-step rounds among these participants (each a host's robots), records passed
    by hand as the bus passes them; returns the rounds it took."""
    blocks = [BlockRounds(h, positions) for h in hosts]
    for r in range(1, 100_000):
        said = {i: block.say() for i, block in enumerate(blocks)}
        agreed = [block.hear({j: recs for j, recs in said.items() if j != i}) for i, block in enumerate(blocks)]
        assert len(set(agreed)) == 1, "hosts disagree on whether the round ended the block"
        if agreed[0]:
            return r
    raise AssertionError("the block did not settle")


@pytest.mark.parametrize("robots, split", [(16, 1), (30, 5), (23, 4)])
def test_lockstep_rounds_give_the_central_board_to_the_bit(robots, split):
    rng = np.random.default_rng(robots + split)
    goals = rng.uniform(-2.0, 2.0, (robots, 2))
    ids = list(range(robots))
    central = Participant(1, goals, ids, ids, EPS, HYSTERESIS)
    hosts = [Participant(1, goals, ids, ids[a : a + split], EPS, HYSTERESIS) for a in range(0, robots, split)]
    position = rng.uniform(-3.0, 3.0, (robots, 2))
    for block in range(5):  # a cold start, then warm blocks as the robots drive, with a deadlock penalty
        if block == 3:
            robot, goal = 4, int(central.goal[4])
            central.penalise(robot, goal, 0.5)
            next(h for h in hosts if robot in h.own).penalise(robot, goal, 0.5)
        assigned = central.settle_alone(position)
        rounds = hosts_settle(hosts, position)
        assert rounds >= 1
        for h in hosts:
            np.testing.assert_array_equal(h.board.price, central.board.price)
            np.testing.assert_array_equal(h.board.owner, central.board.owner)
            np.testing.assert_array_equal(h.board.released, central.board.released)
            assert h.agreed_instance == central.agreed_instance
            assert h.agreed == {r: int(assigned[r]) for r in h.own}
        assert len(np.unique(assigned)) == robots  # one-to-one
        position = position + 0.3 * (goals[assigned] - position) + rng.normal(0.0, 0.01, position.shape)


def test_a_damaged_copy_naming_a_robot_outside_the_goal_set_does_not_stop_a_host():
    """A faulty peer's copy of a host's first records of a block, its robot id damaged to 128 in a goal
    set of 16: AuctionLink._round asks robots_of with the raw records before hear, and the id then
    indexed the robots' flags (IndexError: the agent process died). The block still agrees on the
    central board."""
    rng = np.random.default_rng(5)
    goals, ids = rng.uniform(-2.0, 2.0, (16, 2)), list(range(16))
    position = rng.uniform(-3.0, 3.0, (16, 2))
    central = Participant(1, goals, ids, ids, EPS, HYSTERESIS)
    hosts = [Participant(1, goals, ids, ids[a : a + 4], EPS, HYSTERESIS) for a in range(0, 16, 4)]
    assigned = central.settle_alone(position)
    blocks = [BlockRounds(h, position) for h in hosts]
    for r in range(1, 100_000):
        said = {i: block.say() for i, block in enumerate(blocks)}
        if r == 1:
            forged = said[1].copy()
            forged["robot"][:] = 128
            blocks[0].robots_of(1, forged)  # heard first, as the link counts who spoke
        agreed = [block.hear({j: recs for j, recs in said.items() if j != i}) for i, block in enumerate(blocks)]
        if all(agreed):
            break
    for h in hosts:
        np.testing.assert_array_equal(h.board.owner, central.board.owner)
        assert h.agreed == {r: int(assigned[r]) for r in h.own}


def settle_first_block(links: list[AuctionLink], message: Goals, start: np.ndarray) -> None:
    """Every host takes the goal set up and settles its first block over the bus at tick 0, each in
    its own thread, as agent hosts do in their processes."""
    time.sleep(0.5)  # every subscription declared before the first round
    for link in links:
        link.on_goals(message, {})
    where = {r: start[r] for r in range(len(start))}
    threads = [threading.Thread(target=link.on_tick, args=(0.0, where)) for link in links]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30.0)
    assert not any(t.is_alive() for t in threads)


def test_two_hosts_settle_a_block_over_the_bus_at_the_same_round():
    goals = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    start = np.array([[2.9, 0.1], [2.1, -0.1], [0.2, 0.0], [1.1, 0.2]])
    params = RobotParams(kinematics="holonomic")
    message = Goals(1, 0, goals, np.full((4, 3), 200, np.uint8), np.arange(4), Timing(0.0, 0, 60.0))
    central = Participant(1, message.positions, [0, 1, 2, 3], [0, 1, 2, 3], params.assign_eps, params.assign_hysteresis)
    expected = central.settle_alone(start)
    router = loopback_router()
    session = open_session(router)
    told: dict[int, dict[int, int]] = {}
    try:
        with Bus(client_of(router), "sync") as bus_a, Bus(client_of(router), "sync") as bus_b:
            links = [
                AuctionLink(bus, own, params, lambda e, i, g, p, c: told.update({min(g): g}), lockstep=LockStepRounds())
                for bus, own in ((bus_a, [0, 1]), (bus_b, [2, 3]))
            ]
            settle_first_block(links, message, start)
            assert [link.counts.rounds for link in links][0] == links[1].counts.rounds >= 1
            for link in links:
                assert link.part is not None and link.part.is_agreed and link.counts.abandoned == 0
                np.testing.assert_array_equal(link.part.board.price, central.board.price)
    finally:
        session.close()
    assert told == {0: {0: int(expected[0]), 1: int(expected[1])}, 2: {2: int(expected[2]), 3: int(expected[3])}}


def test_a_block_with_one_round_a_tick_spans_ticks_and_is_agreed_at_one_tick_by_every_host():
    """rounds_per_tick = 1: the cold start agrees within tick 0 (its robots have nothing to drive to);
    once the robots have moved, the next block goes on over the ticks after its own, and every host
    adopts its agreement at the same tick, the one at which the central engine's single host
    (sim.central.engine.play, a round a tick, heard at the next) adopts it, with its board."""
    goals = np.array([[0.0, 0.0], [0.3, 0.0], [0.6, 0.0], [0.9, 0.0], [1.2, 0.0], [1.5, 0.0]])
    start = np.array([[0.1, 0.5], [0.2, 0.5], [0.3, 0.5], [0.4, 0.5], [0.5, 0.5], [0.6, 0.5]])
    moved = start[::-1] + [1.0, 0.0]  # the robots' order reversed: the agreement must change
    params = RobotParams(kinematics="holonomic", rounds_per_tick=1)
    message = Goals(1, 0, goals, np.full((6, 3), 200, np.uint8), np.arange(6), Timing(0.0, 0, 60.0))
    ids = list(range(6))
    central = Participant(1, message.positions, ids, ids, params.assign_eps, params.assign_hysteresis)
    cold = dict(zip(ids, central.settle_alone(start).tolist()))  # the cold start: as the link's, within tick 0
    block = BlockRounds(central, moved)  # from tick 1 on
    # each tick hears the round the last one left open, then says its own (sim.central.engine.play)
    heard_or_played = lambda: (block.open and block.hear({})) or play(block, params.rounds_per_tick)  # noqa: E731
    warm_tick = next(tick for tick in range(1, 1000) if heard_or_played())
    assert warm_tick >= 3  # the block spans ticks
    agreed_board = central.board.price.copy()  # the hosts begin the next block in that tick: its prices tilt
    assert central.agreed != cold
    router = loopback_router()
    session = open_session(router)
    told: dict[int, list[tuple[int, dict[int, int]]]] = {0: [], 3: []}  # host's first robot -> (tick, goals)
    boards: dict[int, np.ndarray] = {}  # host's first robot -> its board when it adopted the last agreement
    tick = 0

    def adopted(links: list[AuctionLink], k: int) -> Callable[..., None]:
        def note(epoch: int, instance: int, goals: dict[int, int], *_: object) -> None:
            told[min(goals)].append((tick, goals))
            boards[min(goals)] = links[k].part.board.price.copy()

        return note

    try:
        with Bus(client_of(router), "sync") as bus_a, Bus(client_of(router), "sync") as bus_b:
            links: list[AuctionLink] = []
            for k, (bus, own) in enumerate(((bus_a, [0, 1, 2]), (bus_b, [3, 4, 5]))):
                links.append(AuctionLink(bus, own, params, adopted(links, k), lockstep=LockStepRounds()))
            time.sleep(0.5)  # every subscription declared before the first round
            for link in links:
                link.on_goals(message, {})
            for tick in range(warm_tick + 1):
                where = {r: (start if tick == 0 else moved)[r] for r in ids}
                threads = [threading.Thread(target=link.on_tick, args=(tick * params.dt, where)) for link in links]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(timeout=30.0)
                assert not any(t.is_alive() for t in threads)
            for link in links:
                assert link.counts.abandoned == 0
                assert link.part is not None and link.part.agreed_instance == central.agreed_instance
    finally:
        session.close()
    for first, own in ((0, [0, 1, 2]), (3, [3, 4, 5])):
        np.testing.assert_array_equal(boards[first], agreed_board)
        assert told[first] == [
            (0, {r: cold[r] for r in own}),
            (warm_tick, {r: central.agreed[r] for r in own}),
        ]


def assert_one_to_one(traj: dict) -> None:
    for k, row in enumerate(traj["assignment"]):
        held = row[row >= 0]
        assert len(np.unique(held)) == len(held), f"two robots drive to one goal at tick {k}: {row}"


@pytest.mark.slow
@pytest.mark.xdist_group("picture-30")
def test_two_lockstep_runs_of_a_picture_are_identical_under_load(tmp_path, shared_runs):
    image = picture(tmp_path)  # agent hosts of 10 robots (each robot its own process: test_one_controller.py)
    flags = ("--clock", "lockstep", *PICTURE_FLAGS, *ENGINES["agent hosts"])
    # the quiet run is test_one_controller's run of the picture in agent hosts, made once for both
    quiet = picture_run(shared_runs, tmp_path, "agent hosts")
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]  # both cores
    try:
        loaded = run_scene(tmp_path, image, *flags, name="loaded")
    finally:
        for p in busy:
            p.kill()
            p.wait(timeout=10)
    assert not reap([p.pid for p in busy])
    for metrics, traj in (quiet, loaded):
        assert metrics["missed_ticks"] == 0 and metrics["converged"]
        assert_one_to_one(traj)
    (_, a), (_, b) = quiet, loaded
    np.testing.assert_array_equal(a["t"], b["t"])
    np.testing.assert_array_equal(a["pose"], b["pose"])
    np.testing.assert_array_equal(a["assignment"], b["assignment"])


def test_after_a_blocks_first_round_hosts_send_only_the_claims_that_changed():
    """Three hosts of ten robots settle a cold block over the bus, to the central engine's board:
    each host's first round claims for every one of its robots, later rounds only for the robots
    whose claim changed (nobody needs the rest again), so the rounds after the first carry fewer
    claims than a claim per robot and round."""
    from transport.codec import Bid, decode

    rng = np.random.default_rng(7)
    goals, start = rng.uniform(-1.0, 1.0, (30, 2)), rng.uniform(-1.5, 1.5, (30, 2))
    params = RobotParams(kinematics="holonomic")
    message = Goals(1, 0, goals, np.full((30, 3), 200, np.uint8), np.arange(30), Timing(0.0, 0, 60.0))
    central = Participant(
        1, message.positions, list(range(30)), list(range(30)), params.assign_eps, params.assign_hysteresis
    )
    central.settle_alone(start)
    router = loopback_router()
    session = open_session(router)
    sent: list[Bid] = []
    try:
        with Bus(client_of(router), "sync") as listener:
            listener.session.declare_subscriber(
                listener.keys.all_of("auction"), lambda s: sent.append(decode(s.payload.to_bytes(), Bid))
            )
            buses = [Bus(client_of(router), "sync") for _ in range(3)]
            try:
                links = [
                    AuctionLink(
                        bus, list(range(10 * h, 10 * h + 10)), params, lambda *a: None, lockstep=LockStepRounds()
                    )
                    for h, bus in enumerate(buses)
                ]
                settle_first_block(links, message, start)
                time.sleep(0.2)  # the listener hears the last round
                rounds = links[0].counts.rounds
                assert rounds > 1 and all(link.counts.rounds == rounds and link.part.is_agreed for link in links)
                for link in links:
                    np.testing.assert_array_equal(link.part.board.price, central.board.price)
                    np.testing.assert_array_equal(link.part.board.owner, central.board.owner)
            finally:
                for bus in buses:
                    bus.close()
    finally:
        session.close()
    claims = {(m.sender, m.serial): int(((m.records["flags"] & 2) == 0).sum()) for m in sent}
    assert all(claims[(10 * h, 1)] == 10 for h in range(3))
    later = sum(n for (_, r), n in claims.items() if r > 1)
    assert later < 30 * (rounds - 1), (later, rounds)


@pytest.mark.parametrize(
    "flags, message",
    [
        (("--rounds-per-tick", "-1"), "--rounds-per-tick must be a whole number >= 0"),
        (("--rounds-per-tick", "2", "--clock", "realtime"), "--rounds-per-tick needs the lock-step clock"),
        (("--rounds-per-tick", "2", "--range", "0.5"), "--rounds-per-tick is not supported with --range"),
    ],
)
def test_a_bad_rounds_per_tick_is_one_line_and_exit_2(tmp_path, flags, message):
    assert_usage_error(tmp_path, message, "swap", *flags)


def test_a_scene_whose_rounds_per_tick_is_not_whole_is_one_line_and_exit_2(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('robots = 3\nclock = "lockstep"\n[robot]\nrounds_per_tick = 1.5\n')
    assert_usage_error(tmp_path, "rounds_per_tick must be a whole number", str(scene))
