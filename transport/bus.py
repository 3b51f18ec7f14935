"""The bus: a zenoh session with typed publishing, queued subscriptions, liveliness and faults.

A subscriber callback (on zenoh's threads) only decodes and queues, never blocks; the owner's loop drains
the queue. A pulled inbox's samples wait in zenoh's channels until the owner reads it. Decoding failures
are counted per inbox and never raise.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import os
import queue
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar, cast

import numpy as np
import zenoh

from .codec import (
    BEFORE_START,
    FRAME_OF,
    Command,
    DropCounter,
    Frame,
    Message,
    MessageT,
    Poses,
    RecordFilter,
    State,
    States,
    decode,
    decode_views,
)
from .faults import FaultPlan, FaultSpec
from .keys import Keys, cell_of, robots_of_ident
from .plausible import MISADDRESSED
from .session import ZenohSettings, open_session

PULL_CAPACITY = 100_000  # samples a pulled subscription holds before zenoh's thread waits for the owner
PULL_EVERY = 0.002  # s between looks of a wait on a pulled inbox
# s a process waits after its last put before closing its session (Bus.linger): zenoh has no flush
CLOSE_LINGER = 0.2
# leases a client waits, once its link to the router is back, before declaring its feeds again (renew_if_due)
RENEW_AFTER_LEASES = 2
T = TypeVar("T")  # what an inbox delivers: a message, or one robot's record of a frame (codec.Pose, ...)


def _drain(q: queue.SimpleQueue, limit: int | None = None) -> list:
    """Everything waiting in a queue (at most ``limit`` items), without blocking."""
    out: list = []
    while limit is None or len(out) < limit:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            break
    return out


class InjectedFault(Generic[T]):
    """An inbox's injected fault (``--faults``): each message dropped or delayed by a draw, and the
    delayed ones kept until they are due, on the wall clock or (lock-step) on the owner's tick clock."""

    def __init__(self, spec: FaultSpec, seed: str) -> None:
        self.spec = spec
        self._delayed: list[tuple[float, int, str, T]] = []  # by wall-clock release time
        self._held: list[tuple[float, int, str, T]] = []  # by release on the owner's tick clock
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._seed = zlib.crc32(seed.encode())
        self._rng: Any = None  # the random stream, made when first drawn from (admit)

    def admit(self, key: str, msgs: list[T], inbox: Inbox[T]) -> bool:
        """The fate of one delivery (a frame's records share it): dropped (counted ``fault``: False),
        queued in the inbox, or kept until its delay has passed."""
        import random  # here: a process without faults never needs it

        spec = self.spec
        stamp: float | None = getattr(msgs[0], "stamp", None) if msgs else None
        # A hello (tick BEFORE_START) is off the tick clock: held on it, it would wait for a tick that
        # waits for it, and every resend of it would meet the same fate.
        tick = getattr(msgs[0], "tick", -1) if msgs else -1
        on_ticks = inbox.sim_time is not None and stamp is not None and 0 <= tick != BEFORE_START
        with self._lock:
            # one stream, or on the tick clock a stream of this message alone (reproducible in lock-step)
            self._rng = self._rng or random.Random(self._seed)
            rng = random.Random(f"{self._seed}/{key}/{stamp!r}") if on_ticks else self._rng
            if rng.random() < spec.drop:
                inbox.drops["fault"] += 1
                return False
            delay = spec.delay + rng.random() * spec.jitter
            if delay <= 0.0:
                for m in msgs:
                    inbox._queue.put((key, m))
                return True
            if on_ticks and stamp is not None:  # on the owner's tick clock in lock-step, else on the wall clock
                heap, release = self._held, stamp + delay
            else:
                heap, release = self._delayed, time.monotonic() + delay
            for m in msgs:
                heapq.heappush(heap, (release, next(self._order), key, m))
        return True

    def release(self, sim_time: float | None, out: queue.SimpleQueue[tuple[str, T]]) -> None:
        """Queue the kept messages that are due."""
        if not self.waiting:
            return
        now = time.monotonic()
        with self._lock:
            ticks = -math.inf if sim_time is None else sim_time + 1e-9
            for heap, due in ((self._delayed, now), (self._held, ticks)):
                while heap and heap[0][0] <= due:
                    _, _, key, msg = heapq.heappop(heap)
                    out.put((key, msg))

    @property
    def waiting(self) -> bool:
        return bool(self._delayed or self._held)


class KeepRobots:
    """These robots' records (a host's own poses; dead robots' bodies for the coordinator)."""

    def __init__(self, robots: Iterable[int] | np.ndarray) -> None:
        # sorted(set()), not np.unique, which loads numpy.ma into a robot's process
        self.robots = {int(r) for r in robots}
        self.ids = np.array(sorted(self.robots), np.int64)

    def mask(self, records: np.ndarray) -> np.ndarray:
        return np.isin(records["robot"], self.ids)

    def keeps(self, view: Any) -> bool:
        return view.robot in self.robots


class Inbox(Generic[T]):
    """Messages of one subscription, decoded, filtered by faults, waiting for the owner's loop."""

    def __init__(self, expected: type[T], fault: FaultSpec, seed: str, only: np.ndarray | None, pulled: bool) -> None:
        """``expected``: a message kind, or a record view (codec.Pose, State, Command) whose frames arrive
        as their records (robots ``only``'s, if given). ``pulled``: decoded when read (see Bus.inbox)."""
        self.expected = expected
        self.frame: type[Frame] | None = FRAME_OF.get(cast(type, expected))
        # which records of the frames are kept (None: all); replaced whole, as zenoh's thread may read it
        self.keep: RecordFilter | None = None if only is None else KeepRobots(only)
        self.fault: InjectedFault[T] | None = InjectedFault(fault, seed) if fault.active else None
        self.drops = DropCounter()
        self.received = 0
        self.bytes = 0
        self._queue: queue.SimpleQueue[tuple[str, T]] = queue.SimpleQueue()
        # The owner's tick clock (s) in lock-step: an injected delay then counts from a message's stamp
        # and each draw is a function of the message, so a lock-step run with faults is reproducible.
        self.sim_time: float | None = None
        self.bell: threading.Event | None = None  # rung on every arrival: one wait serves several inboxes
        # robot -> the tick of its record that arrived last, whatever the faults did (None: not kept), for
        # a lock-step owner. The last, not the greatest: a tick forged from the future would otherwise stand.
        self.seen: dict[int, int] | None = None
        self.pulled = pulled
        self.channels: list[Feed] = []  # pulled: the subscriptions whose channels feed this inbox
        # told the tracker's records of other robots (tick, records), before ``keep`` picks (_records): where
        # the tracker sees the bodies (agent.neighbour_table.TrackedBodies)
        self.bodies: Callable[[int, np.ndarray], None] | None = None

    def _samples(self) -> Iterator[zenoh.Sample]:
        """Pulled: every sample waiting in the channels, taken on the caller's thread."""
        for feed in self.channels:
            while (sample := feed.declared.try_recv()) is not None:
                yield sample

    def _pull(self) -> None:
        """Pulled: take in every sample waiting in the channels."""
        for sample in self._samples():
            self._on_sample(sample)

    def _payload(self, sample: zenoh.Sample) -> bytes:
        """A sample's bytes, counted as received."""
        payload = sample.payload.to_bytes()
        self.received += 1
        self.bytes += len(payload)
        return payload

    def _records(self, payload: bytes, key: str) -> tuple[int, list] | None:
        """A frame's (tick, records ``keep`` keeps); None if malformed. ``bodies`` is told every record of
        a frame of several robots, and of a robot's own key the records after its own."""
        keep, alone = self.keep, Keys.robot_alone(key)
        frame = cast("type[Frame]", self.frame)
        if alone is not None:
            return self._alone(payload, frame, alone)
        if self.bodies is None:
            return decode_views(payload, frame, self.drops, keep)
        got = decode(payload, frame, self.drops)
        if got is None:
            return None
        self.bodies(got.tick, got.records)
        return got.tick, got.messages(keep)

    def _alone(self, payload: bytes, frame: type[Frame], robot: int) -> tuple[int, list] | None:
        """A frame on a key naming one robot: that robot's record first, or refused as misaddressed (a
        damaged robot id would make it another robot's); those after it are the bodies the tracker sees
        near the robot (Bus.publish_poses), for ``bodies`` only."""
        first = frame.views_first(payload)  # its record in one struct call
        if first is None:  # empty (no record of its robot), or malformed: decode counts why
            if decode(payload, frame, self.drops) is not None:
                self.drops[MISADDRESSED] += 1
            return None
        tick, views, rest = first
        if views[0].robot != robot:
            self.drops[MISADDRESSED] += 1
            return None
        if rest is not None and self.bodies is not None:
            self.bodies(tick, rest)
        return tick, views if self.keep is None or self.keep.keeps(views[0]) else []

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload, key = self._payload(sample), str(sample.key_expr)
        if self.frame is None:
            if (msg := decode(payload, cast("type[Message]", self.expected), self.drops)) is not None:
                self._deliver(key, [cast(T, msg)])
        elif (got := self._records(payload, key)) is not None:
            try:
                if got[1]:  # none of ours (a frame of others' records): nothing to queue or wake the owner for
                    self._deliver(key, got[1])
            finally:  # after the records are queued, held or dropped: whoever waits on seen finds them
                self._saw(*got)

    def _saw(self, tick: int, views: list) -> None:
        """Note the tick of these records as their robots' last seen (hellos are not ticks)."""
        if self.seen is not None and tick != BEFORE_START:
            for v in views:
                self.seen[v.robot] = tick

    def _deliver(self, key: str, msgs: list[T]) -> None:
        if self.fault is None:
            for m in msgs:
                self._queue.put((key, m))
        elif not self.fault.admit(key, msgs, self):
            return  # dropped: nothing to wake the owner for
        # Rung for held messages too, to release them in time; a pulled inbox's owner is awake already.
        if self.bell is not None and not self.pulled:
            self.bell.set()

    def _collect(self) -> None:
        """Take in what waits in the channels (pulled) and the held messages now due."""
        self._pull()
        if self.fault is not None:
            self.fault.release(self.sim_time, self._queue)

    @property
    def has_delayed(self) -> bool:
        """Messages held back by an injected delay (their owner must poll until they are due)."""
        return self.fault is not None and self.fault.waiting

    def drain(self) -> list[tuple[str, T]]:
        """Every message that has arrived (and whose injected delay has passed), oldest first."""
        self._collect()
        return _drain(self._queue)

    def take(self) -> list[T]:
        """drain() without the keys. A pulled inbox of frames without faults hands the records straight
        from zenoh's channels (noted ``seen``), on the owner's hot path: no queue between."""
        direct = self.pulled and self.frame is not None and self.fault is None
        if not direct or not self._queue.empty():
            return [m for _, m in self.drain()]
        out: list[T] = []
        for sample in self._samples():
            if (got := self._records(self._payload(sample), str(sample.key_expr))) is not None:
                out += got[1]
                self._saw(*got)
        return out

    def get(self, timeout: float) -> tuple[str, T] | None:
        """Wait up to ``timeout`` s for one message (None if none came)."""
        deadline = time.monotonic() + timeout
        while True:
            self._collect()
            with contextlib.suppress(queue.Empty):
                return self._queue.get_nowait()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            # a pulled inbox or held messages: look again soon, as nothing rings the queue for them
            wait = min(PULL_EVERY if self.pulled else 0.005 if self.has_delayed else remaining, remaining)
            with contextlib.suppress(queue.Empty):
                return self._queue.get(timeout=wait)


class Feed:
    """One declaration of a bus (subscriber, liveliness subscriber, queryable) that Bus.renew can redo."""

    def __init__(self, declare: Callable[[], Any]) -> None:
        self._declare = declare
        self.declared = declare()

    def renew(self) -> None:
        """The new declaration first, so nothing is missed; what both deliver comes twice, as a replay."""
        old, self.declared = self.declared, self._declare()
        old.undeclare()


class RawInbox:
    """Raw samples (key, bytes, wall time) for the recorder, which logs what crossed the bus."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[tuple[str, bytes, float]] = queue.SimpleQueue()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._queue.put((str(sample.key_expr), sample.payload.to_bytes(), time.time()))

    def drain(self, limit: int = 1_000_000) -> list[tuple[str, bytes, float]]:
        return _drain(self._queue, limit)


def alive_parts(key: str) -> list[str]:
    """A liveliness token's role, ident and incarnation (Keys.alive), as the parts of its key."""
    return key.split("/alive/", 1)[-1].split("/")


class LivelinessWatch:
    """Liveliness tokens (those already there too) as (role, ident, alive, wall time, incarnation) events.
    An incarnation is one process's life (Bus.incarnation): a token back under a new one is a restart, under
    the same one a blip. A new incarnation before the old token is gone counts as the old one's death; if the
    new one's token goes first (a forged one, or a restart that died), the old one that still stands lives again."""

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[tuple[str, str, bool, float, str]] = queue.SimpleQueue()
        self._live: dict[tuple[str, str], list[str]] = {}  # (role, ident) -> its standing incarnations, the live last
        self._lock = threading.Lock()
        # robot -> the first robot of the agent whose token names it newest: the id its command frames are keyed by
        self.sender: dict[int, int] = {}

    def _on_sample(self, sample: zenoh.Sample) -> None:
        parts = alive_parts(str(sample.key_expr))
        if len(parts) < 2:
            return
        role, incarnation, alive = parts[0], "/".join(parts[2:]), sample.kind == zenoh.SampleKind.PUT
        robots = robots_of_ident(parts[1]) if role == "agent" else None
        idents = [parts[1]] if robots is None else [str(r) for r in robots]  # a host's token: each robot's event
        now = time.time()
        with self._lock:
            if robots and alive:
                self.sender.update(dict.fromkeys(robots, min(robots)))
            for ident in idents:
                self._take((role, ident), incarnation, alive, now)

    def _take(self, who: tuple[str, str], incarnation: str, alive: bool, now: float) -> None:
        lives = self._live.pop(who, [])
        live = lives[-1] if lives else None
        if incarnation in lives:
            lives.remove(incarnation)
        if alive:
            lives.append(incarnation)
            if live is not None and live != incarnation:
                self._queue.put((*who, False, now, live))
        if lives:
            self._live[who] = lives
        if not alive and live != incarnation:
            return  # a replaced incarnation's token ended (or one never heard)
        self._queue.put((*who, alive, now, incarnation))
        if not alive and lives:
            self._queue.put((*who, True, now, lives[-1]))

    def drain(self) -> list[tuple[str, str, bool, float, str]]:
        return _drain(self._queue)


@dataclass
class Sent:
    """What a bus has put: messages and bytes per kind, and when it last put (Bus.linger)."""

    messages: Counter[str] = field(default_factory=Counter)
    bytes: Counter[str] = field(default_factory=Counter)
    last: float = -math.inf  # time.monotonic() of the last put


class Bus:
    """One participant's connection to the swarm: publish typed messages, subscribe to inboxes; what it
    declared is kept with the link's state, as a renewal declares it all again. It holds more than 15
    attributes for that state: whether the link to the router is lost, when to renew, and how often it came back
    (a host's clock starts again) and was renewed."""

    def __init__(
        self,
        settings: ZenohSettings,
        display: str = "default",
        *,
        faults: FaultPlan | None = None,
        seed: int = 0,
        name: str = "",
        hears_itself: bool = True,
    ) -> None:
        """``hears_itself``: what this session puts reaches its own subscriptions too (off for a robot alone)."""
        self.keys = Keys(display)
        self._destination = zenoh.Locality.ANY if hears_itself else zenoh.Locality.REMOTE
        self.settings = settings
        self.faults = dict(faults or {})
        self._seeds = (f"{seed}/{name}/{n}" for n in itertools.count(1))  # an inbox's faults draw from its own
        self.sent = Sent()
        self._tokens: list[Any] = []
        self.incarnation = os.urandom(4).hex()  # this process's life: a token back under another is a restart
        self._subscriptions: list[Feed] = []
        self._pulled: list[Inbox[Any]] = []
        self.session = open_session(settings)
        self.renewals = 0  # times the link to the router came back and every feed was declared again
        self.link_returns = 0  # times the link to the router came back: what was sent meanwhile never reached us
        self._link_lost = False
        self._renew_at: float | None = None  # time.monotonic() at which to renew (renew_if_due)
        if settings.mode == "client":
            # held: the listener lives as long as this object
            self._link = self.session.info.declare_transport_events_listener(self._on_link, history=False)

    def publish(self, key: str, msg: Message) -> None:
        self.put(key, msg.encode(), msg.NAME)

    def publish_poses(
        self, tick: int, stamp: float, robots: np.ndarray, poses: np.ndarray, frame: bool,
        near: list[np.ndarray] | None = None,
    ) -> None:  # fmt: skip
        """A tick's poses (x, y, theta rows): one frame for agent hosts (``frame``), else one per robot's key,
        its record first, then those of the bodies near it (``near[i]``: their rows), for its agent's safety."""
        records = Poses.records_of(robots, np.asarray(poses, float).reshape(-1, 3))
        if frame:
            self.publish(self.keys.poses, Poses(tick, stamp, records))
            return
        for i in range(len(records)):
            rows = [i] if near is None else [i, *near[i].tolist()]
            self.publish(self.keys.pose(int(records["robot"][i])), Poses(tick, stamp, records[rows]))

    def publish_states(self, tick: int, stamp: float, states: list[State], cell_size: float, first: int | None) -> None:
        """Broadcast states of a tick: one frame on ``state/<first>`` that every agent host hears
        (``first``: the sender's first robot), else each robot's frame of one under its spatial cell."""
        cell_key = lambda s: self.keys.state(cell_of(s.x, s.y, cell_size), s.robot)
        self.publish_frame(States, tick, stamp, states, cell_key if first is None else self.keys.states(first))

    def publish_frame(
        self, frame: type[Frame], tick: int, stamp: float, views: list, key: str | Callable[[Any], str]
    ) -> None:
        """A tick's records as one frame on ``key``, or (``key`` a function of a record) each its frame of one."""
        if isinstance(key, str):
            self.publish(key, frame.of(tick, stamp, views))
            return
        for v in views:
            self.put(key(v), frame.encode_one(v), frame.NAME)

    def put(self, key: str, payload: bytes, kind: str = "raw") -> None:
        # BLOCK, not DROP: in lock-step runs a silently dropped message would break reproducibility.
        self.session.put(
            key, payload, congestion_control=zenoh.CongestionControl.BLOCK, allowed_destination=self._destination
        )
        self.sent.last = time.monotonic()
        self.sent.messages[kind] += 1
        self.sent.bytes[kind] += len(payload)

    def inbox(self, expected: type[T], only: np.ndarray | None = None, *, pulled: bool = False) -> Inbox[T]:
        """An empty inbox of ``expected`` with its kind's faults, for ``subscribe_into``. ``pulled``: decoded
        when read (once a tick), so no thread wakes per sample to contend for the GIL; the owner polls."""
        fault = self.faults.get(getattr(expected, "NAME", ""), FaultSpec())  # a kind's or a view's (its frame's)
        inbox = Inbox(expected, fault, next(self._seeds), only, pulled)
        if pulled:
            self._pulled.append(inbox)
        return inbox

    def commands_inbox(self) -> Inbox[Command]:
        """Every robot's commands, one record at a time: what a body process reads."""
        return self.subscribe(self.keys.all_of("cmd"), Command)

    def subscribe(
        self, keyexpr: str, expected: type[T], only: np.ndarray | None = None, *, pulled: bool = False
    ) -> Inbox[T]:
        """An inbox of decoded messages (or frames' records, robots ``only``'s) from one key expression."""
        inbox = self.inbox(expected, only, pulled=pulled)
        self.subscribe_into(keyexpr, inbox)
        return inbox

    def subscribe_into(self, keyexpr: str, inbox: Inbox[Any]) -> Feed:
        """Add another key expression feeding an existing inbox; returns the feed to unsubscribe."""
        if not inbox.pulled:
            return self._feed(lambda: self.session.declare_subscriber(keyexpr, inbox._on_sample))
        feed = self._feed(lambda: self.session.declare_subscriber(keyexpr, zenoh.handlers.FifoChannel(PULL_CAPACITY)))
        inbox.channels.append(feed)
        return feed

    def _feed(self, declare: Callable[[], Any]) -> Feed:
        feed = Feed(declare)
        self._subscriptions.append(feed)
        return feed

    def unsubscribe(self, subscriber: Feed) -> None:
        for inbox in self._pulled:
            if subscriber in inbox.channels:
                inbox._pull()  # what it already holds was received: keep it
                inbox.channels.remove(subscriber)
        subscriber.declared.undeclare()
        if subscriber in self._subscriptions:
            self._subscriptions.remove(subscriber)

    def subscribe_raw(self, keyexpr: str) -> RawInbox:
        inbox = RawInbox()
        self._feed(lambda: self.session.declare_subscriber(keyexpr, inbox._on_sample))
        return inbox

    def declare_alive(self, role: str, ident: int | str) -> Any:
        token = self.session.liveliness().declare_token(self.keys.alive(role, ident, self.incarnation))
        self._tokens.append(token)
        return token

    def alive_now(self, timeout: float = 2.0) -> list[tuple[str, str]]:
        """(role, ident) of every process alive on this display now, by its liveliness token."""
        replies = self.session.liveliness().get(self.keys.alive_all(), timeout=timeout)
        found = (getattr(reply, "ok", None) for reply in replies)
        parts = [alive_parts(str(ok.key_expr)) for ok in found if ok is not None]
        return sorted((p[0], p[1]) for p in parts if len(p) >= 2)

    def watch_alive(self, role: str | None = None) -> LivelinessWatch:
        watch = LivelinessWatch()
        keyexpr = self.keys.alive_all(role)
        self._feed(
            lambda: self.session.liveliness().declare_subscriber(keyexpr, history=True, handler=watch._on_sample)
        )
        return watch

    def serve(self, keyexpr: str, answer: Callable[[], list[tuple[str, bytes]]]) -> Any:
        def handler(query: zenoh.Query) -> None:
            for key, payload in answer():
                query.reply(key, payload)

        return self._feed(lambda: self.session.declare_queryable(keyexpr, handler))

    def query(self, keyexpr: str, expected: type[MessageT], timeout: float = 2.0) -> list[tuple[str, MessageT]]:
        got = [(key, decode(payload, expected)) for key, payload in self.query_raw([keyexpr], timeout)]
        return [(key, msg) for key, msg in got if msg is not None]

    def query_raw(self, keyexprs: list[str], timeout: float = 2.0) -> list[tuple[str, bytes]]:
        """Every answer to these queries, all in flight at once: (key, payload bytes)."""
        pending = [self.session.get(keyexpr, timeout=timeout) for keyexpr in keyexprs]
        answers = (getattr(reply, "ok", None) for replies in pending for reply in replies)
        return [(str(ok.key_expr), ok.payload.to_bytes()) for ok in answers if ok is not None]

    def _on_link(self, event: Any) -> None:
        """zenoh's thread: the client's link to its router went (DELETE) or came (PUT). Only notes it."""
        if event.kind == zenoh.SampleKind.DELETE:
            self._link_lost = True
        elif self._link_lost:
            self._link_lost = False
            self.link_returns += 1
            self._renew_at = time.monotonic() + self.renew_delay

    @property
    def renew_delay(self) -> float:
        """Seconds from the link's return to the renewal."""
        return RENEW_AFTER_LEASES * self.settings.lease_ms / 1000

    def renew_if_due(self) -> bool:
        """Declare every feed again a while after the link to the router came back (old ones may go quiet)."""
        if self._renew_at is None or time.monotonic() < self._renew_at:
            return False
        self.renew()
        return True

    def renew(self) -> None:
        """Declare every feed again, now (renew_if_due)."""
        self._renew_at = None
        for inbox in self._pulled:
            inbox._pull()  # what the old channels hold was received: keep it
        for feed in self._subscriptions:
            feed.renew()
        self.renewals += 1

    def linger(self) -> None:
        """Before closing: give zenoh's sending thread CLOSE_LINGER since the last put to send what it holds."""
        time.sleep(max(0.0, self.sent.last + CLOSE_LINGER - time.monotonic()))

    def close(self) -> None:
        for token in self._tokens:
            with contextlib.suppress(Exception):
                token.undeclare()
        self._tokens.clear()
        with contextlib.suppress(Exception):
            self.session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
