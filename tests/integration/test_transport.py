"""Codecs, keys, faults and the bus on a real zenoh router on loopback."""

from __future__ import annotations

import dataclasses
import math
import signal
import struct
import subprocess
import threading
import time
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import transport.bus as bus_module
from agent.core.bidder import RECORD as bidder_record
from tests.conftest import REPO, deafen, pixelswarm_cmd, wait_for
from transport.bus import CLOSE_LINGER, Bus, KeepRobots
from transport.codec import (
    BEFORE_START,
    BY_NAME,
    VERSION,
    AuctionRecord,
    Bid,
    Boards,
    Command,
    Commands,
    Contact,
    Correspondence,
    DropCounter,
    Event,
    Goals,
    Lives,
    Motion,
    Pose,
    Poses,
    State,
    States,
    Tick,
    Timing,
    Truth,
    WarmStart,
    decode,
    decode_views,
    life_number,
    with_checksum,
)
from transport.faults import FaultSpec, parse_faults
from transport.keys import Keys, cell_of, robots_ident, robots_of_ident
from transport.session import TransportError, ZenohSettings, client_of, free_port, loopback_router, open_session

SAMPLES = [
    Poses.one(Pose(3, 7, 0.7, 1.5, -2.0, 0.25)),  # a robot alone: a frame of one
    States.one(State(3, 7, 0.7, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL)),
    Commands.one(Command(3, 7, 0.7, Command.WHEELS, 0.1, -0.05, 255, 10, 0)),
    Tick(7, 0.7, 0.1),
    Goals(2, 0, np.array([[0.0, 1.0], [2.0, 3.0], [-1.0, 0.5]]), np.array([[255, 0, 0]] * 3, np.uint8)),
    Goals(
        3,
        0,
        np.array([[0.0, 1.0], [2.0, 3.0]]),
        np.array([[255, 0, 0]] * 2, np.uint8),
        np.array([0, 5]),
        Timing(30.1, 4, 6.0, t_start=30.0, frame_period=6.0),
        Motion(v_gx=0.01, v_gy=-0.02, omega_g=0.05, p_ogx=0.1, p_ogy=-0.1, k_eg=0.004, geometric=1),
    ),
    Goals(
        4,
        0,
        np.array([[0.5, 1.0], [2.0, 2.5]]),
        np.array([[0, 255, 0]] * 2, np.uint8),
        np.array([0, 5]),
        Timing(36.1, 5, 6.0, t_start=36.0, frame_period=6.0),
        correspondence=Correspondence(3, np.array([1, 0])),
        warm_start=WarmStart(3, np.array([1, 0]), np.array([0.0, 0.125])),
        lives=Lives(np.array([0xDEADBEEF, 0])),
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
    _same(msg.to_dict(), back.to_dict())


def _same(a, b):
    """Equal as logged: records (arrays) exactly, other numbers to float32's precision."""
    if isinstance(a, dict):  # an event's data, a frame's records as columns, a goal set's part
        assert a.keys() == b.keys()
        for key in a:
            _same(a[key], b[key])
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, str) or a is None:
        assert a == b
    else:
        np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=1e-6)


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
    bad_goals = Goals(1, 0, np.array([[np.nan, 0.0]]), np.zeros((1, 3), np.uint8)).encode()
    assert decode(bad_goals, drops=drops) is None
    assert decode(with_checksum(bytes([Event.KIND, VERSION]) + b'{"a": NaN}'), drops=drops) is None
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


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_an_inbox_reads_a_frame_as_views_exactly_as_the_frame_decodes(data):
    """Inboxes read a frame of one with struct (Frame.views_first), frames decode with numpy: the same views
    and the same verdict on every record, good or bad, from one layout and one set of rules."""
    frame_kind = data.draw(st.sampled_from([Poses, States, Commands]))
    count = data.draw(st.integers(0, 3))
    raw = bytearray(
        data.draw(st.binary(min_size=count * frame_kind.RECORD.itemsize, max_size=count * frame_kind.RECORD.itemsize))
    )
    records = np.frombuffer(bytes(raw), frame_kind.RECORD)
    header = bytes([frame_kind.KIND, VERSION]) + frame_kind._fixed.pack(7, 0.7)
    wire = header + records.tobytes()
    wire = with_checksum(wire) if frame_kind.CHECKED else wire  # the records' verdict, not the checksum's
    frame_drops, view_drops = DropCounter(), DropCounter()
    frame, views = decode(wire, frame_kind, frame_drops), decode_views(wire, frame_kind, view_drops)
    first = frame_kind.views_first(wire)  # a robot's own key: its record, then the bodies near it
    assert frame_drops == view_drops
    if frame is None:
        assert views is None and first is None
    else:
        assert views == (7, frame.messages())
        assert (first is None) == (frame.count == 0)
        if first is not None:
            assert first[:2] == (7, frame.messages()[:1])
            assert frame.records[1:].tobytes() == (b"" if first[2] is None else first[2].tobytes())


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_a_robot_alone_encodes_its_frame_of_one_byte_for_byte_as_the_frame_does(data):
    """An agent packs its state and command with struct (Frame.encode_one), the world and hosts
    build numpy frames: the same bytes on the wire, whatever the record holds."""
    frame_kind = data.draw(st.sampled_from([Poses, States, Commands]))
    raw = data.draw(st.binary(min_size=frame_kind.RECORD.itemsize, max_size=frame_kind.RECORD.itemsize))
    record = np.frombuffer(raw, frame_kind.RECORD)
    tick = data.draw(st.integers(0, 2**32 - 1))
    stamp = data.draw(st.floats(allow_nan=False))
    view = frame_kind(tick, stamp, record).messages()[0]
    assert frame_kind.encode_one(view) == frame_kind.one(view).encode()


def test_an_inbox_drops_what_a_frame_drops():
    drops = DropCounter()
    bad = SAMPLES[-3].records.copy()
    bad["radius"][1] = -0.1
    assert decode_views(States(7, 0.7, bad).encode(), States, drops) is None
    bad = SAMPLES[-3].records.copy()
    bad["goal_y"][0] = np.nan
    assert decode_views(States(7, 0.7, bad).encode(), States, drops) is None
    assert decode_views(SAMPLES[-2].encode()[:-4], Poses, drops) is None
    assert decode_views(SAMPLES[-2].encode(), States, drops) is None
    assert drops == {"invalid": 1, "non-finite": 1, "truncated": 1, "kind": 1}
    bad["radius"][1] = 0.0  # a bad number and a broken rule: dropped for the number, as a frame is
    assert decode_views(States(7, 0.7, bad).encode(), States, drops) is None
    assert decode(States(7, 0.7, bad).encode(), States, drops) is None
    assert drops["non-finite"] == 3


def test_a_state_damaged_on_its_way_is_dropped_not_believed():
    """A state whose goal changed on its way still reads as a state: its checksum drops it, or
    neighbours would steer by it and the recorder would take it for the goal the robot holds. Its
    layout by hand (docs/protocol.md): header, tick, stamp, robot, seven f32 from x to goal_y, ...,
    the CRC-32 of everything before it."""
    one = State(3, 7, 0.7, 1.0, 2.0, 0.1, -0.1, 0.045, 0.5, 0.5, 4, State.HAS_GOAL, 2, 9)
    data = States.one(one).encode()
    assert len(data) == 14 + 45 + 4 and struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])
    goal_x_at = 14 + 4 + 5 * 4
    damaged = bytearray(data)
    damaged[goal_x_at + 3] ^= 0x01  # one bit of the goal x's exponent: 0.5 becomes 0.125
    drops = DropCounter()
    assert decode(bytes(damaged), States, drops) is None
    assert decode_views(bytes(damaged), States, drops) is None
    assert drops == {"checksum": 2}
    # the same bytes sealed again (a sender that meant them) read as that other goal
    (state,) = decode(with_checksum(bytes(damaged[:-4])), States).messages()
    assert (state.robot, state.goal_x, state.goal_y) == (3, 0.125, 0.5)


def test_what_the_recorder_believes_damaged_on_its_way_is_dropped_not_believed():
    """The world's truth and contacts and the run's events go into metrics.json as they come: a copy
    damaged on its way that still decodes (a faulty peer's once put a drop reason 'trRncated' there)
    is dropped by its checksum. Sealed anew (a sender that meant them) the same bytes would read."""
    stats = Event({"kind": "stats", "dropped": {"truncated": 3}})
    truth = Truth(
        7, 0.7, 0.01, 1, np.zeros((1, 3)), np.zeros((1, 2)), np.zeros((1, 3), np.uint8), np.ones(1, np.uint32)
    )
    contact = Contact(0, 1, 2, 0.5, 0.003)
    drops = DropCounter()
    for msg, damage in (
        (stats, lambda b: b.replace(b"truncated", b"trRncated")),
        (truth, lambda b: b[:6] + struct.pack("<d", 70.0) + b[14:]),  # a stamp from the future
        (contact, lambda b: b[:-8] + struct.pack("<f", 0.3) + b[-4:]),  # a contact 100 times deeper
    ):
        data = msg.encode()
        assert struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])
        damaged = damage(data[:-4]) + data[-4:]
        assert decode(damaged, type(msg), drops) is None
        sealed = decode(with_checksum(damaged[:-4]), type(msg))
        assert sealed is not None and sealed != msg
    assert drops == {"checksum": 3}


def _parts(data: bytes) -> list[tuple[int, int, bytes]]:
    """A Goals message's parts as (part kind, part version, body), read by hand from the layout in
    docs/protocol.md: after the header, parts up to the CRC-32 of everything before it."""
    assert struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])
    data, out, at = data[:-4], [], 2
    while at < len(data):
        kind, version, length = struct.unpack_from("<BBI", data, at)
        out.append((kind, version, data[at + 6 : at + 6 + length]))
        at += 6 + length
    return out


def _sealed(data: bytes) -> bytes:
    """A goal set's bytes and their CRC-32, by hand."""
    return data + struct.pack("<I", zlib.crc32(data))


def _join(parts: list[tuple[int, int, bytes]]) -> bytes:
    return _sealed(bytes([Goals.KIND, VERSION]) + b"".join(struct.pack("<BBI", k, v, len(b)) + b for k, v, b in parts))


def test_a_goal_set_is_its_parts_each_with_its_own_header_and_absent_parts_are_absent():
    """The goal set comes first, then timing, then only the parts that apply: a still image has no
    motion part and decodes as still; a keyframe with a warm start carries both of those parts."""
    still, moving, keyframe = SAMPLES[4:7]
    assert [(k, v) for k, v, _ in _parts(still.encode())] == [(Goals.PART, 1), (Timing.PART, 1)]
    assert [k for k, _, _ in _parts(moving.encode())] == [Goals.PART, Timing.PART, Motion.PART]
    assert [k for k, _, _ in _parts(keyframe.encode())] == [
        Goals.PART,
        Timing.PART,
        Correspondence.PART,
        WarmStart.PART,
        Lives.PART,
    ]
    back = decode(still.encode())
    assert back.motion is None and not back.moves and back.correspondence is None and back.warm_start is None
    back = decode(moving.encode())
    assert back.moves and back.timing == Timing(30.1, 4, 6.0, 30.0, 6.0) and back.motion.geometric == 1
    back = decode(keyframe.encode())
    assert back.correspondence.follows == 3 and back.correspondence.previous.tolist() == [1, 0]
    assert back.warm_start.matched_from == 3 and back.warm_start.matched.tolist() == [1, 0]
    assert back.warm_start.prices.tolist() == [0.0, 0.125] and back.robots.tolist() == [0, 5]
    assert back.lives.life.tolist() == [0xDEADBEEF, 0]  # robot 0's agent in that life, robot 5's in any
    # the goal set part by hand: epoch, per_robot, count, then the goals and the robots to its end
    body = _parts(keyframe.encode())[0][2]
    assert struct.unpack_from("<IBI", body) == (4, 0, 2) and len(body) == 9 + 2 * 11 + 2 * 2


def test_a_part_of_an_unknown_version_drops_the_goal_set_and_an_unknown_part_is_skipped():
    drops = DropCounter()
    parts = _parts(SAMPLES[6].encode())
    for i in range(len(parts)):  # each part has its own version: a newer one of any is refused
        kind, version, body = parts[i]
        newer = parts[:i] + [(kind, version + 1, body)] + parts[i + 1 :]
        assert decode(_join(newer), drops=drops) is None
    assert drops == {"version": len(parts)}
    later = decode(_join(parts + [(200, 1, b"a part added later")]))  # skipped: the rest still holds
    assert later is not None and later.warm_start.matched_from == 3


def test_a_goal_set_with_torn_missing_repeated_or_misplaced_parts_is_dropped():
    drops = DropCounter()
    data = SAMPLES[6].encode()
    parts = _parts(data)
    assert decode(data[:-5] + data[-4:], drops=drops) is None  # a byte lost on the way: the checksum tells
    assert drops == {"checksum": 1}
    drops.clear()
    body = data[:-4]  # as sent, with its checksum made anew
    assert decode(_sealed(body[:-3]), drops=drops) is None  # the last part shorter than its header says
    assert decode(_sealed(body + b"\x05"), drops=drops) is None  # a torn part header
    short = [(k, v, b[:-1]) if k == Correspondence.PART else (k, v, b) for k, v, b in parts]
    assert decode(_join(short), drops=drops) is None  # a part that is not the length its goal count needs
    torn = [(k, v, b[:-1]) if k == Lives.PART else (k, v, b) for k, v, b in parts]
    assert decode(_join(torn), drops=drops) is None  # a life cut short
    assert drops == {"truncated": 4}
    assert decode(_join([p for p in parts if p[0] != Timing.PART]), drops=drops) is None  # no timing
    assert decode(_join(parts[1:2] + parts[:1] + parts[2:]), drops=drops) is None  # the goal set not first
    assert decode(_join(parts + parts[-1:]), drops=drops) is None  # a part twice
    assert decode(_join(parts + parts[:1]), drops=drops) is None  # the goal set twice
    assert decode(_join([]), drops=drops) is None  # no part at all
    three = [(k, v, b + b[:4]) if k == Lives.PART else (k, v, b) for k, v, b in parts]
    assert decode(_join(three), drops=drops) is None  # three lives for two robots
    assert drops["invalid"] == 6


def test_goal_set_parts_refuse_bad_values():
    still, moving, keyframe = SAMPLES[4:7]
    drops = DropCounter()
    for bad in (Timing(1.0, frame_period=-1.0), Timing(math.nan)):
        assert decode(dataclasses.replace(still, timing=bad).encode(), drops=drops) is None
    for bad in (dict(geometric=2), dict(geometric=1, k_eg=-1.0), dict(omega_g=math.inf)):
        assert (
            decode(dataclasses.replace(moving, motion=dataclasses.replace(moving.motion, **bad)).encode(), drops=drops)
            is None
        ), bad
    for correspondence in (Correspondence(3, np.array([0, 2])), Correspondence(0, np.array([0, 1]))):
        assert decode(dataclasses.replace(keyframe, correspondence=correspondence).encode(), drops=drops) is None
    for warm in (
        WarmStart(3, np.array([0, 2]), np.zeros(2)),
        WarmStart(3, np.array([0, 1]), np.array([0.0, math.nan])),
    ):
        assert decode(dataclasses.replace(keyframe, warm_start=warm).encode(), drops=drops) is None
    assert drops == {"invalid": 6, "non-finite": 3}
    with pytest.raises(ValueError):  # an encoder never sends a part that does not fit its goal set
        dataclasses.replace(keyframe, correspondence=Correspondence(3, np.array([0]))).encode()
    with pytest.raises(ValueError):
        dataclasses.replace(keyframe, lives=Lives(np.array([1]))).encode()


def test_a_life_is_an_incarnation_as_a_number_and_anything_else_is_any_life():
    assert life_number("0a1b2c3d") == 0x0A1B2C3D and life_number("ffffffff") == 2**32 - 1
    assert [life_number(x) for x in ("first", "", "0a1b2c3", "-a1b2c3d", "0A1B2C3D", " a1b2c3d")] == [0] * 6


def test_retired_single_robot_kinds_are_dropped_as_unknown():
    """Kinds 1, 2 and 3 (one robot's pose, state, command of earlier versions) are gone: a robot
    alone sends a frame of one."""
    drops = DropCounter()
    for kind in (1, 2, 3):
        assert decode(bytes([kind, VERSION]) + bytes(28), drops=drops) is None
    assert drops == {"kind": 3}


def test_a_frame_of_one_is_a_frame_and_as_compact_as_one_robots_message_was():
    pose = Pose(3, 7, 0.7, 1.5, -2.0, 0.25)
    data = Poses.one(pose).encode()
    assert data[:2] == bytes([Poses.KIND, VERSION]) and struct.unpack_from("<Id", data, 2) == (7, 0.7)
    assert struct.unpack_from("<Ifff", data, 14) == (3, 1.5, -2.0, 0.25) and len(data) == 30
    assert decode(data).messages() == [pose]
    assert decode(Poses.of(7, 0.7, []).encode()).count == 0  # a tracker that sees nobody
    drops = DropCounter()
    assert decode(data + bytes(5), drops=drops) is None  # not a whole number of records
    assert decode(data[:13], drops=drops) is None  # not even the fixed part
    assert drops == {"truncated": 2}


def test_the_auction_record_is_one_layout_in_bids_boards_and_the_bidder():
    """One robot's word on one goal at a price reads the same in a Bid, in a Boards word's board
    and in the bidder's records: the same fields and the same flags."""
    assert Boards.RECORD == AuctionRecord.DTYPE
    assert Bid.RECORD.descr[: len(AuctionRecord.FIELDS)] == AuctionRecord.DTYPE.descr
    assert bidder_record is Bid.RECORD
    words = np.zeros(1, Boards.WORD)
    words["robot"], words["flags"], words["records"] = 7, Boards.FRESH, 2
    said = np.array([(7, 3, 0.5, 0), (9, 4, 0.25, AuctionRecord.RELEASED)], AuctionRecord.DTYPE)
    boards = decode(Boards(2, 1, 7, 5, 6, 10, 1, words, np.zeros((0, 2), np.uint8), said).encode())
    bid = np.zeros(2, Bid.RECORD)
    for name, _ in AuctionRecord.FIELDS:
        bid[name] = said[name]
    bid = decode(Bid(2, 1, 7, 5, 99, 2, bid).encode())
    for name, _ in AuctionRecord.FIELDS:
        np.testing.assert_array_equal(boards.records[name], said[name])
        np.testing.assert_array_equal(bid.records[name], said[name])
    assert (bid.records["flags"] & AuctionRecord.RELEASED).tolist() == [0, AuctionRecord.RELEASED]


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
    bad_plans = ["state", "state:drop=2", "state:loss=0.1", "state:drop=x", "pose:delay=inf", "state:delay=nan"]
    # an entry repeated would silently replace the first (the 50 % loss lost)
    bad_plans += ["state:jitter=inf", "state:drop=0.5;state:delay=0.1", "state:drop=0.5,drop=0.1"]
    for bad in bad_plans:
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


def test_a_bus_that_does_not_hear_itself_still_reaches_the_others(router):
    """A robot alone (agent/__main__.py) keeps what it says: its states and claims reach every
    other session, never its own subscriptions; a bus that hears itself gets its own back."""

    def state(robot):
        return States.one(State(robot, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0))

    with Bus(client_of(router), "t", hears_itself=False) as alone, Bus(client_of(router), "t") as other:
        own, theirs = (bus.subscribe(bus.keys.all_of("state"), State) for bus in (alone, other))
        time.sleep(0.3)
        alone.publish(alone.keys.state((0, 0), 5), state(5))
        other.publish(other.keys.state((0, 0), 6), state(6))
        assert sorted(m.robot for _, m in _collect(theirs, 2)) == [5, 6]
        assert [m.robot for _, m in _collect(own, 1)] == [6]
        time.sleep(0.2)
        assert own.get(timeout=0.1) is None


def test_a_pulled_inbox_needs_no_thread_and_keeps_what_came_before_an_unsubscribe(router):
    """An agent's neighbour states: many cell subscriptions, read once a tick on the owner's
    thread. Zenoh-python gives a callback subscription a Python thread of its own; a pulled one
    has none, and a cell left after a state arrived still hands that state over."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        inbox = b.inbox(State, pulled=True)
        threads = threading.active_count()
        subs = [b.subscribe_into(b.keys.state_cell((cx, 0)), inbox) for cx in range(25)]
        assert threading.active_count() == threads
        time.sleep(0.3)
        for cx in range(25):
            a.publish(a.keys.state((cx, 0), cx), States.one(State(cx, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        time.sleep(0.3)
        b.unsubscribe(subs[3])
        got = _collect(inbox, 25)
        assert sorted(m.robot for _, m in got) == list(range(25))
        a.publish(a.keys.state((3, 0), 3), States.one(State(3, 2, 0.2, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        time.sleep(0.3)
        assert inbox.drain() == []  # nothing from the cell it left


def test_a_state_forged_from_the_future_does_not_stand_for_the_robots_next_ones(router):
    """A lock-step host waits on ``seen`` for a nearby robot's state of the tick before (even one
    its fault plan then drops); a copy of a state with its tick moved 5000 ahead, kept as the
    greatest, made every later wait for that robot run out."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        inbox = b.inbox(State, pulled=True)
        inbox.seen = {}
        b.subscribe_into(b.keys.state_cell((0, 0)), inbox)
        time.sleep(0.3)
        for tick in (5, 5005, 6):
            a.publish(a.keys.state((0, 0), 4), States.one(State(4, tick, 0.5, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
            time.sleep(0.2)
            inbox.take()
            assert inbox.seen == {4: tick}


def test_taking_from_a_pulled_inbox_gives_what_draining_gives_records_queued_first(router):
    """take() is drain() without the keys: records a wait already queued come first, then those
    still in zenoh's channels in the order each cell's robots spoke, malformed ones counted."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        inbox = b.inbox(State, pulled=True)
        for cx in range(3):
            b.subscribe_into(b.keys.state_cell((cx, 0)), inbox)
        time.sleep(0.3)

        def say(robot: int, tick: int) -> None:
            state = State(robot, tick, 0.1 * tick, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)
            a.publish(a.keys.state((robot % 3, 0), robot), States.one(state))

        say(0, 1)
        say(1, 1)
        time.sleep(0.3)
        got = inbox.get(timeout=1.0)  # a wait pulls every channel into the queue and hands one over
        assert got is not None
        say(2, 1)  # into its channel, behind the one still queued
        time.sleep(0.3)
        queued, rest = [(s.robot, s.tick) for s in inbox.take()]
        assert sorted([(got[1].robot, 1), queued]) == [(0, 1), (1, 1)] and rest == (2, 1)
        for tick in (2, 3):
            for robot in range(6):
                say(robot, tick)
        a.put(a.keys.state((0, 0), 9), bytes([States.KIND, VERSION]) + b"garbage")
        time.sleep(0.3)
        b.subscribe_into(b.keys.state_cell((9, 0)), inbox)  # an empty channel changes nothing
        taken = inbox.take()
        assert sorted((s.robot, s.tick) for s in taken) == [(r, t) for r in range(6) for t in (2, 3)]
        for robot in range(6):  # each robot's states in the order it sent them
            assert [s.tick for s in taken if s.robot == robot] == [2, 3]
        assert inbox.drops["checksum"] == 1 and inbox.take() == [] and inbox.drain() == []


def test_a_process_lingers_before_it_closes_only_for_what_it_just_put(router, monkeypatch):
    """zenoh has no flush: a process's last report leaves on zenoh's thread, so a bus about to
    close waits CLOSE_LINGER after its last put, and not at all when it put nothing."""
    slept: list[float] = []
    monkeypatch.setattr(bus_module.time, "sleep", slept.append)
    with Bus(client_of(router), "t") as bus:
        bus.linger()
        bus.publish(bus.keys.event, Event({"kind": "stats"}))
        bus.linger()
    assert slept[0] == 0.0
    assert 0.0 < slept[1] <= CLOSE_LINGER


def test_fault_injection_drop_and_delay(router):
    faults = {"state": FaultSpec(drop=0.3, delay=0.2)}
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t", faults=faults, seed=3) as b:
        lossy = b.subscribe(b.keys.all_of("state"), State)
        time.sleep(0.3)
        for i in range(200):
            a.publish(a.keys.state((0, 0), i), States.one(State(i, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        assert lossy.get(timeout=0.15) is None  # nothing before the added delay
        got = _collect(lossy, 200, timeout=2.0)
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
        events = [(role, ident, alive) for role, ident, alive, _, _ in watch.drain()]
        assert events == [("agent", "4", True), ("agent", "4", False)]


def test_a_hosts_one_token_is_each_of_its_robots_life_and_death(router):
    """An agent host declares one token naming its robots (robots_ident): watchers hear each robot
    come alive and die, as from a token per robot."""
    with Bus(client_of(router), "t") as watcher:
        watch = watcher.watch_alive("agent")
        host = Bus(client_of(router), "t")
        host.declare_alive("agent", robots_ident([7, 3, 4, 5, 9]))
        time.sleep(0.3)
        host.close()
        time.sleep(0.3)
        events = [(ident, alive) for _, ident, alive, _, _ in watch.drain()]
        robots = ["3", "4", "5", "7", "9"]
        assert events == [(r, True) for r in robots] + [(r, False) for r in robots]


@pytest.mark.parametrize(
    "robots, ident",
    [([4], "4"), ([0, 1, 2], "0-2"), ([9, 3, 5, 4, 7], "3-5_7_9"), (list(range(1000, 2000)), "1000-1999")],
)
def test_robots_ident_names_a_hosts_robots_as_runs(robots, ident):
    assert robots_ident(robots) == ident
    assert robots_of_ident(ident) == sorted(robots)


@pytest.mark.parametrize(
    "ident", ["", "a", "3-", "5-3", "1_x", "-4", "2--3", "0-4294967295", "65536", "_".join(["0-65535"] * 2)]
)
def test_an_ident_that_names_no_robots_is_none(ident):
    assert robots_of_ident(ident) is None


def test_a_restarted_agent_heard_before_its_old_token_ends_is_a_death_then_a_life(router):
    """The old process's token may end after the new one's is heard: every watcher still sees the
    robot die, then live, and the old token's late end is no death."""
    with Bus(client_of(router), "t") as watcher:
        watch = watcher.watch_alive("agent")
        old, new = Bus(client_of(router), "t"), Bus(client_of(router), "t")
        old.declare_alive("agent", 4)
        assert wait_for(lambda: watch._live, timeout=5)
        new.declare_alive("agent", 4)
        assert wait_for(lambda: watch._live.get(("agent", "4"), [None])[-1] == new.incarnation, timeout=5)
        old.close()
        time.sleep(0.3)
        events = [(alive, life) for _, _, alive, _, life in watch.drain()]
        new.close()
        assert events == [(True, old.incarnation), (False, old.incarnation), (True, new.incarnation)]


def test_a_forged_life_that_comes_and_goes_leaves_the_agent_that_still_stands_alive(router):
    """A peer declared robot 4's token under another life for a moment: the agent's own life counted as dead (a
    restart), and once the forged token went robot 4 was dead for good though its agent lived on (every robot of
    a run froze for the rest of it under a forged host token). The life whose token still stands lives again."""
    with Bus(client_of(router), "t") as watcher, Bus(client_of(router), "t") as real:
        watch = watcher.watch_alive("agent")
        real.declare_alive("agent", 4)
        assert wait_for(lambda: watch._live, timeout=5)
        with Bus(client_of(router), "t") as forged:
            forged.declare_alive("agent", "3-5")
            assert wait_for(lambda: watch._live.get(("agent", "4"), [None])[-1] == forged.incarnation, timeout=5)
        assert wait_for(lambda: watch._live.get(("agent", "4"), [None])[-1] == real.incarnation, timeout=5)
        time.sleep(0.3)
        events = [(ident, alive, life) for _, ident, alive, _, life in watch.drain()]
    lives = {real.incarnation: "real", forged.incarnation: "forged"}
    assert [(i, a, lives[life]) for i, a, life in events if i == "4"] == [
        ("4", True, "real"), ("4", False, "real"), ("4", True, "forged"), ("4", False, "forged"), ("4", True, "real")
    ]  # fmt: skip
    assert [(i, a) for i, a, _ in events if i != "4"] == [("3", True), ("5", True), ("3", False), ("5", False)]


def test_occupied_port_is_a_clear_error(router):
    with pytest.raises(TransportError, match="in use"):
        open_session(router)


def test_resent_hellos_get_through_a_lossy_lock_step_inbox(router):
    """Hellos (tick BEFORE_START) come before the lock-step tick clock runs: a delay holds them on the
    wall clock and each resend takes its own draw, so with 50 % loss one of a few resends gets
    through (on the tick clock every resend was dropped alike, or held for a tick that waited for
    it: the run started only at the hello timeout)."""
    faults = {"state": FaultSpec(drop=0.5, delay=0.05)}
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t", faults=faults, seed=1) as b:
        inbox = b.subscribe(b.keys.all_of("state"), State)
        inbox.sim_time = 0.0  # a lock-step owner before its first tick
        time.sleep(0.3)
        for _ in range(12):  # an agent resends its hello until it hears the others
            a.publish(a.keys.state((0, 0), 4), States.one(State(4, BEFORE_START, 0.0, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        got = _collect(inbox, 1, timeout=2.0)
        assert got and got[0][1].tick == BEFORE_START
        assert 0 < inbox.drops["fault"] < 12


def test_a_frame_on_a_key_naming_one_robot_holds_that_robots_record_alone(router):
    """A damaged robot id would make one robot's pose or state another's: refused as misaddressed,
    by the callback inbox and the pulled one alike."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        poses = b.inbox(Pose)
        b.subscribe_into(b.keys.pose(3), poses)
        states = b.inbox(State, pulled=True)
        b.subscribe_into(b.keys.state_cell((0, 0)), states)
        time.sleep(0.3)
        a.publish(a.keys.pose(3), Poses.one(Pose(5, 1, 0.1, 0.2, 0.0, 0.0)))  # robot 5's pose under robot 3's key
        a.publish_poses(1, 0.1, np.array([3, 5]), np.zeros((2, 3)), frame=False)  # each under its own key
        a.publish(a.keys.state((0, 0), 4), States.one(State(6, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        a.publish(a.keys.state((0, 0), 4), States.one(State(4, 1, 0.1, 0, 0, 0, 0, 0.045, 0, 0, -1, 0)))
        time.sleep(0.3)
        assert [(p.robot, p.x) for _, p in poses.drain()] == [(3, 0.0)]
        assert [s.robot for s in states.take()] == [4]
        assert poses.drops["misaddressed"] == 1 and states.drops["misaddressed"] == 1


def test_a_robot_alone_hears_the_bodies_near_it_after_its_pose_in_one_frame(router):
    """The tracker's frame on pose/<id> holds the robot's pose first, then the bodies near it: its agent
    sees those (Inbox.bodies) and its pose inbox yields its own pose alone, and one subscription to
    every pose (the coordinator's) takes a robot's record from its own key only."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        seen: list[tuple[int, list[int]]] = []
        poses = b.subscribe(b.keys.pose(3), Pose, only=np.array([3]))
        poses.bodies = lambda tick, records: seen.append((tick, records["robot"].tolist()))
        every = b.subscribe(b.keys.all_of("pose"), Pose, only=np.array([5]))
        time.sleep(0.3)
        near = [np.array([1, 2]), np.array([0]), np.array([], np.int64)]
        a.publish_poses(1, 0.1, np.array([3, 5, 6]), np.arange(9.0).reshape(3, 3), frame=False, near=near)
        time.sleep(0.3)
        assert [(p.robot, p.x) for _, p in poses.drain()] == [(3, 0.0)]
        assert seen == [(1, [5, 6])]
        assert [(p.robot, p.x) for _, p in every.drain()] == [(5, 3.0)]


def test_one_subscription_to_every_pose_keeps_the_robots_it_names_from_frames_and_single_keys(router):
    """What the coordinator hears of dead robots' bodies: their records of the tracker's frames and
    of single robots' keys, through one subscription, widened when another robot dies."""
    with Bus(client_of(router), "t") as a, Bus(client_of(router), "t") as b:
        bodies = b.subscribe(b.keys.all_of("pose"), Pose, only=np.array([5]))
        time.sleep(0.3)
        a.publish_poses(1, 0.1, np.arange(8), np.arange(24.0).reshape(8, 3), frame=True)
        a.publish_poses(1, 0.1, np.array([5, 6]), np.ones((2, 3)), frame=False)
        time.sleep(0.3)
        assert [(p.robot, p.x) for _, p in bodies.drain()] == [(5, 15.0), (5, 1.0)]
        bodies.keep = KeepRobots([5, 2])
        a.publish_poses(2, 0.2, np.arange(8), np.zeros((8, 3)), frame=True)
        time.sleep(0.3)
        assert sorted(p.robot for _, p in bodies.drain()) == [2, 5]


def test_the_coordinator_hears_where_a_dead_robots_body_stays_in_the_trackers_frames(router):
    """Agent hosts hear the tracker as frames of every robot: a dead robot's body is in them, and the
    coordinator learns where it stays, to keep the goals clear of it (paper 5.1.2), instead of
    waiting for a pose on the robot's own key that never comes."""
    from coordinator.scene import scene_from_dict
    from coordinator.service import Coordinator

    scene = scene_from_dict(
        {"robots": 4, "seed": 5, "layout": {"kind": "grid", "spacing": 0.2}, "steps": [{"shape": "disk", "hold": 30}]}
    )
    with Bus(client_of(router), "t") as world, Bus(client_of(router), "t") as hosts, Bus(client_of(router), "t") as c:
        coordinator = Coordinator(c, scene)

        def live() -> set[int]:
            coordinator._hear()
            return coordinator.roster.live

        hosts.declare_alive("agent", "0-2")
        last = hosts.declare_alive("agent", "3")
        assert wait_for(lambda: live() == {0, 1, 2, 3}, timeout=5.0)
        last.undeclare()
        assert wait_for(lambda: live() == {0, 1, 2}, timeout=5.0)
        poses = np.arange(12.0).reshape(4, 3)

        def heard() -> bool:
            world.publish_poses(8, 0.8, np.arange(4), poses, frame=True)
            coordinator._hear()
            return 3 in coordinator.bodies.positions

        assert wait_for(heard, timeout=5.0)
        assert list(coordinator.bodies.positions) == [3] and coordinator.bodies.positions[3].tolist() == [9.0, 10.0]


@pytest.mark.slow
def test_a_client_whose_link_to_its_router_came_back_declares_its_subscriptions_again(spawned):
    """On a starved machine (100 one-robot agents starting on 2 cores) links dropped and came back,
    and a few agents' subscriptions made before went deaf: they never heard a pose again. A client
    declares every subscription again a while after its link comes back. Here the router is frozen
    past its lease (the link drops and returns) and the subscriptions are made deaf under the bus."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen(pixelswarm_cmd("router", "-l", endpoint), cwd=REPO, stdout=subprocess.PIPE, text=True)
    spawned.append(router)
    assert router.stdout is not None
    with router.stdout:
        assert "listening" in router.stdout.readline()
    client = ZenohSettings(mode="client", connect=[endpoint])
    with Bus(client, "t") as a, Bus(client, "t") as b:
        inbox = b.subscribe(b.keys.pose(1), Pose)

        def heard(tick: int) -> bool:
            a.publish(a.keys.pose(1), Poses.one(Pose(1, tick, 0.1 * tick, 0.0, 0.0, 0.0)))
            b.renew_if_due()
            return any(m.tick == tick for _, m in _collect(inbox, 1, timeout=0.2))

        assert wait_for(lambda: heard(1), timeout=5.0)
        assert not b.renew_if_due() and b.renewals == 0  # the link never went: nothing to renew
        deafen(b)
        router.send_signal(signal.SIGSTOP)
        time.sleep(1.5 * b.settings.lease_ms / 1000)
        router.send_signal(signal.SIGCONT)
        assert wait_for(lambda: heard(2), timeout=20.0), "the subscription was not declared again"
        assert b.renewals == 1


@pytest.mark.parametrize(
    "plan, said",
    [
        ("state:drop", "drop needs a value, e.g. state:drop=0.1"),  # the value left out
        ("cmd:delay", "delay needs a value, e.g. cmd:delay=0.1"),
        ("state:loss=0.2", "no setting 'loss' (did you mean 'drop'? "),  # what a study calls it
        ("state:dorp=0.2", "no setting 'dorp' (did you mean 'drop'? "),
        ("state:speed=1", "no setting 'speed' (settings: "),
    ],
)
def test_a_fault_setting_it_cannot_read_is_said_with_the_settings_there_are_and_the_plans_shape(plan, said):
    with pytest.raises(ValueError) as refused:
        parse_faults(plan)
    message = str(refused.value)
    assert message.startswith(f"fault {plan!r}: {said}"), message
    assert "KIND:drop=P,delay=S,jitter=S" in message and "unknown setting" not in message
    if "no setting" in message:
        assert "settings: drop, delay, jitter" in message


@pytest.mark.parametrize("problem, said", [("missing", "no such file or directory"), ("folder", "is a directory")])
def test_a_zenoh_config_file_it_cannot_read_is_named_not_taken_for_a_busy_port(tmp_path, problem, said):
    path = tmp_path / "router.json5"
    if problem == "folder":
        path.mkdir()
    with pytest.raises(TransportError) as refused:
        open_session(ZenohSettings(mode="router", config_file=str(path)))
    assert str(refused.value) == f"--zenoh-config {path}: {said}"


def test_a_zenoh_config_file_that_is_not_a_configuration_says_what_zenoh_found(tmp_path):
    for text, found in [("{ mode: ", "expected array"), ("{ banana: 1 }", "unknown field `banana`")]:
        path = tmp_path / "router.json5"
        path.write_text(text)
        with pytest.raises(TransportError, match=f"^--zenoh-config {path}: not a zenoh JSON5 configuration: {found}"):
            open_session(ZenohSettings(mode="router", config_file=str(path)))
