"""A faulty peer on an open bus: it hears a display's messages and re-publishes damaged copies of them,
``rate`` a second, on the keys it heard them on (docs/faults.md).

    python -m sim.emulators.faulty_peer -e tcp/127.0.0.1:PORT [--display NAME] --mode MODE
        [--rate R] [--duration S] [--start-after S] [--stale-after S] [--seed N]

It starts ``--start-after`` s after the run's first clock tick, damages for ``--duration`` s (default: until
stopped) and ends with one line on stdout: the copies it sent, per key kind and per damage. Modes (each
mutates only what it says; the layouts: docs/protocol.md):

- ``future-pose``, ``future-state``, ``future-cmd``: frames with their tick (and stamp) moved 1..FUTURE_MAX ticks
  ahead, half the poses at most AHEAD ticks past the newest heard (what a receiver's clock allows).
- ``malformed-pose``: pose frames truncated, extended, or with a header byte, the count or random bytes
  overwritten (``--damage`` picks among these); some copies still decode.
- ``malformed-all``: every key kind of the bus (``--include-sim``: also sim/truth, sim/contact) likewise.
- ``stale-cmd``: commands re-sent unchanged ``--stale-after`` s or more after they were first heard.
- ``misc``: clock ticks, goal sets, bids and boards, malformed or with a time-like field moved forward.
- ``restart``: frames with the (smaller) tick and stamp of a sender restarted every RESTART_EVERY s.
- ``all``: each copy from one of the modes in ALL_OF that has something to send.
"""

from __future__ import annotations

import argparse
import math
import random
import struct
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TextIO

from sim.args import OneLineParser, add_seconds, display_name, positive_number, positive_seconds, zenoh_endpoint
from sim.processes import stopped_by_signals
from transport.bus import Bus, RawInbox
from transport.codec import BEFORE_START, CHECKSUM_SIZE, FRAME_OF, with_checksum
from transport.keys import Keys
from transport.plausible import AHEAD
from transport.session import ZENOH_HELP, TransportError, ZenohSettings

FRAME_KINDS = ("pose", "state", "cmd")
MISC_KINDS = ("clock", "goals", "auction", "boards")
BUS_KINDS = ("pose", "state", "cmd", "goals", "auction", "boards", "clock", "event")
SIM_KINDS = ("sim/truth", "sim/contact")
ALL_OF = ("future-pose", "future-state", "future-cmd", "malformed-all", "stale-cmd", "misc", "restart")
_MODE_KINDS = {
    "future-pose": ("pose",),
    "future-state": ("state",),
    "future-cmd": ("cmd",),
    "malformed-pose": ("pose",),
    "malformed-all": BUS_KINDS,
    "stale-cmd": ("cmd",),
    "misc": MISC_KINDS,
    "restart": FRAME_KINDS,
    "all": BUS_KINDS,
}
MODES_AND_ALL = tuple(_MODE_KINDS)

FUTURE_MAX = 10_000  # ticks: how far a future tick (epoch, serial) goes at most
RESTART_EVERY = 10.0  # s of wall time between the imitated sender's restarts
RESTART_RATE = 10.0  # ticks a second the restarted sender counts
BUFFER = 256  # recent messages kept per key kind
CONNECT_WAIT = 60.0  # s the peer keeps trying to reach the run's router (it may start first)

_U32 = struct.Struct("<I")
_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")
_TICK_AT = 2  # frames and clock ticks: the u32 tick right after the header
_FRAME_FIXED = 14  # header, tick, stamp
_RECORD_SIZE = {"pose": 16, "cmd": 16, "state": 45}
_CHECKED_FRAMES = {f.NAME for f in FRAME_OF.values() if f.CHECKED}  # frames that end in a checksum
_COUNT_AT = {"auction": (26,), "boards": (18, 22, 26), "sim/truth": (18,)}
_GOALS_SET_AT = 8  # goal set part body: epoch u32, per_robot u8, count u32
_PART_HEADER = struct.Struct("<BBI")


def kinds_of(mode: str, include_sim: bool = False) -> tuple[str, ...]:
    """The key kinds a mode damages."""
    if mode not in _MODE_KINDS:
        raise ValueError(f"unknown mode {mode!r}: one of {', '.join(MODES_AND_ALL)}")
    return _MODE_KINDS[mode] + (SIM_KINDS if include_sim and mode in ("malformed-all", "all") else ())


def _get_u32(data: bytes, at: int) -> int:
    return _U32.unpack_from(data, at)[0]


def _put(data: bytes, at: int, packed: bytes) -> bytes:
    return data[:at] + packed + data[at + len(packed) :]


def _forward_u32(data: bytes, at: int, rng: random.Random) -> bytes | None:
    """The u32 at ``at`` moved forward by 1..FUTURE_MAX (not past 0xFFFFFFFE)."""
    if len(data) < at + 4 or (value := _get_u32(data, at)) >= BEFORE_START - 1:
        return None
    return _put(data, at, _U32.pack(min(value + rng.randint(1, FUTURE_MAX), BEFORE_START - 1)))


def _sealed(kind: str, forged: bytes | None) -> bytes | None:
    """A forged frame resealed with the checksum of its new bytes (if its kind has one): what the future
    and restart modes test is the receiver's judgement of the tick, not the checksum."""
    if forged is None or kind not in _CHECKED_FRAMES:
        return forged
    return with_checksum(forged[:-CHECKSUM_SIZE])


def with_tick(data: bytes, tick: int) -> bytes | None:
    """A frame's copy at another tick, its stamp (the start of its tick) moved along, so that only its
    tick can give it away; None for a frame of tick 0 or before the start (no period to count by)."""
    if len(data) < _FRAME_FIXED:
        return None
    real, stamp = _get_u32(data, _TICK_AT), _F64.unpack_from(data, _TICK_AT + 4)[0]
    if real in (0, BEFORE_START) or not 0 <= tick < BEFORE_START:
        return None
    return _put(data, _TICK_AT, _U32.pack(tick) + _F64.pack(stamp / real * tick))


def future_tick(data: bytes, rng: random.Random, near: bool) -> bytes | None:
    """A frame with its tick moved into the future, the rest intact: ``near``, within the few ticks a receiver's
    clock allows (transport.plausible.AHEAD), else beyond them, up to FUTURE_MAX."""
    if len(data) < _FRAME_FIXED:
        return None
    ahead = rng.randint(1, AHEAD) if near else rng.randint(AHEAD + 1, FUTURE_MAX)
    return with_tick(data, _get_u32(data, _TICK_AT) + ahead)


def truncate(data: bytes, rng: random.Random, kind: str = "") -> bytes | None:
    return data[: rng.randrange(len(data))] if data else None


def extend(data: bytes, rng: random.Random, kind: str = "") -> bytes | None:
    return data + rng.randbytes(rng.randint(1, 32))


def overwrite_header(data: bytes, rng: random.Random, kind: str = "") -> bytes | None:
    """The kind byte, the version byte or both overwritten with other values."""
    if len(data) < 2:
        return None
    out = bytearray(data)
    for at in rng.choice(((0,), (1,), (0, 1))):
        out[at] = (out[at] + rng.randint(1, 255)) % 256
    return bytes(out)


def overwrite_count(data: bytes, rng: random.Random, kind: str = "") -> bytes | None:
    """A count field overwritten; a frame a part of a record short or long; else overwrite_random."""
    places: tuple[int, ...] = _COUNT_AT.get(kind, ())
    if kind == "goals" and len(data) >= _GOALS_SET_AT + 9:
        places = (4, _GOALS_SET_AT + 5)  # the goal set part's length, its count of goals
    if kind in _RECORD_SIZE:
        if len(data) < _FRAME_FIXED:
            return None
        cut = rng.randint(1, _RECORD_SIZE[kind] - 1)
        if rng.random() < 0.5 and len(data) - _FRAME_FIXED >= cut:
            return data[: len(data) - cut]
        return data + rng.randbytes(cut)
    places = tuple(at for at in places if at + 4 <= len(data))
    if not places:
        return overwrite_random(data, rng, kind)
    at = rng.choice(places)
    old = _get_u32(data, at)
    new = rng.choice((0, 0xFFFFFFFF, rng.getrandbits(32), (old + rng.randint(1, 3)) % 2**32, max(old - 1, 0)))
    if new == old:
        new = (old + 1) % 2**32
    return _put(data, at, _U32.pack(new))


def overwrite_random(data: bytes, rng: random.Random, kind: str = "") -> bytes | None:
    """1 to 4 bytes anywhere overwritten with other values."""
    if not data:
        return None
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        at = rng.randrange(len(out))
        out[at] = (out[at] + rng.randint(1, 255)) % 256
    return bytes(out)


MALFORM: dict[str, Callable[..., bytes | None]] = {
    "truncated": truncate,
    "extended": extend,
    "header": overwrite_header,
    "count": overwrite_count,
    "random": overwrite_random,
}


def _goals_timing_stamp_at(data: bytes) -> int | None:
    """Where a goal set's timing part (part 2) keeps its stamp (f64), None if it has none."""
    at = 2
    while at + _PART_HEADER.size <= len(data):
        kind, _, length = _PART_HEADER.unpack_from(data, at)
        at += _PART_HEADER.size
        if kind == 2 and length >= 8 and at + 8 <= len(data):
            return at
        at += length
    return None


def future_stamp(data: bytes, rng: random.Random, kind: str) -> tuple[str, bytes | None]:
    """A clock tick, goal set, bid or board with one of its time-like fields moved forward: its name, the copy."""
    if kind == "clock":
        field = rng.choice(("tick", "stamp", "goal_epoch"))
        if len(data) < 22:
            return field, None
        if field == "tick":
            return field, _forward_u32(data, 2, rng)
        if field == "stamp":
            dt = _F32.unpack_from(data, 14)[0] or 0.1
            stamp = _F64.unpack_from(data, 6)[0]
            return field, _put(data, 6, _F64.pack(stamp + rng.randint(1, FUTURE_MAX) * dt))
        return field, _forward_u32(data, 18, rng)
    if kind == "goals":
        if rng.random() < 0.5:
            return "epoch", _forward_u32(data, _GOALS_SET_AT, rng) if len(data) >= _GOALS_SET_AT + 9 else None
        at = _goals_timing_stamp_at(data)
        if at is None:
            return "stamp", None
        stamp = _F64.unpack_from(data, at)[0]
        return "stamp", _put(data, at, _F64.pack(stamp + rng.uniform(1.0, 1000.0)))
    field, at = rng.choice((("epoch", 2), ("serial", 14)))  # a bid or a board (the misc kinds' last)
    return field, _forward_u32(data, at, rng)


@dataclass(frozen=True)
class PeerPlan:
    """What the faulty peer does: which kinds (``mode``), which damages, copies a second, from
    ``start_after`` s for ``duration`` s (None: until stopped), the seed of its choices, and how long
    after a command was first heard it may be re-sent unchanged (``stale_after``)."""

    mode: str = "all"
    rate: float = 350.0
    duration: float | None = None
    start_after: float = 0.0
    seed: int = 0
    include_sim: bool = False
    damages: tuple[str, ...] = tuple(MALFORM)
    stale_after: float = 2.0


@dataclass
class PeerTally:
    """What the peer heard and sent, for its summary line."""

    heard: Counter[str] = field(default_factory=Counter)  # messages heard, per key kind
    sent: Counter[str] = field(default_factory=Counter)  # damaged copies sent, per key kind
    damage: Counter[str] = field(default_factory=Counter)  # per sub-mode/damage
    skipped: int = 0  # slots with nothing to damage
    started: float | None = None  # wall (monotonic) time damage began
    ended: float | None = None


class FaultyPeer:
    """Hears a display's messages and re-publishes damaged copies of them (see the module's text)."""

    def __init__(
        self,
        settings: ZenohSettings,
        display: str = "default",
        plan: PeerPlan = PeerPlan(),
        connect_wait: float = CONNECT_WAIT,
    ) -> None:
        self.kinds = kinds_of(plan.mode, plan.include_sim)
        unknown = set(plan.damages) - set(MALFORM)
        if unknown or not plan.damages:
            raise ValueError(f"damages must be some of {', '.join(MALFORM)}, not {sorted(unknown) or 'none'}")
        if not (math.isfinite(plan.rate) and plan.rate > 0):
            raise ValueError(f"rate must be a positive number, not {plan.rate}")
        self.settings = replace(settings, mode="client" if settings.mode == "router" else settings.mode)
        self.keys = Keys(display)
        self.plan = plan
        self.rng = random.Random(plan.seed)
        self.connect_wait = connect_wait
        self.heard: dict[str, deque[tuple[str, bytes]]] = {k: deque(maxlen=BUFFER) for k in self.kinds}
        # stale-cmd: commands heard less than stale_after ago, and those old enough to re-send
        self.cmd_fresh: deque[tuple[float, str, bytes]] = deque(maxlen=100_000)
        self.cmd_old: deque[tuple[str, bytes]] = deque(maxlen=2000)
        self.first_tick_wall: float | None = None
        self.tally = PeerTally()
        self.restart_at = 0.0
        self._own: set[bytes] = set()  # copies sent lately (the subscriptions hear them back)
        self._own_order: deque[bytes] = deque(maxlen=8192)

    def hear(self, inboxes: list[RawInbox]) -> None:
        """Keep what the subscriptions brought (not the peer's own copies, which it hears too); commands
        heard stale_after s ago or more become old enough to re-send."""
        for inbox in inboxes:
            for key, data, wall in inbox.drain():
                if data in self._own:
                    continue
                kind = self.keys.kind_of(key)
                if kind == "clock" and self.first_tick_wall is None:
                    self.first_tick_wall = time.monotonic()
                buffer = self.heard.get(kind)
                if buffer is None:
                    continue
                self.tally.heard[kind] += 1
                buffer.append((key, data))
                if kind == "cmd" and self.plan.mode in ("stale-cmd", "all"):
                    self.cmd_fresh.append((wall, key, data))
        now = time.time()  # the subscriptions' clock
        while self.cmd_fresh and now - self.cmd_fresh[0][0] >= self.plan.stale_after:
            _, key, data = self.cmd_fresh.popleft()
            self.cmd_old.append((key, data))

    def _sent_copy(self, payload: bytes) -> None:
        """Remember a copy sent, so that hearing it back is not hearing the display."""
        if len(self._own_order) == self._own_order.maxlen:
            self._own.discard(self._own_order[0])
        self._own_order.append(payload)
        self._own.add(payload)

    def _heard_kinds(self, sub: str) -> list[str]:
        """The key kinds a sub-mode damages that something was heard on."""
        return [k for k in (self.kinds if sub == "malformed-all" else kinds_of(sub)) if self.heard.get(k)]

    def make_copy(self, now: float) -> tuple[str, bytes, str, str] | None:
        """(key, payload, key kind, damage) of one damaged copy, None if there is nothing to damage."""
        sub = self.plan.mode
        if sub == "all":
            choices = [s for s in ALL_OF if (self.cmd_old if s == "stale-cmd" else self._heard_kinds(s))]
            if not choices:
                return None
            sub = self.rng.choice(choices)
        for _ in range(8):  # a drawn message the damage does not apply to: draw another
            got = self._copy_of(sub, now)
            if got is not None:
                return got
        return None

    def _copy_of(self, sub: str, now: float) -> tuple[str, bytes, str, str] | None:
        rng = self.rng
        if sub == "stale-cmd":
            if not self.cmd_old:
                return None
            key, data = rng.choice(self.cmd_old)
            return key, data, "cmd", "stale-cmd"
        kinds = self._heard_kinds(sub)
        if not kinds:
            return None
        kind = rng.choice(kinds)
        key, data = rng.choice(self.heard[kind])
        if sub.startswith("future-"):
            # half the poses a tick or two past the newest heard (an older one moved so little is no future one).
            # A command so near is a second controller's, which makes its robot stand; a state so near is taken
            # when its tick comes, if it comes first (docs/faults.md): neither tests the judgement of a tick
            near = kind == "pose" and rng.random() < 0.5
            key, data = self.heard[kind][-1] if near else (key, data)
            out, what = _sealed(kind, future_tick(data, rng, near)), sub
        elif sub == "misc" and rng.random() >= 0.5:  # else malformed, as below
            field, out = future_stamp(data, rng, kind)
            what = f"future:{field}"
        elif sub in ("malformed-pose", "malformed-all", "misc"):
            name = rng.choice(self.plan.damages)
            out, what = MALFORM[name](data, rng, kind), f"malformed:{name}"
        else:  # restart
            out, what = _sealed(kind, self._restarted(data, now)), "restart"
        if out is None or out == data:
            return None
        return key, out, kind, what

    def _restarted(self, data: bytes, now: float) -> bytes | None:
        """The frame with its tick replaced by a restarted sender's (counting from 0 since its restart)."""
        if len(data) < _FRAME_FIXED:
            return None
        if now - self.restart_at >= RESTART_EVERY:
            self.restart_at = now
        tick = int((now - self.restart_at) * RESTART_RATE)
        return with_tick(data, tick) if tick < _get_u32(data, _TICK_AT) else None

    def _open(self, stop: threading.Event) -> Bus:
        end = time.monotonic() + self.connect_wait
        while True:
            try:
                return Bus(self.settings, self.keys.display, name="faulty-peer")
            except TransportError:
                if time.monotonic() >= end or stop.is_set():
                    raise
                stop.wait(0.5)

    def run(self, stop: threading.Event | None = None, report: TextIO | None = None) -> Counter[str]:
        """Hear, wait for the first tick (and start_after), damage until duration or ``stop``; the summary
        goes to ``report`` before the session closes (which can wait long on a gone router)."""
        stop = stop or threading.Event()
        bus = self._open(stop)
        try:
            inboxes = [
                bus.subscribe_raw(self.keys.clock if kind == "clock" else self.keys.all_of(kind))
                for kind in sorted(set(self.kinds) | {"clock"})
            ]
            while not stop.is_set() and (
                self.first_tick_wall is None or time.monotonic() < self.first_tick_wall + self.plan.start_after
            ):
                self.hear(inboxes)
                stop.wait(0.02)
            started = self.tally.started = self.restart_at = time.monotonic()
            rate, slots = self.plan.rate, 0
            while not stop.is_set():
                now = time.monotonic()
                if self.plan.duration is not None and now >= started + self.plan.duration:
                    break
                self.hear(inboxes)
                due = int((now - started) * rate)
                slots = max(slots, due - int(rate))  # at most a second's worth behind: no burst after a stall
                while slots < due:
                    slots += 1
                    copy = self.make_copy(now)
                    if copy is None:
                        self.tally.skipped += 1
                        continue
                    key, payload, kind, what = copy
                    self._sent_copy(payload)
                    bus.put(key, payload, kind)
                    self.tally.sent[kind] += 1
                    self.tally.damage[what] += 1
                stop.wait(0.01)
            self.tally.ended = time.monotonic()
        finally:
            if report is not None:
                print(self.summary(), file=report, flush=True)
            bus.linger()
            bus.close()
        return self.tally.sent

    def summary(self) -> str:
        t = self.tally
        seconds = (t.ended or time.monotonic()) - t.started if t.started is not None else 0.0
        total = sum(t.sent.values())
        per_kind = " ".join(f"{k}={v}" for k, v in sorted(t.sent.items())) or "-"
        per_damage = " ".join(f"{k}={v}" for k, v in sorted(t.damage.items())) or "-"
        return (
            f"faulty-peer: mode {self.plan.mode}, sent {total} in {seconds:.1f} s "
            f"({total / seconds if seconds > 0 else 0:.0f}/s); by kind: {per_kind}; by damage: {per_damage}; "
            f"heard {sum(t.heard.values())}; nothing to damage {t.skipped}"
        )


def damage_names(text: str) -> tuple[str, ...]:
    """--damage: comma-separated names of MALFORM's damages, at least one."""
    names = tuple(d.strip() for d in text.split(",") if d.strip())
    unknown = [d for d in names if d not in MALFORM]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown damage {unknown[0]!r} (known: {', '.join(MALFORM)})")
    if not names:
        raise argparse.ArgumentTypeError(f"give one or more of {', '.join(MALFORM)}")
    return names


def non_negative_seconds(text: str) -> float:
    """A finite number of seconds, 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be 0 or more seconds, not {text}")
    return value


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog="python -m sim.emulators.faulty_peer", description="A faulty peer: re-publishes damaged copies."
    )
    parser.add_argument("--display", type=display_name, default="default", help="display name (key prefix)")
    parser.add_argument("--mode", choices=MODES_AND_ALL, required=True, help="what to damage and how")
    parser.add_argument(
        "--rate",
        type=positive_number,
        default=PeerPlan.rate,
        help=f"damaged copies a second (default {PeerPlan.rate:g})",
    )
    parser.add_argument("--duration", type=positive_seconds, help="seconds of damage (default: until stopped)")
    parser.add_argument(
        "--start-after",
        type=non_negative_seconds,
        default=PeerPlan.start_after,
        help="seconds after the run's first clock tick before damage begins",
    )
    parser.add_argument(
        "--stale-after",
        type=non_negative_seconds,
        default=PeerPlan.stale_after,
        help=f"stale-cmd: seconds after a command is first heard before it may be re-sent "
        f"(default {PeerPlan.stale_after:g})",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument(
        "--include-sim", action="store_true", help="malformed-all, all: damage sim/truth and sim/contact too"
    )
    parser.add_argument(
        "--damage",
        type=damage_names,
        default=PeerPlan.damages,
        help=f"the malformed modes' damages, comma-separated (default {','.join(MALFORM)})",
    )
    add_seconds(parser, "--connect-wait", CONNECT_WAIT, "seconds to keep trying to reach the router")
    # zenoh: a client of the run's router (-m is not offered: --mode is the peer's)
    parser.add_argument(
        "-e",
        "--connect",
        type=zenoh_endpoint,
        action="append",
        required=True,
        metavar="ENDPOINT",
        help=ZENOH_HELP["--connect"],
    )
    parser.add_argument("--zenoh-config", metavar="FILE", help=ZENOH_HELP["--zenoh-config"])
    parser.add_argument("--multicast-scouting", action="store_true", help=ZENOH_HELP["--multicast-scouting"])
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    zenoh = {"multicast_scouting": args.multicast_scouting, "config_file": args.zenoh_config}
    settings = ZenohSettings(mode="client", connect=list(args.connect), **zenoh)
    chosen = ("mode", "rate", "duration", "start_after", "seed", "include_sim", "stale_after")
    plan = PeerPlan(**{name: getattr(args, name) for name in chosen}, damages=args.damage)
    peer = FaultyPeer(settings, args.display, plan, args.connect_wait)
    try:
        with stopped_by_signals() as stop:
            peer.run(stop, report=sys.stdout)
    except TransportError as err:
        print(f"faulty-peer: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
