"""Codecs, keys, faults and the bus on a real zenoh router on loopback."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from transport.bus import Bus
from transport.codec import (
    BY_NAME,
    VERSION,
    Command,
    Commands,
    Contact,
    DropCounter,
    Event,
    Goals,
    Pose,
    Poses,
    State,
    States,
    Tick,
    Truth,
    decode,
)
from transport.faults import FaultSpec, parse_faults
from transport.keys import Keys, cell_of
from transport.session import TransportError, client_of, loopback_router, open_session

SAMPLES = [
    Poses.one(Pose(3, 7, 0.7, 1.5, -2.0, 0.25)),  # a robot alone: a frame of one
    States.one(State(3, 7, 0.7, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL)),
    Commands.one(Command(3, 7, 0.7, Command.WHEELS, 0.1, -0.05, 255, 10, 0)),
    Tick(7, 0.7, 0.1),
    Goals(2, 0, 0.0, 3, np.array([[0.0, 1.0], [2.0, 3.0], [-1.0, 0.5]]), np.array([[255, 0, 0]] * 3, np.uint8)),
    Goals(
        3,
        0,
        30.1,
        2,
        np.array([[0.0, 1.0], [2.0, 3.0]]),
        np.array([[255, 0, 0]] * 2, np.uint8),
        4,
        6.0,
        np.array([0, 5]),
        t_start=30.0,
        frame_period=6.0,
        v_gx=0.01,
        v_gy=-0.02,
        omega_g=0.05,
        p_ogx=0.1,
        p_ogy=-0.1,
        k_eg=0.004,
        geometric=1,
    ),
    Goals(
        4,
        0,
        36.1,
        2,
        np.array([[0.5, 1.0], [2.0, 2.5]]),
        np.array([[0, 255, 0]] * 2, np.uint8),
        5,
        6.0,
        np.array([0, 5]),
        t_start=36.0,
        frame_period=6.0,
        follows=3,
        previous=np.array([1, 0]),
    ),
    Truth(7, 0.7, 0.01, 2, np.zeros((2, 3)), np.ones((2, 2)), np.zeros((2, 3), np.uint8), np.array([1, 2], np.uint32)),
    Contact(0, 1, 2, 0.5, 0.003),
    Event({"kind": "end", "reason": "converged"}),
    States.of(
        7,
        0.7,
        [
            State(3, 7, 0.7, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL, 2, 9),
            State(4, 7, 0.7, -1.0, 0.5, 0.0, 0.2, 0.045, 0.0, 0.0, -1, 0),
        ],
    ),
    Poses(7, 0.7, np.array([(3, 1.5, -2.0, 0.25), (9, 0.5, 0.5, -3.0)], Poses.RECORD)),
    Commands(7, 0.7, np.array([(3, 1, 0.1, -0.05, 255, 10, 0), (4, 1, 0.0, 0.02, 0, 0, 255)], Commands.RECORD)),
]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: m.NAME)
def test_round_trip(msg):
    back = decode(msg.encode())
    assert type(back) is type(msg)
    a, b = msg.to_dict(), back.to_dict()
    for key in a:
        if isinstance(a[key], dict):  # an event's data, or a frame's records as columns
            assert a[key].keys() == b[key].keys()
            for column in a[key]:
                np.testing.assert_array_equal(np.asarray(a[key][column]), np.asarray(b[key][column]))
        elif isinstance(a[key], str):
            assert a[key] == b[key]
        else:
            np.testing.assert_allclose(np.asarray(a[key], float), np.asarray(b[key], float), rtol=1e-6)


def test_messages_are_compact():
    # 10 Hz per robot of each: the per-robot traffic budget (2 KB/s) leaves room for the auction.
    assert len(SAMPLES[0].encode()) <= 32
    assert len(SAMPLES[1].encode()) <= 64  # state, with the agreed assignment it comes from
    assert len(SAMPLES[2].encode()) <= 32


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: m.NAME)
def test_malformed_is_dropped_and_counted(msg):
    data = msg.encode()
    drops = DropCounter()
    assert decode(data[:-1], drops=drops) is None  # truncated
    assert decode(bytes([data[0], VERSION + 1]) + data[2:], drops=drops) is None  # wrong version
    assert decode(b"", drops=drops) is None
    assert decode(bytes([200, VERSION]) + data[2:], drops=drops) is None  # unknown kind
    assert sum(drops.values()) == 4
    assert drops["version"] == 1 and drops["kind"] == 1


def test_non_finite_is_rejected():
    drops = DropCounter()
    assert decode(Poses.one(Pose(1, 1, 0.1, math.nan, 0.0, 0.0)).encode(), drops=drops) is None
    assert decode(States.one(State(1, 1, 0.1, 0, 0, math.inf, 0, 0.045, 0, 0, -1, 0)).encode(), drops=drops) is None
    bad_goals = Goals(1, 0, 0.0, 1, np.array([[np.nan, 0.0]]), np.zeros((1, 3), np.uint8)).encode()
    assert decode(bad_goals, drops=drops) is None
    assert decode(b"\x08\x01" + b'{"a": NaN}', drops=drops) is None
    assert drops["non-finite"] == 4


def test_a_frame_with_one_bad_record_is_dropped_whole():
    """A tracker or host frame is one message: one non-finite pose or command, or an unknown
    command mode, drops it (a robot must not steer by half a frame)."""
    drops = DropCounter()
    poses = SAMPLES[-2].records.copy()
    poses["theta"][1] = np.inf
    assert decode(Poses(7, 0.7, poses).encode(), drops=drops) is None
    commands = SAMPLES[-1].records.copy()
    commands["b"][0] = np.nan
    assert decode(Commands(7, 0.7, commands).encode(), drops=drops) is None
    commands = SAMPLES[-1].records.copy()
    commands["mode"][1] = 7
    assert decode(Commands(7, 0.7, commands).encode(), drops=drops) is None
    states = SAMPLES[-3].records.copy()
    states["radius"][0] = 0.0
    assert decode(States(7, 0.7, states).encode(), drops=drops) is None
    assert drops == {"non-finite": 2, "invalid": 2}
    assert decode(SAMPLES[-2].encode()[:-4], drops=drops) is None and drops["truncated"] == 1
    frame = decode(SAMPLES[-2].encode())
    assert frame.messages()[1] == Pose(9, 7, 0.7, 0.5, 0.5, -3.0)
    assert decode(SAMPLES[-1].encode()).messages()[0] == Command(3, 7, 0.7, 1, *np.float32([0.1, -0.05]), 255, 10, 0)
    # each record is exactly the frame of one its robot would have sent alone
    one = State(3, 7, 0.7, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL, 2, 9)
    assert decode(SAMPLES[-3].encode()).messages()[0] == decode(States.one(one).encode()).messages()[0]


def test_goals_of_an_older_coordinator_decode_as_a_still_image():
    """The keyframe timing and the motion (eq. 27, 28) ride in a trailer: a message without it is read
    as before (no motion, not a keyframe); a torn trailer is dropped; bad values are refused."""
    full = SAMPLES[5]
    data = full.encode()
    old = data[: -Goals._trailer.size]
    back = decode(old)
    assert back is not None and back.epoch == 3 and back.step == 4 and back.robots.tolist() == [0, 5]
    assert (back.t_start, back.frame_period, back.moves) == (0.0, 0.0, False)
    drops = DropCounter()
    assert decode(data[:-3], drops=drops) is None and drops["truncated"] == 1
    for bad in (dict(frame_period=-1.0), dict(geometric=2), dict(geometric=1, k_eg=-1.0), dict(omega_g=math.inf)):
        assert (
            decode(
                Goals(
                    **{
                        **full.to_dict(),
                        **bad,
                        "positions": full.positions,
                        "colors": full.colors,
                        "robots": full.robots,
                    }
                ).encode(),
                drops=drops,
            )
            is None
        ), bad
    assert drops["invalid"] == 3 and drops["non-finite"] == 1


def test_keyframe_correspondence_rides_in_a_second_trailer():
    """The goals' correspondence to the previous keyframe's (6.1) is optional: without it a keyframe
    decodes as before; indices outside the goal set are refused."""
    keyframe = SAMPLES[6]
    back = decode(keyframe.encode())
    assert back.follows == 3 and back.previous.tolist() == [1, 0] and back.frame_period == 6.0
    plain = decode(
        Goals(
            **{
                **keyframe.to_dict(),
                "follows": 0,
                "positions": keyframe.positions,
                "colors": keyframe.colors,
                "robots": keyframe.robots,
            }
        ).encode()
    )
    assert plain.follows == 0 and len(plain.previous) == 0 and plain.frame_period == 6.0
    drops = DropCounter()
    bad = Goals(
        **{
            **keyframe.to_dict(),
            "previous": np.array([0, 2]),
            "positions": keyframe.positions,
            "colors": keyframe.colors,
            "robots": keyframe.robots,
        }
    )
    assert decode(bad.encode(), drops=drops) is None and drops["invalid"] == 1


def test_the_auctions_warm_start_rides_in_a_third_trailer():
    """The matching to the last goal set and its prices (coordinator.keyframes.goal_matching) ride
    after the keyframe correspondence, or alone for the next image of a sequence; a matched index
    outside the set or a non-finite price drops the message."""
    keyframe = SAMPLES[6]
    fields = {
        **keyframe.to_dict(),
        "positions": keyframe.positions,
        "colors": keyframe.colors,
        "robots": keyframe.robots,
    }
    warm = {"matched_from": 3, "matched": np.array([1, 0]), "prices": np.array([0.0, 0.125])}
    both = decode(Goals(**{**fields, **warm}).encode())
    assert both.follows == 3 and both.previous.tolist() == [1, 0]
    assert both.matched_from == 3 and both.matched.tolist() == [1, 0] and both.prices.tolist() == [0.0, 0.125]
    image = decode(Goals(**{**fields, "follows": 0, "frame_period": 0.0, **warm}).encode())
    assert image.follows == 0 and len(image.previous) == 0
    assert image.matched_from == 3 and image.matched.tolist() == [1, 0] and image.prices.tolist() == [0.0, 0.125]
    assert decode(keyframe.encode()).matched_from == 0  # without it: cold, as before
    drops = DropCounter()
    assert decode(Goals(**{**fields, **warm, "matched": np.array([0, 2])}).encode(), drops=drops) is None
    assert decode(Goals(**{**fields, **warm, "prices": np.array([0.0, math.nan])}).encode(), drops=drops) is None
    assert drops["invalid"] == 1 and drops["non-finite"] == 1


def test_wrong_kind_on_a_key_is_dropped():
    drops = DropCounter()
    assert decode(SAMPLES[2].encode(), Poses, drops) is None
    assert drops["kind"] == 1


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_never_raise(data):
    for expected in [None, *BY_NAME.values()]:
        msg = decode(data, expected, DropCounter())
        assert msg is None or isinstance(msg, tuple(BY_NAME.values()))


def test_keys_and_cells():
    k = Keys("lab")
    assert k.pose(3) == "px/lab/pose/3"
    assert k.state((-1, 2), 5) == "px/lab/state/-1/2/5"
    assert k.kind_of(k.state((0, 0), 1)) == "state" and k.kind_of(k.truth) == "sim/truth"
    assert cell_of(-0.01, 0.99, 0.5) == (-1, 1)
    with pytest.raises(ValueError):
        Keys("bad/name")


def test_fault_plan_parsing():
    plan = parse_faults("state:drop=0.1,delay=0.05,jitter=0.01; cmd:drop=0.5")
    assert plan["state"] == FaultSpec(0.1, 0.05, 0.01) and plan["cmd"].drop == 0.5
    for bad in ["state", "state:drop=2", "state:loss=0.1", "state:drop=x"]:
        with pytest.raises(ValueError):
            parse_faults(bad)


@pytest.fixture
def router():
    settings = loopback_router()
    session = open_session(settings)
    yield settings
    session.close()


def _collect(inbox, n, timeout=3.0):
    out, end = [], time.monotonic() + timeout
    while len(out) < n and time.monotonic() < end:
        got = inbox.get(timeout=0.05)
        if got is not None:
            out.append(got)
    return out


def test_bus_publish_subscribe_and_drop_malformed(router):
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        inbox = b.subscribe(b.keys.all_of("pose"), Pose)
        time.sleep(0.3)
        a.put(a.keys.pose(1), bytes([Poses.KIND, VERSION]) + b"garbage")  # malformed: counted, not delivered
        a.publish(a.keys.pose(1), Poses.one(Pose(1, 1, 0.1, 0.0, 0.0, 0.0)))
        a.publish(a.keys.pose(2), Commands.one(Command(2, 1, 0.1, 0, 0, 0, 0, 0, 0)))  # wrong kind on a pose key
        got = _collect(inbox, 1)
        time.sleep(0.2)
        assert [m.robot for _, m in got] == [1] and inbox.get(timeout=0.1) is None
        assert inbox.drops["truncated"] == 1 and inbox.drops["kind"] == 1


def test_fault_injection_drop_and_delay(router):
    faults = {"state": FaultSpec(drop=0.3, delay=0.2)}
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t", faults=faults, seed=3) as b:
        lossy = b.subscribe(b.keys.all_of("state"), State)
        time.sleep(0.3)
        sent = time.monotonic()
        for i in range(200):
            a.publish(a.keys.state((0, 0), i), States.one(State(i, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        assert lossy.get(timeout=0.15) is None  # nothing before the added delay
        got = _collect(lossy, 200, timeout=2.0)
        assert time.monotonic() - sent >= 0.2
        assert 100 < len(got) < 180  # ~30% lost
        assert lossy.drops["fault"] == 200 - len(got)


@pytest.mark.parametrize("fault", [FaultSpec(drop=0.05), FaultSpec(drop=0.05, delay=0.05)], ids=["drop", "delay"])
def test_a_faulty_inbox_rings_its_bell_for_what_it_keeps(router, fault):
    # An agent sleeps on one bell for all its inboxes: a pose that came through a fault plan without a
    # ring waited for the agent's next wake-up, and with 5 % loss every other tick went unanswered.
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t", faults={"pose": fault}, seed=3) as b:
        inbox = b.subscribe(b.keys.all_of("pose"), Pose)
        inbox.bell = threading.Event()
        time.sleep(0.3)
        rung = 0
        for tick in range(20):
            inbox.bell.clear()
            a.publish(a.keys.pose(1), Poses.one(Pose(1, tick, tick * 0.1, 0.0, 0.0, 0.0)))
            if inbox.bell.wait(timeout=2.0):
                rung += 1
                assert _collect(inbox, 1, timeout=2.0)  # kept: it is there once its delay is over
        assert rung + inbox.drops["fault"] == 20 and rung >= 15


def test_liveliness_reports_death(router):
    with Bus(client_of(router), "t") as watcher:
        watch = watcher.watch_alive("agent")
        agent = Bus(client_of(router), "t")
        agent.declare_alive("agent", 4)
        time.sleep(0.3)
        agent.close()
        time.sleep(0.3)
        events = [(role, ident, alive) for role, ident, alive, _ in watch.drain()]
        assert events == [("agent", "4", True), ("agent", "4", False)]


def test_occupied_port_is_a_clear_error(router):
    with pytest.raises(TransportError, match="in use"):
        open_session(router)
