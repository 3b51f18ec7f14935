"""Fuzz of every message kind's decoder from valid encodings (issue 40).

Each input is a valid message of one kind, encoded, then maybe mutated: cut short, extended, one
field overwritten with an extreme (0, max, min, the smallest, NaN, +/-inf), the kind or the version
byte wrong, a byte of noise. Whatever the input, ``decode`` does not raise and either drops it,
counting exactly one drop with a known reason, or returns what was encoded: an unmutated message
equal field by field (float32 fields as float32 rounds them), and a mutated one that is still well
formed (an int overwritten with 0, a frame cut at a record's end) re-encodes to exactly the bytes it
came from (a goal set less the parts of kinds it does not know, which it skips). Where the verdict
is certain it is checked: a wrong version is `version`, a wrong kind `kind`, a NaN or infinity
`non-finite`, a fixed-length message cut or extended `truncated`, a goal set or auction message
mutated under the checksum of what was sent `checksum` (mutated and sealed anew, as a faulty sender
would, it meets the same verdicts as any other kind). For the frames, ``decode_views``
and the one-struct ``Frame.views_first`` agree with ``decode`` on every input.

A warning is an error here: a decoder that warns on what a peer sent raises where warnings are errors.

Cost: the fast tier fuzzes 1,000 inputs of every kind, the slow tier 10,000. Hypothesis costs more
per example than the fuzz of every kind once, however little the example draws, so one example
fuzzes every kind INPUTS_PER_EXAMPLE times over, from a stream of choices seeded by the one integer
hypothesis draws: 1,000 examples are 10,000 inputs of every kind. Inputs stay small (at most four
records, goals, words or keys, an extension of at most 64 bytes), so no input can make a decoder
work long.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import random
import struct
import sys
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from transport.codec import (
    MESSAGE_TYPES,
    VERSION,
    Bid,
    Boards,
    Commands,
    Contact,
    Correspondence,
    DropCounter,
    Event,
    Frame,
    Goals,
    Lives,
    Message,
    Motion,
    Poses,
    States,
    Tick,
    Timing,
    Truth,
    WarmStart,
    decode,
    decode_views,
    with_checksum,
)

EXAMPLES = 10_000  # inputs per message kind in the slow tier
FAST_EXAMPLES = 1_000  # the fast tier's share of them
INPUTS_PER_EXAMPLE = 10  # inputs of each kind one hypothesis example fuzzes
REASONS = {"truncated", "version", "kind", "checksum", "non-finite", "invalid"}
U16, U32, U64 = 2**16 - 1, 2**32 - 1, 2**64 - 1
I32_MIN, I32_MAX = -(2**31), 2**31 - 1
F32_MAX = float(np.finfo(np.float32).max)
F32_TINY = float(np.finfo(np.float32).smallest_subnormal)

# The layouts, field by field as docs/protocol.md gives them (struct codes), after the 2-byte header.
TICK = [("tick", "I"), ("stamp", "d"), ("dt", "f"), ("goal_epoch", "I")]
CONTACT = [("contact_kind", "B"), ("i", "I"), ("j", "i"), ("t_start", "d"), ("depth", "f")]
FRAME = [("tick", "I"), ("stamp", "d")]
POSE = [("robot", "I"), ("x", "f"), ("y", "f"), ("theta", "f")]
COMMAND = [("robot", "I"), ("mode", "B"), ("a", "f"), ("b", "f"), ("r", "B"), ("g", "B"), ("bl", "B")]
STATE = [("robot", "I"), *((k, "f") for k in ("x", "y", "vx", "vy", "radius", "goal_x", "goal_y"))]
STATE += [("goal_index", "i"), ("flags", "B"), ("assign_epoch", "I"), ("assign_instance", "I")]
TRUTH = [("tick", "I"), ("stamp", "d"), ("min_clearance", "f"), ("count", "I")]
TRUTH_ROBOT = [("pose", "ddd"), ("velocity", "ff"), ("color", "BBB"), ("applied", "I")]
AUCTION = [("robot", "H"), ("goal", "i"), ("price", "d"), ("flags", "B")]
BID = [("epoch", "I"), ("instance", "I"), ("sender", "I"), ("serial", "I"), ("digest", "Q"), ("count", "I")]
BID_RECORD = [*AUCTION, ("penalty", "f"), ("x", "f"), ("y", "f")]
BOARDS = [(k, "I") for k in ("epoch", "instance", "sender", "serial", "goals", "robots", "count")]
WORD = [("robot", "H"), ("x", "f"), ("y", "f"), ("phase", "B"), ("flags", "B"), ("last", "I"), ("records", "I")]
PART = [("part kind", "B"), ("part version", "B"), ("length", "I")]
GOAL_SET = [("epoch", "I"), ("per_robot", "B"), ("count", "I")]
GOAL = [("x", "f"), ("y", "f"), ("rgb", "BBB")]
TIMING = [("stamp", "d"), ("step", "H"), ("hold", "f"), ("t_start", "d"), ("frame_period", "f")]
MOTION = [*((k, "f") for k in ("v_gx", "v_gy", "omega_g", "p_ogx", "p_ogy", "k_eg")), ("geometric", "B")]
FRAMES = {Poses: POSE, Commands: COMMAND, States: STATE}


def _codes(layout: list[tuple[str, str]]) -> str:
    return "<" + "".join(code for _, code in layout)


def _r32(value: float) -> float:
    """A float as a float32 field carries it."""
    return struct.unpack("<f", struct.pack("<f", value))[0]


class Choices:
    """A message's and its mutation's choices, from a seeded stream: small values, bounds and
    specials often, uniform ones otherwise (hypothesis's own mix, at a fraction of its cost)."""

    F32 = (0.0, -0.0, 1.0, -1.0, 0.5, F32_MAX, -F32_MAX, F32_TINY, -F32_TINY, 1.1754943508222875e-38, 16777217.0)
    F64 = (0.0, -0.0, 1.0, -1.0, 0.1, sys.float_info.max, -sys.float_info.max, 5e-324, 2.2250738585072014e-308, 1e300)

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.bits = self.rng.getrandbits

    def below(self, n: int) -> int:
        return self.bits(32) % n

    def integer(self, lo: int, hi: int) -> int:
        mode = self.bits(3)
        if mode < 3:
            return min(lo + self.bits(3), hi)
        if mode == 3:
            return hi
        if mode == 4:
            return max(hi - self.bits(3), lo)
        return lo + self.bits(64) % (hi - lo + 1)

    def f32(self) -> float:
        """A finite float within float32's range (a float32 field rounds it, never to infinity)."""
        mode = self.bits(3)
        if mode == 0:
            return 0.0
        if mode == 1:
            return self.F32[self.below(len(self.F32))]
        if mode < 4:
            return (self.bits(20) - 2**19) / 1000  # decimals: most are not float32 values
        if mode < 6:
            word = self.bits(32)
            if (word >> 23) & 0xFF == 0xFF:
                word &= ~(1 << 23)  # an infinity or NaN's exponent, one less: finite
            return struct.unpack("<f", word.to_bytes(4, "little"))[0]
        return (self.rng.random() * 2 - 1) * 10

    def f64(self) -> float:
        mode = self.bits(3)
        if mode == 0:
            return 0.0
        if mode == 1:
            return self.F64[self.below(len(self.F64))]
        if mode < 4:
            return (self.bits(20) - 2**19) / 1000
        if mode < 6:
            word = self.bits(64)
            if (word >> 52) & 0x7FF == 0x7FF:
                word &= ~(1 << 52)
            return struct.unpack("<d", word.to_bytes(8, "little"))[0]
        return (self.rng.random() * 2 - 1) * 1e3

    def text(self) -> str:
        return "".join(self.rng.choice('ab_ -\u00e9\u2713"\\\n\u2028\U0001f600') for _ in range(self.below(6)))

    def json_value(self, depth: int = 0) -> object:
        mode = self.below(8)
        if mode == 0:
            return self.integer(-(2**64), 2**64)
        if mode == 1:
            return self.f64()
        if mode == 2:
            return self.text()
        if mode == 3:
            return bool(self.below(2))
        if mode == 4:
            return None
        if mode == 5 or depth:
            return [self.integer(-5, 5) for _ in range(self.below(4))]
        return {self.text(): self.json_value(depth + 1) for _ in range(self.below(3))}


# Valid messages of each kind: (message, what it decodes to), and its fields' layout (offset, code,
# name) for the overwrites.


def _tick(c: Choices) -> tuple[Message, Message]:
    tick, stamp, dt, epoch = c.integer(0, U32), c.f64(), c.f32(), c.integer(0, U32)
    return Tick(tick, stamp, dt, epoch), Tick(tick, stamp, _r32(dt), epoch)


def _contact(c: Choices) -> tuple[Message, Message]:
    kind, i, j, t, depth = c.integer(0, 255), c.integer(0, U32), c.integer(I32_MIN, I32_MAX), c.f64(), c.f32()
    return Contact(kind, i, j, t, depth), Contact(kind, i, j, t, _r32(depth))


def _event(c: Choices) -> tuple[Message, Message]:
    data = {c.text(): c.json_value() for _ in range(c.below(4))}
    return Event(data), Event(data)


def _record(c: Choices, frame: type[Frame]) -> tuple:
    if frame is Poses:
        return (c.integer(0, U32), c.f32(), c.f32(), c.f32())
    if frame is Commands:
        return (c.integer(0, U32), c.below(2), c.f32(), c.f32(), c.below(256), c.below(256), c.below(256))
    x, y, vx, vy, radius, gx, gy = (c.f32() for _ in range(7))
    radius = abs(radius) or 0.045  # > 0: a float32 rounds no nonzero choice to 0
    flags = (c.integer(I32_MIN, I32_MAX), c.below(256), c.integer(0, U32), c.integer(0, U32))
    return (c.integer(0, U32), x, y, vx, vy, radius, gx, gy, *flags)


def _frame(frame: type[Frame]):
    def make(c: Choices) -> tuple[Message, Message]:
        tick, stamp = c.integer(0, U32), c.f64()
        records = np.array([_record(c, frame) for _ in range(c.below(5))], frame.RECORD)
        return frame(tick, stamp, records), frame(tick, stamp, records.copy())

    return make


def _f32s(rows: list, columns: int) -> tuple[np.ndarray, np.ndarray]:
    sent = np.array(rows, float).reshape(len(rows), columns)
    return sent, sent.astype(np.float32).astype(float)


def _goals(c: Choices) -> tuple[Message, Message]:
    count = c.below(5)
    positions, positions32 = _f32s([(c.f32(), c.f32()) for _ in range(count)], 2)
    colors = np.array([[c.below(256) for _ in range(3)] for _ in range(count)], np.uint8).reshape(count, 3)
    robots = np.array([c.integer(0, U16) for _ in range(c.below(5))], np.int64)
    epoch, per_robot = c.integer(0, U32), c.below(2)
    stamp, step, hold, t_start, period = c.f64(), c.integer(0, U16), c.f32(), c.f64(), abs(c.f32())
    timing = Timing(stamp, step, hold, t_start, period)
    timing32 = Timing(stamp, step, _r32(hold), t_start, _r32(period))
    motion = motion32 = correspondence = warm_start = lives = None
    if c.below(2):
        floats, geometric = [c.f32() for _ in range(6)], c.below(2)
        if geometric and _r32(floats[5]) <= -1:
            floats[5] = -floats[5]  # K_eG > -1 for a geometric scaling
        motion, motion32 = Motion(*floats, geometric), Motion(*map(_r32, floats), geometric)
    if c.below(2):
        previous = np.array([c.integer(-1, count - 1) for _ in range(count)], np.int64)
        correspondence = Correspondence(c.integer(1, U32), previous)
    if c.below(2):
        matched = np.array([c.integer(0, count - 1) for _ in range(count)], np.int64)
        warm_start = WarmStart(c.integer(1, U32), matched, np.array([c.f64() for _ in range(count)], float))
    if c.below(2):
        lives = Lives(np.array([c.integer(0, U32) for _ in range(len(robots))], np.int64))
    parts = (correspondence, warm_start, lives)
    return (
        Goals(epoch, per_robot, positions, colors, robots, timing, motion, *parts),
        Goals(epoch, per_robot, positions32, colors.copy(), robots.copy(), timing32, motion32, *parts),
    )


def _truth(c: Choices) -> tuple[Message, Message]:
    n = c.below(5)
    tick, stamp = c.integer(0, U32), c.f64()
    clearance = math.inf if c.below(8) == 0 else c.f32()  # +inf: one robot, nothing to clear
    pose = np.array([[c.f64() for _ in range(3)] for _ in range(n)], float).reshape(n, 3)
    velocity, velocity32 = _f32s([(c.f32(), c.f32()) for _ in range(n)], 2)
    color = np.array([[c.below(256) for _ in range(3)] for _ in range(n)], np.uint8).reshape(n, 3)
    applied = np.array([c.integer(0, U32) for _ in range(n)], np.uint32)
    return (
        Truth(tick, stamp, clearance, n, pose, velocity, color, applied),
        Truth(tick, stamp, _r32(clearance), n, pose.copy(), velocity32, color.copy(), applied.copy()),
    )


def _auction_record(c: Choices, goals: int = 0) -> tuple:
    goal = c.integer(0, min(goals, I32_MAX + 1) - 1) if goals else c.integer(I32_MIN, I32_MAX)
    return (c.integer(0, U16), goal, c.f64(), c.below(256))


def _bid(c: Choices) -> tuple[Message, Message]:
    n = c.below(5)
    fixed = (c.integer(0, U32), c.integer(0, U32), c.integer(0, U32), c.integer(0, U32), c.integer(0, U64))
    records = np.array([(*_auction_record(c), c.f32(), c.f32(), c.f32()) for _ in range(n)], Bid.RECORD)
    return Bid(*fixed, n, records), Bid(*fixed, n, records.copy())


def _boards(c: Choices) -> tuple[Message, Message]:
    fixed = (c.integer(0, U32), c.integer(0, U32), c.integer(0, U32), c.integer(0, U32))
    goals, robots = c.integer(1, U32), c.integer(1, 64)
    words = []
    for _ in range(c.below(5)):
        flags = c.below(8)
        records = c.below(3) if flags & Boards.FRESH else 0
        words.append((c.integer(0, U16), c.f32(), c.f32(), c.below(256), flags, c.integer(0, U32), records))
    grown, row = sum(1 for w in words if w[4] & Boards.GROWN), (robots + 7) // 8
    known = np.array([[c.below(256) for _ in range(row)] for _ in range(grown)], np.uint8).reshape(grown, row)
    records = np.array([_auction_record(c, goals) for _ in range(sum(w[6] for w in words))], Boards.RECORD)
    args = (*fixed, goals, robots, len(words), np.array(words, Boards.WORD), known, records)
    return Boards(*args), Boards(*(a.copy() if isinstance(a, np.ndarray) else a for a in args))


KINDS = {
    Tick: _tick,
    Contact: _contact,
    Event: _event,
    Goals: _goals,
    Truth: _truth,
    Bid: _bid,
    Boards: _boards,
    **{frame: _frame(frame) for frame in FRAMES},
}


def _layout(msg: Message) -> tuple[tuple[int, str, str], ...]:
    """Every field of an encoded message: (byte offset, struct code, name)."""
    shape: tuple = ()
    if isinstance(msg, Goals):
        parts = (msg.motion, msg.correspondence, msg.warm_start, msg.lives)
        shape = (msg.count, len(msg.robots), *(part is not None for part in parts))
    elif isinstance(msg, Boards):
        shape = (len(msg.words), msg.known.size, len(msg.records))
    elif isinstance(msg, Frame | Bid):
        shape = (len(msg.records),)
    elif isinstance(msg, Truth):
        shape = (len(msg.pose),)
    return _layout_of(type(msg), shape)


@functools.cache
def _layout_of(kind: type[Message], shape: tuple) -> tuple[tuple[int, str, str], ...]:
    groups: list[tuple[str, list[tuple[str, str]]]] = []
    if kind is Tick:
        groups = [("", TICK)]
    elif kind is Contact:
        groups = [("", CONTACT)]
    elif kind in FRAMES:
        groups = [("", FRAME)] + [("record.", FRAMES[kind])] * shape[0]
    elif kind is Truth:
        groups = [("", TRUTH)] + [("robot.", TRUTH_ROBOT)] * shape[0]
    elif kind is Bid:
        groups = [("", BID)] + [("record.", BID_RECORD)] * shape[0]
    elif kind is Boards:
        words, known, records = shape
        groups = [("", BOARDS), *[("word.", WORD)] * words, ("", [("known", "B")] * known)]
        groups += [("record.", AUCTION)] * records
    elif kind is Goals:
        count, robots, motion, correspondence, warm_start, lives = shape
        groups = [("set.", PART), ("set.", GOAL_SET), *[("goal.", GOAL)] * count, ("set.", [("robot", "H")] * robots)]
        groups += [("timing.", PART), ("timing.", TIMING)]
        if motion:
            groups += [("motion.", PART), ("motion.", MOTION)]
        if correspondence:
            groups += [("correspondence.", PART + [("follows", "I")] + [("previous", "i")] * count)]
        if warm_start:
            matched = [("matched", "i")] * count + [("prices", "d")] * count
            groups += [("warm_start.", PART + [("matched_from", "I")] + matched)]
        if lives:
            groups += [("lives.", PART + [("life", "I")] * robots)]
    out, at = [], 2
    for prefix, layout in groups:
        for name, codes in layout:
            for code in codes:
                out.append((at, code, prefix + name))
                at += struct.calcsize("<" + code)
    return tuple(out)


def _extremes(code: str) -> list[tuple[str, bytes]]:
    """A field's extreme values, packed: 0, max and min, and for floats the smallest, NaN (quiet,
    signalling, negative) and the infinities."""
    if code in "fd":
        fmt, word = "<" + code, "<I" if code == "f" else "<Q"
        big, tiny = (F32_MAX, F32_TINY) if code == "f" else (sys.float_info.max, 5e-324)
        snan, negative_nan = (0x7F800001, 0xFFC00000) if code == "f" else (0x7FF0000000000001, 0xFFF8000000000000)
        values = [("0", 0.0), ("max", big), ("min", -big), ("tiny", tiny)]
        values += [("nan", math.nan), ("inf", math.inf), ("-inf", -math.inf)]
        packed = [(label, struct.pack(fmt, v)) for label, v in values]
        return packed + [("snan", struct.pack(word, snan)), ("-nan", struct.pack(word, negative_nan))]
    bits = 8 * struct.calcsize(code)
    if code.isupper():
        return [("0", bytes(bits // 8)), ("max", struct.pack("<" + code, 2**bits - 1))]
    lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
    return [(label, struct.pack("<" + code, v)) for label, v in (("0", 0), ("min", lo), ("max", hi), ("-1", -1))]


EXTREMES = {code: _extremes(code) for code in "BHIQifd"}
NON_FINITE = {"nan", "snan", "-nan", "inf", "-inf"}
# JSON text in place of one value of an event, and the drop it must cause (None: it is a value)
LITERALS = [
    ("0", None),
    ("-0.0", None),
    ("1.7976931348623157e308", None),
    ("-1.7976931348623157e308", None),
    ("5e-324", None),
    ("18446744073709551616", None),
    ("-9223372036854775809", None),
    ('"\\ud800"', None),
    ("null", None),
    ("1e999", "non-finite"),
    ("-1e999", "non-finite"),
    ("NaN", "non-finite"),
    ("Infinity", "non-finite"),
    ("-Infinity", "non-finite"),
    ("1" * 5000, "invalid" if 0 < sys.get_int_max_str_digits() < 5000 else None),
    ("[" * 5000 + "]" * 5000, "invalid"),  # deeper than Python's stack: a RecursionError killed the recorder's process
]
OTHER_KINDS = (0, 1, 2, 3, 200, 255)  # unknown, or retired (1-3)


@dataclasses.dataclass
class Case:
    """One input: its bytes, what was done, and what decode must make of it: "same" (equal to
    ``want`` field by field), "accept" (well formed: ``want`` if given), a drop's reason, or None
    (either way)."""

    data: bytes
    what: str
    expect: str | None
    want: Message | None = None


def _mutate(c: Choices, msg: Message, want: Message) -> Case:
    """A kind that ends in a checksum has its bytes before it mutated, then either sealed anew (what a
    faulty sender sends: its layout is fuzzed as any other kind's) or sent with the checksum of the
    bytes unmutated (damaged on the way: dropped as such unless its kind or version says otherwise)."""
    if not msg.CHECKED:
        return _mutate_body(c, msg, want, msg.encode())
    data = msg.encode()
    body, checksum = data[:-4], data[-4:]
    case = _mutate_body(c, msg, want, body)
    expect = None if len(case.data) < 2 else case.expect  # the checksum's bytes are its header now
    if c.below(2):
        return Case(with_checksum(case.data), case.what + ", sealed anew", expect, case.want)
    if case.data != body and case.data[:2] == body[:2]:  # a header is read before the checksum
        expect = "checksum"
    return Case(case.data + checksum, case.what, expect, case.want)


def _mutate_body(c: Choices, msg: Message, want: Message, data: bytes) -> Case:
    kind, mode = type(msg), c.below(16)
    fixed_length = kind in (Tick, Contact, Truth, Bid, Boards)
    if mode < 2:
        return Case(data, "none", "same", want)
    if mode < 4:
        k = c.below(len(data))
        if k < 2 or fixed_length:
            return Case(data[:k], f"cut to {k}", "truncated")
        if isinstance(want, Frame):
            whole, part = divmod(k - 2 - Frame._fixed.size, kind.RECORD.itemsize)
            if whole < 0 or part:
                return Case(data[:k], f"cut to {k}", "truncated")
            return Case(data[:k], f"cut to {k}", "accept", kind(want.tick, want.stamp, want.records[:whole]))
        return Case(data[:k], f"cut to {k}", None)
    if mode < 6:
        how = c.below(4)
        if how == 0:  # a copy of its own start
            extra = data[: c.integer(1, min(64, len(data)))]
        elif how == 1 and isinstance(msg, Frame):  # whole records
            extra = c.rng.randbytes(kind.RECORD.itemsize * c.integer(1, 2))
        elif how == 1 and isinstance(msg, Goals):  # a part, of a kind that may be unknown
            body = c.rng.randbytes(c.integer(0, 30))
            extra = struct.pack("<BBI", c.integer(0, 255), c.integer(0, 2), len(body)) + body
        else:
            extra = c.rng.randbytes(c.integer(1, 64))
        return Case(data + extra, f"extended by {extra.hex()}", "truncated" if fixed_length else None)
    if mode < 13:
        if isinstance(msg, Event):
            return _overwrite_event_value(c, msg)
        layout = _layout(msg)
        at, code, name = layout[c.below(len(layout))]
        label, value = EXTREMES[code][c.below(len(EXTREMES[code]))]
        mutated = data[:at] + value + data[at + len(value) :]
        expect = None
        if label in NON_FINITE:
            expect = "accept" if (kind is Truth and name == "min_clearance" and label == "inf") else "non-finite"
        return Case(mutated, f"{name} (byte {at}, {code}) = {label}", expect)
    if mode == 13:
        others = [k for k in (*OTHER_KINDS, *MESSAGE_TYPES) if k != kind.KIND]
        wrong = others[c.below(len(others))]
        return Case(bytes([wrong]) + data[1:], f"kind {wrong}", "kind")
    if mode == 14:
        wrong = (0, VERSION - 1, VERSION + 1, 255)[c.below(4)]
        return Case(data[:1] + bytes([wrong]) + data[2:], f"version {wrong}", "version")
    at = c.below(len(data))
    return Case(data[:at] + bytes([c.below(256)]) + data[at + 1 :], f"noise at {at}", None)


def _overwrite_event_value(c: Choices, msg: Event) -> Case:
    data = dict(msg.data) or {"k": 0}
    key = list(data)[c.below(len(data))]
    literal, reason = LITERALS[c.below(len(LITERALS))]
    data[key] = "@@"  # no text of ours has an @
    body = json.dumps(data, allow_nan=False, separators=(",", ":")).replace('"@@"', literal)
    if reason is not None:
        return Case(bytes([Event.KIND, VERSION]) + body.encode(), f"{key!r}: {literal[:30]}", reason)
    data[key] = json.loads(literal)
    return Case(bytes([Event.KIND, VERSION]) + body.encode(), f"{key!r}: {literal[:30]}", "accept", Event(data))


def _canonical(kind: type[Message], data: bytes) -> bytes:
    """The bytes a well-formed message re-encodes to: itself; a goal set without the parts of kinds
    it skips (in the order of their kinds, as it encodes them); an event as compact JSON."""
    if kind is Event:  # its JSON between the header and the checksum
        return with_checksum(
            data[:2] + json.dumps(json.loads(data[2:-4]), allow_nan=False, separators=(",", ":")).encode()
        )
    if kind is not Goals:
        return data
    parts, at, end = [], 2, len(data) - 4  # the parts, then the checksum
    while at < end:
        part, _, length = struct.unpack_from("<BBI", data, at)
        parts.append((part, data[at : at + 6 + length]))
        at += 6 + length
    known = sorted((p for p in parts if p[0] == Goals.PART or p[0] in Goals._PARTS), key=lambda p: p[0])
    return with_checksum(data[:2] + b"".join(body for _, body in known))


def _same(got: object, want: object, path: str = "") -> None:
    """Equal field by field: numbers of the same type and value, arrays of the same dtype, shape
    and bytes (so -0.0 is not 0.0)."""
    if dataclasses.is_dataclass(want):
        assert type(got) is type(want), f"{path}: {type(got).__name__}, not {type(want).__name__}"
        for f in dataclasses.fields(want):
            _same(getattr(got, f.name), getattr(want, f.name), f"{path}.{f.name}")
    elif isinstance(want, np.ndarray):
        assert isinstance(got, np.ndarray), f"{path}: {got!r}"
        assert (got.dtype, got.shape) == (want.dtype, want.shape), (
            f"{path}: {got.dtype} {got.shape}, not {want.dtype} {want.shape}"
        )
        assert got.tobytes() == want.tobytes(), f"{path}: {got!r}, not {want!r}"
    else:
        assert type(got) is type(want) and got == want, f"{path}: {got!r}, not {want!r}"
        if isinstance(want, float):
            assert math.copysign(1, got) == math.copysign(1, want), f"{path}: {got!r}, not {want!r}"


def _verdict(data: bytes | memoryview, expected: type[Message] | None) -> tuple[Message | None, DropCounter]:
    """decode, which must drop with one count and a known reason or give a message that re-encodes
    to what it decoded."""
    drops = DropCounter()
    got = decode(data, expected, drops)
    if got is None:
        assert sum(drops.values()) == 1 and set(drops) <= REASONS, f"dropped with {drops}"
    else:
        assert not drops, f"decoded {got!r} and counted {drops}"
        assert expected is None or type(got) is expected
        assert got.encode() == _canonical(type(got), bytes(data)), f"decoded {got!r}, which is not what was encoded"
    return got, drops


def _fuzz(kind: type[Message], c: Choices) -> None:
    msg, want = KINDS[kind](c)
    case = _mutate(c, msg, want)
    try:
        got, drops = _verdict(case.data, kind)
        if case.expect in ("same", "accept"):
            assert got is not None, f"dropped with {drops}"
            if case.want is not None:
                _same(got, case.want)
        elif case.expect is not None:
            assert got is None and drops == {case.expect: 1}, f"not dropped as {case.expect}: {got!r} {drops}"
        if case.data[:1] != bytes([kind.KIND]):
            _verdict(memoryview(case.data), None)  # read as whatever kind its header now says
        if kind in FRAMES:
            _views_agree(case.data, kind, got, drops)
    except Exception as error:
        error.add_note(f"{kind.__name__} {msg!r}\n{case.what}: {case.data.hex()}")
        raise


def _views_agree(data: bytes, kind: type[Frame], frame: Message | None, drops: DropCounter) -> None:
    """An inbox's reading (decode_views, Frame.views_first for a robot's own key) is the frame's."""
    view_drops = DropCounter()
    views = decode_views(data, kind, view_drops)
    first = kind.views_first(data)
    assert view_drops == drops, f"views dropped with {view_drops}, the frame with {drops}"
    if frame is None:
        assert views is None and first is None, f"views {views}, first {first} of a dropped frame"
        return
    assert isinstance(frame, Frame)
    assert views == (frame.tick, frame.messages())
    if frame.count == 0:
        assert first is None, f"first {first} of an empty frame"
        return
    assert first is not None, "a sound frame's first record was refused"
    tick, head, rest = first
    assert (tick, head) == (frame.tick, frame.messages()[:1])
    assert (rest is None) == (frame.count == 1)
    assert rest is None or rest.tobytes() == frame.records[1:].tobytes()


def test_the_layouts_fuzzed_are_the_codecs():
    """The test's layouts (docs/protocol.md) are the codec's, so an overwrite hits one whole field."""
    assert struct.calcsize(_codes(TICK)) == Tick._fixed.size
    assert struct.calcsize(_codes(CONTACT)) == Contact._fixed.size
    assert struct.calcsize(_codes(FRAME)) == Frame._fixed.size
    for frame, layout in FRAMES.items():
        assert struct.calcsize(_codes(layout)) == frame.RECORD.itemsize
    assert struct.calcsize(_codes(TRUTH)) == Truth._fixed.size
    assert struct.calcsize(_codes(TRUTH_ROBOT)) == Truth.RECORD.itemsize
    assert struct.calcsize(_codes(BID)) == Bid._fixed.size
    assert struct.calcsize(_codes(BID_RECORD)) == Bid.RECORD.itemsize
    assert struct.calcsize(_codes(BOARDS)) == Boards._fixed.size
    assert struct.calcsize(_codes(WORD)) == Boards.WORD.itemsize
    assert struct.calcsize(_codes(AUCTION)) == Boards.RECORD.itemsize
    assert struct.calcsize(_codes(GOAL_SET)) == Goals._set.size
    assert struct.calcsize(_codes(GOAL)) == Goals.RECORD.itemsize
    assert struct.calcsize(_codes(TIMING)) == Timing._layout.size
    assert struct.calcsize(_codes(MOTION)) == Motion._layout.size
    for kind, make in KINDS.items():  # and a message's layout holds every byte after its header (an event's: JSON)
        for seed in range(20):
            msg, _ = make(Choices(seed))
            if kind is not Event:
                checksum = 4 if kind.CHECKED else 0
                assert 2 + sum(struct.calcsize(code) for _, code, _ in _layout(msg)) + checksum == len(msg.encode())


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("examples", [FAST_EXAMPLES, pytest.param(EXAMPLES, marks=pytest.mark.slow)])
def test_every_kind_decodes_what_was_encoded_or_drops_it_with_one_reason(examples: int):
    """``examples`` fuzzed inputs of every message kind (hypothesis draws the seed of each example)."""
    assert set(KINDS) == set(MESSAGE_TYPES.values()), "a message kind without a fuzz"
    inputs: Counter = Counter()
    seeds: set[int] = set()

    @settings(max_examples=examples // INPUTS_PER_EXAMPLE)
    @given(st.integers(0, U64))
    def fuzz(seed: int) -> None:
        seeds.add(seed)
        choices = Choices(seed)
        for _ in range(INPUTS_PER_EXAMPLE):
            for kind in KINDS:
                _fuzz(kind, choices)
                inputs[kind.__name__] += 1

    fuzz()
    runs = len(seeds) * INPUTS_PER_EXAMPLE
    assert runs >= examples and min(inputs.values()) >= examples, (len(seeds), inputs)


def test_an_event_nested_past_the_stack_is_dropped_as_invalid():
    """One such event, sealed, on the event key killed the launcher (its recorder decodes every event)."""
    drops: Counter = Counter()
    body = ("[" * 5000 + "]" * 5000).encode()
    assert decode(with_checksum(bytes([Event.KIND, VERSION]) + body), Event, drops) is None
    assert drops == Counter({"invalid": 1})
