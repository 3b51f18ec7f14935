"""Versioned, compact binary codecs for every message kind, with validating decoders.

Every message starts with a (kind, version) header; poses, states and commands travel as frames, a goal set
as parts with their own headers. ``decode`` never raises: anything malformed is None, counted in a
``DropCounter``, so no peer can break a control loop. Kinds every host must hold to the bit end in a CRC-32;
poses (judged by agent.pose_trust), commands (checked against their tick) and clock ticks (bounded by
the poses' ticks, agent.clocks) do not. See docs/protocol.md.
"""

from __future__ import annotations

import functools
import json
import math
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from operator import attrgetter
from typing import Any, ClassVar, Protocol, TypeVar, overload

import numpy as np

VERSION = 6  # of the message header and every kind's layout; a goal set's parts have their own
_HEADER = struct.Struct("<BB")
_CHECKSUM = struct.Struct("<I")  # CRC-32 (zlib's) of a CHECKED kind's bytes before it
CHECKSUM_SIZE = _CHECKSUM.size


def with_checksum(data: bytes) -> bytes:
    """A CHECKED kind's bytes with their checksum after them."""
    return data + _CHECKSUM.pack(zlib.crc32(data))


# CRC-32 of any bytes followed by their own CRC-32 (little-endian): the same constant whatever the
# bytes, and for given bytes no other four bytes after them give it (the tail's CRC is one-to-one).
_RESIDUE = 0x2144DF1C


def intact(data: bytes | memoryview) -> bool:
    """Whether a CHECKED kind's bytes end in the checksum of the rest (one pass, no copy)."""
    return len(data) >= _CHECKSUM.size and zlib.crc32(data) == _RESIDUE


def as_sent(values: Any) -> np.ndarray:
    """Values as a receiver decodes them (float32 on the wire): an in-process link rounds through this."""
    return np.asarray(values, np.float32).astype(np.float64)


class DropCounter(Counter):
    """Counts dropped messages by reason ('truncated', 'version', 'kind', 'checksum', 'non-finite', 'invalid')."""


class Malformed(ValueError):
    """Raised inside decoders; turned into a counted drop by ``decode``."""


def _finite(*values: Any) -> None:
    """Numbers or arrays of them: all finite, or the message is dropped as non-finite."""
    if not all(np.isfinite(v).all() for v in values):
        raise Malformed("non-finite")


def _leading(layout: struct.Struct, body: memoryview, exact: bool = False) -> tuple:
    """The fields of ``layout`` at the start of ``body`` (``exact``: the whole of it), or truncated."""
    if len(body) < layout.size or (exact and len(body) != layout.size):
        raise Malformed("truncated")
    return layout.unpack_from(body)


_FEW = 8  # records a message checks in Python rather than numpy, whose reductions cost more for a few
_FEW_ROWS = 16  # a frame's records checked in one struct call rather than numpy (a robot's bodies near it)
_ONE_RECORD_AT = 2  # in the body of a frame of one: tick, stamp, then the record


@functools.cache  # per layout and count up to _FEW_ROWS
def _rows_struct(row: str, count: int) -> struct.Struct:
    """``count`` records of the packed layout ``row`` (struct's characters, no byte order) as one struct."""
    return struct.Struct("<" + row * count)


def _row_struct(item: np.dtype) -> struct.Struct:
    """A packed record dtype as one struct (numpy's type characters are struct's)."""
    fields: Mapping[str, tuple] = item.fields or {}
    row = struct.Struct("<" + "".join(fields[k][0].char for k in item.names or ()))
    assert row.size == item.itemsize, f"{item}: a record must be packed of standard-size fields"
    return row


@dataclass
class Message:
    """Base of all messages: a fixed part packed with ``_fixed`` and an optional variable tail."""

    KIND: ClassVar[int] = 0
    NAME: ClassVar[str] = ""
    CHECKED: ClassVar[bool] = False  # ends in a checksum (with_checksum)
    _fixed: ClassVar[struct.Struct]

    @classmethod
    @functools.cache  # once per class: every decode validates the fields, and Tick goes out every tick
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def encode(self) -> bytes:
        data = _HEADER.pack(self.KIND, VERSION) + self._fixed.pack(*self._fixed_values()) + self._tail()
        return with_checksum(data) if self.CHECKED else data

    @classmethod
    @functools.cache
    def _fixed_names(cls) -> tuple[str, ...]:
        """The fields the fixed part packs: the first ones, one per field of ``_fixed``."""
        return cls.field_names()[: len(cls._fixed.unpack(bytes(cls._fixed.size)))]

    _counts: ClassVar[str] = ""  # a table whose length the fixed part's last field (``count``) packs

    def _fixed_values(self) -> tuple:
        values = tuple(getattr(self, name) for name in self._fixed_names())
        return (*values[:-1], len(getattr(self, self._counts))) if self._counts else values

    def _tail(self) -> bytes:
        return b""

    @classmethod
    def _from(cls, body: memoryview) -> Message:
        msg = cls(*_leading(cls._fixed, body, exact=True))
        if not all(math.isfinite(v) for v in msg._fixed_values() if isinstance(v, float)):
            raise Malformed("non-finite")
        return msg

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly view (for logs): a record array as columns (one array per field), others and parts as lists."""
        out = {}
        for name in self.field_names():
            v = getattr(self, name)
            if isinstance(v, np.ndarray):
                v = {k: v[k] for k in v.dtype.names} if v.dtype.names else v.tolist()
            elif is_dataclass(v):  # a goal set's part
                v = {f.name: np.asarray(getattr(v, f.name)).tolist() for f in fields(v)}
            out[name] = v
        return out


MAX_ROBOTS = 2**16  # robot ids travel as u16 in goal sets and auction words: a display has at most this many
BEFORE_START = 0xFFFFFFFF  # tick of a frame sent before the robots' agents are live (poses, hellos)
START_TICK = -1  # a hello as a neighbour's state: where it stands before tick 0 (never on the wire)


@dataclass
class Pose:
    """A record of a ``Poses`` frame: the tracked pose of one robot at a tick (paper: central tracking, 10 Hz)."""

    NAME: ClassVar[str] = "pose"
    robot: int
    tick: int
    stamp: float
    x: float
    y: float
    theta: float


@dataclass
class State:
    """A record of a ``States`` frame: what neighbours need for ORCA and the auction. (vx, vy) is v_opt of
    eq. 11, ``radius`` what others avoid; ``goal_index`` (-1: none) is from the agreed assignment of auction
    ``assign_instance`` of goal set ``assign_epoch``, or (CARRIED) carried over from the last keyframe."""

    NAME: ClassVar[str] = "state"
    CARRIED: ClassVar[int] = 0xFFFFFFFF  # assign_instance of a carried goal: not an agreed instance
    robot: int
    tick: int
    stamp: float
    x: float
    y: float
    vx: float
    vy: float
    radius: float
    goal_x: float
    goal_y: float
    goal_index: int
    flags: int  # bit 0: has a goal; bit 1: at its goal; bit 2: a dynamic obstacle (does not avoid others)
    assign_epoch: int = 0  # the goal set (epoch) and auction instance whose agreed assignment gave
    assign_instance: int = 0  # goal_index (0, 0 for goals that were not auctioned)

    HAS_GOAL: ClassVar[int] = 1
    AT_GOAL: ClassVar[int] = 2
    DYNAMIC: ClassVar[int] = 4


@dataclass
class Command:
    """A record of a ``Commands`` frame: holonomic velocity (mode 0) or linear wheel speeds (mode 1), and LED colour."""

    NAME: ClassVar[str] = "cmd"
    robot: int
    tick: int
    stamp: float
    mode: int
    a: float
    b: float
    r: int
    g: int
    bl: int

    HOLONOMIC: ClassVar[int] = 0
    WHEELS: ClassVar[int] = 1


@dataclass
class Tick(Message):
    """Clock: tick k starts at ``stamp`` s of display time, ``dt`` the control period. ``goal_epoch``: the
    newest goal set the world had heard; in lock-step every agent takes it up at this tick, all at once."""

    KIND: ClassVar[int] = 4
    NAME: ClassVar[str] = "clock"
    _fixed: ClassVar[struct.Struct] = struct.Struct("<IdfI")
    tick: int
    stamp: float
    dt: float
    goal_epoch: int = 0


_PART = struct.Struct("<BBI")  # a goal set's part header: part kind, part version, body length
_EPOCH = struct.Struct("<I")  # the goal set a part refers to


@dataclass
class _FixedPart:
    """A goal set's part of one fixed layout: its fields in order, then ``_check`` of what they hold."""

    _layout: ClassVar[struct.Struct]

    def pack(self, count: int) -> bytes:
        return self._layout.pack(*(getattr(self, f.name) for f in fields(self)))

    @classmethod
    def unpack(cls, body: memoryview, count: int) -> Any:
        part = cls(*_leading(cls._layout, body, exact=True))
        part._check()
        return part

    def _check(self) -> None:
        raise NotImplementedError


@dataclass
class Timing(_FixedPart):
    """Part 2 of a goal set: when published (``stamp``, display time, past the set before's:
    coordinator.service.Coordinator._stamp), the scene step shown, for how long (``hold``, s), the display
    time it began (t = 0 of eq. 28) and an animation keyframe's K_f dt (eq. 27; 0: none)."""

    PART: ClassVar[int] = 2
    VERSION: ClassVar[int] = 1
    _layout: ClassVar[struct.Struct] = struct.Struct("<dHfdf")
    stamp: float = 0.0
    step: int = 0
    hold: float = 0.0
    t_start: float = 0.0
    frame_period: float = 0.0

    def _check(self) -> None:
        _finite(self.stamp, self.hold, self.t_start, self.frame_period)
        if self.frame_period < 0:
            raise Malformed("invalid")


@dataclass
class Motion(_FixedPart):
    """Part 3 of a goal set: its motion as a dynamic image (paper 7.4.1, eq. 28, t = display time - t_start):
    v_G, omega_G, p_OG, K_eG, and whether the scaling is geometric. Absent: the goal set stands still."""

    PART: ClassVar[int] = 3
    VERSION: ClassVar[int] = 1
    _layout: ClassVar[struct.Struct] = struct.Struct("<ffffffB")
    v_gx: float = 0.0  # v_G (m/s)
    v_gy: float = 0.0
    omega_g: float = 0.0  # omega_G (rad/s)
    p_ogx: float = 0.0  # p_OG (m)
    p_ogy: float = 0.0
    k_eg: float = 0.0  # K_eG (1/s)
    geometric: int = 0  # 1: s(t) = (1 + K_eG)^t, 0: s(t) = 1 + K_eG t

    @property
    def moves(self) -> bool:
        """It translates, rotates or scales."""
        return any((self.v_gx, self.v_gy, self.omega_g, self.k_eg))

    def _check(self) -> None:
        _finite(self.v_gx, self.v_gy, self.omega_g, self.p_ogx, self.p_ogy, self.k_eg)
        if self.geometric not in (0, 1) or (self.geometric and self.k_eg <= -1):
            raise Malformed("invalid")


@dataclass
class Correspondence:
    """Part 4 of a goal set: per goal, its corresponding goal (-1: none) in goal set ``follows``, the
    previous keyframe of an animation (paper 6.1; coordinator.keyframes.goal_correspondence)."""

    PART: ClassVar[int] = 4
    VERSION: ClassVar[int] = 1
    follows: int
    previous: np.ndarray

    def pack(self, count: int) -> bytes:
        if len(self.previous) != count:
            raise ValueError("previous needs one index per goal")
        return _EPOCH.pack(self.follows) + np.asarray(self.previous, "<i4").tobytes()

    @classmethod
    def unpack(cls, body: memoryview, count: int) -> Correspondence:
        if len(body) != _EPOCH.size + 4 * count:
            raise Malformed("truncated")
        (follows,) = _EPOCH.unpack(body[: _EPOCH.size])
        previous = np.frombuffer(body[_EPOCH.size :], "<i4").astype(np.int64)
        if follows == 0 or (previous < -1).any() or (previous >= count).any():
            raise Malformed("invalid")
        return cls(follows, previous)


@dataclass
class WarmStart:
    """Part 5 of a goal set: where its auction starts: per goal, the goal of set ``matched_from`` matched to
    it and prices in equilibrium for it (coordinator.warm_start.goal_matching); ``matched_from`` 0: matched
    to the robots' start (per goal, its robot's index in the set's robots). Absent: a cold start."""

    PART: ClassVar[int] = 5
    VERSION: ClassVar[int] = 1
    matched_from: int
    matched: np.ndarray
    prices: np.ndarray

    def pack(self, count: int) -> bytes:
        if len(self.matched) != count or len(self.prices) != count:
            raise ValueError("matched and prices need one entry per goal")
        matched, prices = np.asarray(self.matched, "<i4"), np.asarray(self.prices, "<f8")
        return _EPOCH.pack(self.matched_from) + matched.tobytes() + prices.tobytes()

    @classmethod
    def unpack(cls, body: memoryview, count: int) -> WarmStart:
        if len(body) != _EPOCH.size + 12 * count:
            raise Malformed("truncated")
        (matched_from,) = _EPOCH.unpack(body[: _EPOCH.size])
        at = _EPOCH.size + 4 * count
        matched = np.frombuffer(body[_EPOCH.size : at], "<i4").astype(np.int64)
        prices = np.frombuffer(body[at:], "<f8").copy()
        _finite(prices)
        if (matched < 0).any() or (matched >= count).any():
            raise Malformed("invalid")
        return cls(matched_from, matched, prices)


@dataclass
class Lives:
    """Part 6 of a goal set: per robot of its ``robots``, the life of its agent (Bus.incarnation as a number,
    ``life_number``) that the coordinator heard when it published the set. A robot takes part in the set's
    auction in that life only: an agent started again waits for the next set, and the others do not wait for
    it (agent.runtime.Departures). 0: any life. Absent: a host takes part in a set published after it joined,
    and waits for every robot that did not die during the set."""

    PART: ClassVar[int] = 6
    VERSION: ClassVar[int] = 1
    life: np.ndarray  # per robot of the set's robots

    def pack(self, count: int) -> bytes:
        return np.asarray(self.life, "<u4").tobytes()

    @classmethod
    def unpack(cls, body: memoryview, count: int) -> Lives:
        if len(body) % 4:
            raise Malformed("truncated")
        return cls(np.frombuffer(body, "<u4").astype(np.int64))


def life_number(incarnation: str) -> int:
    """An incarnation (Bus.incarnation: 8 hex digits) as Lives carries it; 0 for anything else."""
    hex_digits = len(incarnation) == 8 and all(c in "0123456789abcdef" for c in incarnation)
    return int(incarnation, 16) if hex_digits else 0


@dataclass
class Goals(Message):
    """Coordinator -> all: a goal set with colours (part 1), then its parts, each of its own version:
    ``timing`` always, ``motion``, ``correspondence`` and ``warm_start`` when they apply. ``per_robot``:
    goals[i] is robot i's own goal; otherwise the robots in ``robots`` assign themselves by auction."""

    KIND: ClassVar[int] = 5
    NAME: ClassVar[str] = "goals"
    CHECKED: ClassVar[bool] = True
    PART: ClassVar[int] = 1  # the goal set itself
    PART_VERSION: ClassVar[int] = 1
    _fixed: ClassVar[struct.Struct] = struct.Struct("<")
    _set: ClassVar[struct.Struct] = struct.Struct("<IBI")  # epoch, per_robot, count; goals, then robots to the end
    RECORD: ClassVar[np.dtype] = np.dtype([("x", "<f4"), ("y", "<f4"), ("rgb", "u1", (3,))])
    epoch: int
    per_robot: int
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    robots: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    timing: Timing = field(default_factory=Timing)
    motion: Motion | None = None
    correspondence: Correspondence | None = None
    warm_start: WarmStart | None = None
    lives: Lives | None = None

    # the parts after the goal set: part kind -> (its class, its field)
    _PARTS: ClassVar[dict[int, tuple[Any, str]]] = {
        Timing.PART: (Timing, "timing"),
        Motion.PART: (Motion, "motion"),
        Correspondence.PART: (Correspondence, "correspondence"),
        WarmStart.PART: (WarmStart, "warm_start"),
        Lives.PART: (Lives, "lives"),
    }

    @property
    def count(self) -> int:
        return len(self.positions)

    def listed_lives(self) -> dict[int, int] | None:
        """Each robot's life as the set lists it (Lives), by robot; None when it lists none."""
        return None if self.lives is None else dict(zip(self.robots.tolist(), self.lives.life.tolist()))

    @property
    def moves(self) -> bool:
        """The goal set translates, rotates or scales (a dynamic image)."""
        return self.motion is not None and self.motion.moves

    def _tail(self) -> bytes:
        count = len(self.positions)
        items = np.empty(count, self.RECORD)
        items["x"], items["y"], items["rgb"] = self.positions[:, 0], self.positions[:, 1], self.colors
        goal_set = self._set.pack(self.epoch, self.per_robot, count) + items.tobytes()
        if self.lives is not None and len(self.lives.life) != len(self.robots):
            raise ValueError("lives needs one life per robot")
        parts = [(self.PART, self.PART_VERSION, goal_set + np.asarray(self.robots, "<u2").tobytes())]
        for part in (getattr(self, name) for _, name in self._PARTS.values()):
            if part is not None:
                parts.append((part.PART, part.VERSION, part.pack(count)))
        return b"".join(_PART.pack(kind, version, len(body)) + body for kind, version, body in parts)

    @classmethod
    def _from(cls, body: memoryview) -> Goals:
        parts = _split_parts(body)
        if not parts or parts[0][0] != cls.PART:
            raise Malformed("invalid")  # the goal set comes first: the other parts count its goals
        _, version, goal_set = parts[0]
        if version != cls.PART_VERSION:
            raise Malformed("version")
        epoch, per_robot, count = _leading(cls._set, goal_set)
        end = cls._set.size + count * cls.RECORD.itemsize
        if len(goal_set) < end or (len(goal_set) - end) % 2:
            raise Malformed("truncated")
        items = np.frombuffer(goal_set[cls._set.size : end], cls.RECORD)
        _finite(items["x"], items["y"])  # before the cast to float64: a signalling NaN warns in the cast
        positions = np.stack([items["x"], items["y"]], axis=1).astype(float)
        robots = np.frombuffer(goal_set[end:], "<u2").astype(np.int64)
        msg = cls(epoch, per_robot, positions, items["rgb"].copy(), robots)
        seen = {cls.PART}
        for kind, version, part_body in parts[1:]:
            if kind in seen:
                raise Malformed("invalid")  # a part twice (the goal set too)
            seen.add(kind)
            if kind not in cls._PARTS:
                continue  # a kind of part added later to the protocol: what we know of the set still holds
            part_type, name = cls._PARTS[kind]
            if version != part_type.VERSION:
                raise Malformed("version")
            setattr(msg, name, part_type.unpack(part_body, count))
        if Timing.PART not in seen:
            raise Malformed("invalid")  # every goal set says when it was published
        if msg.lives is not None and len(msg.lives.life) != len(robots):
            raise Malformed("invalid")  # a life per robot
        return msg


def _split_parts(body: memoryview) -> list[tuple[int, int, memoryview]]:
    """A message's parts as (part kind, part version, body); their lengths must fill it exactly."""
    out, at = [], 0
    while at < len(body):
        if len(body) - at < _PART.size:
            raise Malformed("truncated")
        kind, version, length = _PART.unpack(body[at : at + _PART.size])
        at += _PART.size
        if len(body) - at < length:
            raise Malformed("truncated")
        out.append((kind, version, body[at : at + length]))
        at += length
    return out


class AuctionRecord:
    """The auction record (paper 5.1.1): one robot's word on one goal at a price; one layout and set of
    flags for a ``Bid``, a ``Boards`` word (``robot``: the owner) and the bidder (agent.core.bidder)."""

    FIELDS: ClassVar[list[tuple[str, str]]] = [("robot", "<u2"), ("goal", "<i4"), ("price", "<f8"), ("flags", "u1")]
    DTYPE: ClassVar[np.dtype] = np.dtype(FIELDS)
    CONTENT: ClassVar[int] = 1  # the robot holds ``goal``, no other better by more than the phase's slack
    RELEASED: ClassVar[int] = 2  # the robot gave ``goal`` up at ``price`` (it bids elsewhere)
    SETTLED: ClassVar[int] = 4  # lock-step rounds: content at the final phase's slack (agent.core.bidder)


@dataclass
class Bid(Message):
    """Agent host -> all: its robots' word in the goal auction (paper 5.1.1), one record per robot
    and per goal it released, with the host's board digest (see agent.core.bidder)."""

    KIND: ClassVar[int] = 9
    NAME: ClassVar[str] = "auction"
    CHECKED: ClassVar[bool] = True
    _fixed: ClassVar[struct.Struct] = struct.Struct("<IIIIQI")
    # the auction record, and the robot's total deadlock penalty in force (m^2), so its agreed cost
    # can be checked, and the position it bid from
    RECORD: ClassVar[np.dtype] = np.dtype(AuctionRecord.FIELDS + [("penalty", "<f4"), ("x", "<f4"), ("y", "<f4")])
    _row: ClassVar[struct.Struct] = _row_struct(RECORD)  # a record as struct reads it
    _row_floats: ClassVar[tuple[int, ...]] = tuple(map((RECORD.names or ()).index, ("price", "penalty", "x", "y")))
    epoch: int
    instance: int
    sender: int
    serial: int  # the sender's message counter: a later message supersedes an earlier one
    digest: int  # hash of the sender's board (prices, owners, releases) when it wrote the records
    count: int
    records: np.ndarray = field(default_factory=lambda: np.zeros(0, Bid.RECORD))
    _counts: ClassVar[str] = "records"

    def _tail(self) -> bytes:
        return np.asarray(self.records, self.RECORD).tobytes()

    @classmethod
    def _from(cls, body: memoryview) -> Bid:
        """A bid usually holds a record or two: struct checks a few records' floats, cheaper than numpy."""
        epoch, instance, sender, serial, digest, count = _leading(cls._fixed, body)
        tail = body[cls._fixed.size :]
        if len(tail) != count * cls.RECORD.itemsize:
            raise Malformed("truncated")
        items = np.frombuffer(bytearray(tail), cls.RECORD)
        if count <= _FEW:
            finite = all(math.isfinite(row[i]) for row in cls._row.iter_unpack(tail) for i in cls._row_floats)
        else:
            finite = all(bool(np.isfinite(items[k]).all()) for k in ("price", "penalty", "x", "y"))
        if not finite:
            raise Malformed("non-finite")
        return cls(epoch, instance, sender, serial, digest, count, items)


@dataclass
class Boards(Message):
    """Agent host -> all: its robots' words in one round of the range-limited auction (agent.core.local_auction):
    per robot (``words``) its position, phase, end of block and newest round of change known; the robots it
    has heard of (``known``: bits, for words flagged GROWN) and its board's owned records (``records``, the
    owner as ``robot``; for words flagged FRESH). See docs/protocol.md."""

    KIND: ClassVar[int] = 13
    NAME: ClassVar[str] = "boards"
    CHECKED: ClassVar[bool] = True
    _fixed: ClassVar[struct.Struct] = struct.Struct("<IIIIIII")
    WORD: ClassVar[np.dtype] = np.dtype(
        [("robot", "<u2"), ("x", "<f4"), ("y", "<f4"), ("phase", "u1"), ("flags", "u1")]
        + [("last", "<u4"), ("records", "<u4")]
    )
    RECORD: ClassVar[np.dtype] = AuctionRecord.DTYPE
    ENDED: ClassVar[int] = 1  # the robot ended the block: its goal is agreed
    FRESH: ClassVar[int] = 2  # its board changed since its last word: its records follow
    GROWN: ClassVar[int] = 4  # the robots it has heard of grew since its last word: its bits follow
    epoch: int
    instance: int  # the block's final phase (agent.core.bidder numbers instances)
    sender: int
    serial: int  # the round
    goals: int  # G
    robots: int  # N: the bits of each known row
    count: int
    words: np.ndarray = field(default_factory=lambda: np.zeros(0, Boards.WORD))
    known: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))  # packed bits, a row per GROWN word
    records: np.ndarray = field(default_factory=lambda: np.zeros(0, Boards.RECORD))
    _counts: ClassVar[str] = "words"

    def _tail(self) -> bytes:
        row = (self.robots + 7) // 8
        known = np.asarray(self.known, np.uint8)
        known = known.reshape(-1, row) if row else known.reshape(0, 0)  # numpy infers no rows of width 0
        words, records = np.asarray(self.words, self.WORD), np.asarray(self.records, self.RECORD)
        return words.tobytes() + known.tobytes() + records.tobytes()

    @classmethod
    def _from(cls, body: memoryview) -> Boards:
        epoch, instance, sender, serial, goals, robots, count = _leading(cls._fixed, body)
        at = cls._fixed.size + count * cls.WORD.itemsize
        if len(body) < at:
            raise Malformed("truncated")
        words = np.frombuffer(body[cls._fixed.size : at], cls.WORD).copy()
        row = (robots + 7) // 8
        grown = int(np.count_nonzero(words["flags"] & cls.GROWN))
        fresh = (words["flags"] & cls.FRESH) != 0
        n_records = int(words["records"][fresh].sum())
        if len(body) != at + grown * row + n_records * cls.RECORD.itemsize or words["records"][~fresh].any():
            raise Malformed("truncated")
        known = np.frombuffer(body[at : at + grown * row], np.uint8).reshape(grown, row).copy()
        records = np.frombuffer(body[at + grown * row :], cls.RECORD).copy()
        _finite(words["x"], words["y"], records["price"])
        if (records["goal"] < 0).any() or (records["goal"] >= goals).any():
            raise Malformed("invalid")
        return cls(epoch, instance, sender, serial, goals, robots, count, words, known, records)

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in super().to_dict().items() if k != "known"}


@dataclass
class Frame(Message):
    """A tick's records of one or many robots: (tick, stamp), then one record per robot to the end. A host
    sends one frame of each kind a tick: a message per robot would cost each process as much as a frame."""

    _fixed: ClassVar[struct.Struct] = struct.Struct("<Id")
    VIEW: ClassVar[type]  # the record as a Python object (Pose, State, Command)
    RECORD: ClassVar[np.dtype]
    _floats: ClassVar[tuple[str, ...]]
    tick: int
    stamp: float
    records: np.ndarray

    @classmethod
    def of(cls, tick: int, stamp: float, views: list) -> Frame:
        """The frame of these robots' records (their tick and stamp are the frame's)."""
        return cls(tick, stamp, np.array([cls._record_of(v) for v in views], cls.RECORD).reshape(-1))

    @classmethod
    def one(cls, view: Any) -> Frame:
        """The frame of one robot alone."""
        return cls.of(view.tick, view.stamp, [view])

    @classmethod
    def encode_one(cls, view: Any) -> bytes:
        """``one(view).encode()``, the same bytes, packed in one struct call (a robot alone sends two a tick)."""
        data = cls._alone.pack(cls.KIND, VERSION, view.tick, view.stamp, *cls._record_of(view))
        return with_checksum(data) if cls.CHECKED else data

    @property
    def count(self) -> int:
        return len(self.records)

    def messages(self, keep: RecordFilter | None = None) -> list:
        """One view per record ``keep`` keeps (all without it): the robot, the frame's tick and stamp, the record."""
        tick, stamp = self.tick, self.stamp
        view: Callable[..., Any] = self.VIEW
        records = self.records if keep is None else self.records[keep.mask(self.records)]
        return [view(robot, tick, stamp, *rest) for robot, *rest in records.tolist()]

    def _tail(self) -> bytes:
        return np.asarray(self.records, self.RECORD).tobytes()

    @classmethod
    def _from(cls, body: memoryview) -> Frame:
        size = cls._fixed.size
        if len(body) < size or (len(body) - size) % cls.RECORD.itemsize:
            raise Malformed("truncated")
        tick, stamp = cls._fixed.unpack(body[:size])
        count = (len(body) - size) // cls.RECORD.itemsize
        if count == 1:  # a robot alone's: checked (the stamp too) in one struct call, cheaper than numpy
            if (why := cls._unsound_one(cls._one.unpack(body))) is not None:
                raise Malformed(why)
        elif not math.isfinite(stamp):
            raise Malformed("non-finite")
        # its own writable bytes: cheaper than a copy of the structured array
        records = np.frombuffer(bytearray(body[size:]), cls.RECORD)
        if count > 1 and (why := cls._unsound(records)) is not None:
            raise Malformed(why)
        return cls(tick, stamp, records)

    @classmethod
    def _unsound(cls, records: np.ndarray) -> str | None:
        """Why these records are malformed, or None. A few without rules: the sum of all their fields
        (float32 and integers: no overflow in a double) is finite exactly when each float is. Else their
        float fields lie side by side: one strided view checks them all at once."""
        if len(records) <= _FEW_ROWS and not cls._rules:
            fields = _rows_struct(cls._row_format, len(records)).unpack(records.data)
            return None if math.isfinite(sum(fields)) else "non-finite"
        start, width = cls._float_block
        floats = np.ndarray((len(records), width), "<f4", records.data, start, (cls.RECORD.itemsize, 4))
        if not np.isfinite(floats).all():
            return "non-finite"
        return None if all(test(records[k]).all() for k, test in cls._rules) else "invalid"

    @classmethod
    def _unsound_one(cls, v: tuple) -> str | None:
        """Why a frame of one record, read into ``v`` (tick, stamp, the record), is malformed, or None:
        ``_from``'s checks. The floats are float32, so their sum is finite exactly when each is."""
        if not math.isfinite(v[1]) or not math.isfinite(sum(v[cls._one_floats])):
            return "non-finite"
        for i, test in cls._one_rules:  # a loop, not all(): a generator costs more than a rule or two
            if not test(v[i]):
                return "invalid"
        return None

    # Rules of a kind's records beyond finite numbers: (field, test), a test taking a value or a column.
    _rules: ClassVar[tuple[tuple[str, Callable[[Any], Any]], ...]] = ()
    # Derived from RECORD once per kind (__init_subclass__):
    _float_block: ClassVar[tuple[int, int]]  # (byte offset in a record, count) of the float fields
    _row_format: ClassVar[str]  # a record's struct characters, without byte order
    _alone: ClassVar[struct.Struct]  # a whole message of one record: header, tick, stamp, the record
    _alone_bytes: ClassVar[int]  # its length on the wire, with the checksum of a CHECKED kind
    _one: ClassVar[struct.Struct]  # the body of a frame of one record: tick, stamp, the record
    _one_floats: ClassVar[slice]  # the record's float fields in what _one reads
    _one_rules: ClassVar[tuple[tuple[int, Callable[[Any], Any]], ...]]  # _rules by position in it
    _record_of: ClassVar[Callable[[Any], tuple]]  # a view's record fields, in the record's order

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        names = cls.RECORD.names or ()
        fields: Mapping[str, tuple] = cls.RECORD.fields or {}
        offsets = [fields[k][1] for k in cls._floats]
        adjacent = offsets == list(range(offsets[0], offsets[0] + 4 * len(offsets), 4))
        if not adjacent or any(fields[k][0] != np.dtype("<f4") for k in cls._floats):
            raise TypeError(f"{cls.__name__}: the float fields of a record must be adjacent float32")
        cls._float_block = (offsets[0], len(offsets))
        cls._row_format = row = _row_struct(cls.RECORD).format[1:]
        cls._alone = struct.Struct(_HEADER.format + cls._fixed.format[1:] + row)
        cls._alone_bytes = cls._alone.size + (_CHECKSUM.size if cls.CHECKED else 0)
        cls._one = struct.Struct(cls._fixed.format + row)
        first = _ONE_RECORD_AT + names.index(cls._floats[0])
        cls._one_floats = slice(first, first + len(cls._floats))
        cls._one_rules = tuple((_ONE_RECORD_AT + names.index(k), test) for k, test in cls._rules)
        cls._record_of = staticmethod(attrgetter(*names))

    @classmethod
    def views_first(cls, data: bytes) -> tuple[int, list, np.ndarray | None] | None:
        """(tick, [view of its first record], the records after it, None for a frame of one) of a well-formed
        frame, with ``_from``'s checks: the first record in one struct call, the rest in one numpy view. None
        for anything else (an empty frame, or anything wrong), for decode to read and count."""
        extra = len(data) - cls._alone_bytes
        if extra < 0 or extra % cls.RECORD.itemsize:
            return None
        if (cls.CHECKED and not intact(data)) or data[0] != cls.KIND or data[1] != VERSION:
            return None
        v = cls._one.unpack_from(data, _HEADER.size)
        if cls._unsound_one(v) is not None:
            return None
        rest = np.frombuffer(data, cls.RECORD, extra // cls.RECORD.itemsize, cls._alone.size) if extra else None
        if rest is not None and cls._unsound(rest) is not None:
            return None
        return v[0], [cls.VIEW(v[_ONE_RECORD_AT], v[0], v[1], *v[_ONE_RECORD_AT + 1 :])], rest


@dataclass
class Poses(Frame):
    """Tracker -> agents: a tick's tracked poses, every robot's (agent hosts) or one's and the bodies near it
    (a robot alone)."""

    KIND: ClassVar[int] = 10
    VIEW: ClassVar[type] = Pose
    NAME: ClassVar[str] = Pose.NAME
    RECORD: ClassVar[np.dtype] = np.dtype([("robot", "<u4"), ("x", "<f4"), ("y", "<f4"), ("theta", "<f4")])
    _floats: ClassVar[tuple[str, ...]] = ("x", "y", "theta")

    @classmethod
    def records_of(cls, robots: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """The records of these robots at these poses ((N, 2) or (N, 3): x, y, and theta if given, else 0)."""
        records = np.zeros(len(robots), cls.RECORD)
        records["robot"] = robots
        for name, column in zip(cls._floats, np.asarray(poses, float).T):
            records[name] = column
        return records


@dataclass
class Commands(Frame):
    """Agent host -> bodies: the commands of its robots for one tick."""

    KIND: ClassVar[int] = 11
    VIEW: ClassVar[type] = Command
    NAME: ClassVar[str] = Command.NAME
    RECORD: ClassVar[np.dtype] = np.dtype(
        [("robot", "<u4"), ("mode", "u1"), ("a", "<f4"), ("b", "<f4"), ("r", "u1"), ("g", "u1"), ("bl", "u1")]
    )
    _floats: ClassVar[tuple[str, ...]] = ("a", "b")
    _rules = (("mode", lambda mode: mode <= Command.WHEELS),)


@dataclass
class States(Frame):
    """Agent host -> agent hosts: its robots' states at a tick (hellos: BEFORE_START). A robot alone files its
    frame under its spatial cell; a host's goes to every host, which listens to most cells anyway."""

    KIND: ClassVar[int] = 12
    # checked: a damaged copy that still decodes would be believed by neighbours' ORCA and the run's record
    CHECKED: ClassVar[bool] = True
    VIEW: ClassVar[type] = State
    NAME: ClassVar[str] = State.NAME
    _floats: ClassVar[tuple[str, ...]] = ("x", "y", "vx", "vy", "radius", "goal_x", "goal_y")
    RECORD: ClassVar[np.dtype] = np.dtype(
        [("robot", "<u4"), *((k, "<f4") for k in _floats), ("goal_index", "<i4"), ("flags", "u1")]
        + [("assign_epoch", "<u4"), ("assign_instance", "<u4")]
    )
    _rules = (("radius", lambda radius: radius > 0),)


FRAME_OF: dict[type, type[Frame]] = {f.VIEW: f for f in (Poses, Commands, States)}  # view -> its frame kind


@dataclass
class Truth(Message):
    """Simulation only: true poses, velocities and LED colours of all robots at a tick (recorder)."""

    KIND: ClassVar[int] = 6
    NAME: ClassVar[str] = "sim/truth"
    # checked, as Contact and Event are: the recorder believes them, and a damaged copy would rewrite the record
    CHECKED: ClassVar[bool] = True
    _fixed: ClassVar[struct.Struct] = struct.Struct("<IdfI")
    RECORD: ClassVar[np.dtype] = np.dtype(
        [("pose", "<f8", (3,)), ("vel", "<f4", (2,)), ("rgb", "u1", (3,)), ("applied", "<u4")]
    )
    tick: int
    stamp: float
    min_clearance: float  # smallest robot-robot clearance during the last step (all substeps)
    count: int
    pose: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    applied: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))  # commands applied per robot
    _counts: ClassVar[str] = "pose"

    def _tail(self) -> bytes:
        items = np.empty(len(self.pose), self.RECORD)
        items["pose"], items["vel"], items["rgb"], items["applied"] = self.pose, self.velocity, self.color, self.applied
        return items.tobytes()

    @classmethod
    def _from(cls, body: memoryview) -> Truth:
        tick, stamp, min_clearance, count = _leading(cls._fixed, body)
        if len(body) != cls._fixed.size + count * cls.RECORD.itemsize:
            raise Malformed("truncated")
        items = np.frombuffer(body[cls._fixed.size :], cls.RECORD)
        _finite(stamp, items["pose"], items["vel"])
        if math.isnan(min_clearance) or min_clearance == -math.inf:  # +inf with one robot; never NaN or -inf
            raise Malformed("non-finite")
        pose, rgb, applied = (items[k].copy() for k in ("pose", "rgb", "applied"))
        return cls(tick, stamp, min_clearance, count, pose, items["vel"].astype(float), rgb, applied)


@dataclass
class Contact(Message):
    """Simulation only: a contact event began (kind 0 robot-robot, 1 obstacle, 2 wall)."""

    KIND: ClassVar[int] = 7
    NAME: ClassVar[str] = "sim/contact"
    CHECKED: ClassVar[bool] = True
    _fixed: ClassVar[struct.Struct] = struct.Struct("<BIidf")
    contact_kind: int
    i: int
    j: int
    t_start: float
    depth: float


@dataclass
class Event(Message):
    """Low-rate run events as a JSON object (end of run, world statistics, crash reports)."""

    KIND: ClassVar[int] = 8
    NAME: ClassVar[str] = "event"
    CHECKED: ClassVar[bool] = True
    _fixed: ClassVar[struct.Struct] = struct.Struct("<")
    data: dict = field(default_factory=dict)

    def _tail(self) -> bytes:
        return json.dumps(self.data, allow_nan=False, separators=(",", ":")).encode()

    @classmethod
    def _from(cls, body: memoryview) -> Event:
        # bad JSON or UTF-8 raises ValueError, which decode counts as invalid
        data = json.loads(bytes(body), parse_constant=_finite_float, parse_float=_finite_float)
        if not isinstance(data, dict):
            raise Malformed("invalid")
        return cls(data)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.data)


BLOCK_ABANDONED = "block-abandoned"  # an Event: a lock-step host gave up an auction block (epoch, robots)


def _finite_float(text: str) -> float:
    """A JSON number (or NaN, Infinity) as a float; non-finite (1e999 too) is Malformed."""
    value = float(text)
    if not math.isfinite(value):
        raise Malformed("non-finite")
    return value


MESSAGE_TYPES: dict[int, type[Message]] = {
    t.KIND: t for t in (Tick, Goals, Truth, Contact, Event, Bid, Boards, Poses, Commands, States)
}
BY_NAME: dict[str, type[Message]] = {t.NAME: t for t in MESSAGE_TYPES.values()}


MessageT = TypeVar("MessageT", bound=Message)


@overload
def decode(data: bytes | memoryview, expected: type[MessageT], drops: DropCounter | None = None) -> MessageT | None: ...


@overload
def decode(data: bytes | memoryview, expected: None = None, drops: DropCounter | None = None) -> Message | None: ...


def decode(
    data: bytes | memoryview, expected: type[Message] | None = None, drops: DropCounter | None = None
) -> Message | None:
    """Decode one message; None (and a counted drop) for anything malformed. Never raises."""
    try:
        view = memoryview(data)
        kind, version = _leading(_HEADER, view)
        if version != VERSION:
            raise Malformed("version")
        message_type = MESSAGE_TYPES.get(kind)
        if message_type is None or (expected is not None and message_type is not expected):
            raise Malformed("kind")
        if not message_type.CHECKED:
            return message_type._from(view[_HEADER.size :])
        if not intact(view):
            raise Malformed("checksum")
        return message_type._from(view[_HEADER.size : len(view) - _CHECKSUM.size])
    except Malformed as err:
        reason = str(err)
    except (struct.error, ValueError, TypeError, OverflowError, RecursionError):  # JSON nested past Python's stack
        reason = "invalid"
    if drops is not None:
        drops[reason] += 1
    return None


class RecordFilter(Protocol):
    """Which records of a frame an inbox keeps (transport.bus.KeepRobots, agent.runtime's cells)."""

    def mask(self, records: np.ndarray) -> np.ndarray:
        """The records kept, of a frame's structured array."""

    def keeps(self, view: Any) -> bool:
        """Whether the view of one record is kept."""


def decode_views(
    data: bytes | memoryview, frame: type[Frame], drops: DropCounter | None = None, keep: RecordFilter | None = None
) -> tuple[int, list] | None:
    """A frame of this kind as (tick, one view per record it keeps); a frame of one in one struct call
    (Frame.views_first). None (and a counted drop) for anything malformed. Never raises."""
    # a frame of one only: a longer frame's checks are decode's, made once
    if isinstance(data, bytes) and len(data) == frame._alone_bytes and (first := frame.views_first(data)) is not None:
        return first[:2] if keep is None or keep.keeps(first[1][0]) else (first[0], [])
    got = decode(data, frame, drops)
    return None if got is None else (got.tick, got.messages(keep))
