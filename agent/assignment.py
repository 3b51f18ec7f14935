"""The goal auction on the bus: binds the pure participant (core/bidder.py) of a host's robots to zenoh, one message
per host. Real time publishes on news (throttled: QUIET, DIGEST_EVERY) with a resend backstop; lock-step plays
numbered rounds, bid for bid the central engine's, so every host adopts a block at the same tick (settle_block)."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from transport.bus import Bus, Inbox
from transport.codec import Bid, Boards, Goals
from transport.plausible import INCONSISTENT

from .core.bidder import RELEASED, Participant
from .core.local_auction import NO_OWNER, LocalAuction, Words, new_auction
from .core.params import RobotParams
from .core.rounds import BlockRounds

DIGEST_EVERY = 0.01
QUIET = 0.02  # digest-only news waits until the board has not changed for this long (no storms)
RESEND_BUSY = 0.25  # a lost message stalls a phase until a resend: short while an instance is open
RESEND_PER_ROBOT = 0.01  # ... but every resend reaches every host: the backstop grows with the swarm
RESEND_IDLE = 1.0
MAX_LEAD = 15.0  # s: the longest latency the robots' bid positions compensate (agent.runtime.bid_position)
ROUND_RESEND = 0.1  # s: lock-step, the least a host waits for a round's records before resending (_resend_base)
ROUND_BACKOFF = 8  # a round's resends space out to at most this many times the first interval
ROUND_CAP = 30.0  # s: lock-step, the longest a host waits for one round; then its robots hold their positions

OnAgreed = Callable[[int, int, dict[int, int], np.ndarray, np.ndarray], None]
OnAbandoned = Callable[[list[int]], None]
Where = Callable[[], dict[int, np.ndarray]]


@dataclass
class AuctionCounts:
    """What a host's auction did, for its statistics (AuctionLink.stats)."""

    sent: int = 0  # messages
    received: int = 0
    agreements: int = 0
    penalties: int = 0  # deadlock penalties charged (paper 5.5.5)
    rounds: int = 0  # lock-step rounds taken part in
    abandoned: int = 0  # lock-step blocks given up (a round never completed)
    dropped: int = 0  # lock-step blocks dropped unagreed at block_max_age
    first_agreement_s: list[float] = field(default_factory=list)  # per goal set: wall time from its arrival


@dataclass(frozen=True)
class LockStepRounds:
    """What the tick-synchronous rounds need of a host beside the auction itself."""

    on_abandoned: OnAbandoned | None = None  # own robots whose block could not finish: they hold their positions
    dead: Callable[[], set[int]] = set  # robots not waited for: dead now, or not in the goal set's life (Departures)
    reach: float = math.inf  # m: a robot hears the auction only from robots this close (core.local_auction)
    # a round of this epoch is not worth waiting for any more (AgentHost.round_moot); by default never
    moot: Callable[[int], bool] = lambda epoch: False  # noqa: E731


REAL_TIME = LockStepRounds()  # what a real-time auction takes of the rounds' settings: their defaults


class RoundExchange:
    """Lock-step: a host's side of the auction's rounds: ours kept to resend, the others' filed by round (``keeps``)."""

    def __init__(
        self, bus: Bus, robots: list[int], inbox: Inbox[Any], counts: AuctionCounts, keeps: Callable[[Any], bool]
    ) -> None:
        self.bus, self.robots, self.sender, self.inbox, self.counts = bus, robots, robots[0], inbox, counts
        self.keeps = keeps
        self.rounds = REAL_TIME  # who is not waited for, and when a round is moot (AuctionLink's lockstep)
        self.records: dict[tuple[int, int, int], dict[int, Any]] = {}  # round -> sender -> its message
        self.said: dict[tuple[int, int, int], tuple[Bid | Boards, float]] = {}  # our rounds' messages, when last sent
        self.said_block: tuple[int, int] | None = None  # (epoch, block) of the newest round in ``said``
        self.waiting_for: tuple[int, int, int] | None = None  # the round we wait in
        self.newest_round: dict[tuple[int, int, int], int] = {}  # (epoch, block, sender) -> its latest round heard
        self.stopped = False  # the host is shutting down: stop waiting for rounds

    def open(self, key: tuple[int, int, int], msg: Bid | Boards, speak: bool) -> None:
        """Say our message of round ``key`` (epoch, block's final instance, round); not ``speak``: only as a resend."""
        self.records = {k: heard for k, heard in self.records.items() if k >= key}
        if key[:2] != self.said_block:  # a block's first round: forget the blocks before the last
            last, self.said_block = self.said_block, key[:2]
            # the last block's stay: a host that lost one of its final round still waits for it
            self.said = {k: said for k, said in self.said.items() if k[:2] in (key[:2], last) or k >= key}
            self.newest_round = {b: n for b, n in self.newest_round.items() if b[:2] >= key[:2] or b[:2] == last}
        self.said[key] = (msg, time.monotonic())
        self.waiting_for = key  # an open round is no round we left: its messages draw no answer (file)
        if speak:
            self.send(key)

    def close(
        self, key: tuple[int, int, int], members: set[int], robots_of: Callable[[Any], np.ndarray], base: float
    ) -> dict[int, Any] | None:
        """Wait for every live robot in ``members``'s word in round ``key``: messages by sender (None: timed out)."""
        # every resend reaches every host and may draw an answer from each: back off so as not to feed the load
        wait, start = base, time.monotonic()
        said: set[int] = set(self.robots)  # robots heard in this round
        counted: set[int] = set()  # the senders whose robots are in ``said``
        try:
            while not self.stopped:
                self.file(self.inbox.drain())
                heard = self.records.get(key, {})
                for sender in heard.keys() - counted:  # a resent message names the same robots
                    said.update(robots_of(heard[sender]).tolist())
                    counted.add(sender)
                if members <= said | self.rounds.dead():
                    return heard
                if self.rounds.moot(key[0]):
                    return None
                now = time.monotonic()
                if now - start >= ROUND_CAP:
                    return None
                if now - max(self.said[key][1], start) >= wait:
                    wait = min(2 * wait, ROUND_BACKOFF * base)
                    self.send(key)
                due = min(max(self.said[key][1], start) + wait, start + ROUND_CAP)
                got = self.inbox.get(timeout=max(0.0, due - time.monotonic()))
                self.file([got] if got is not None else [])
            return None
        finally:
            self.waiting_for = None

    def say(self, key: tuple[int, int, int], msg: Bid | Boards) -> None:
        """Our last message of a block: sent once, and again to whoever asks for it (file)."""
        self.said[key] = (msg, -np.inf)
        self.send(key)

    def file(self, arrived: list) -> None:
        """Keep other hosts' messages (those ``keeps`` takes) by round."""
        for _, msg in arrived:
            self.counts.received += 1
            if msg.sender == self.sender or not self.keeps(msg):
                continue
            key = (msg.epoch, msg.instance, msg.serial)
            self.records.setdefault(key, {})[msg.sender] = msg
            # answer a sender still waiting in a round we left, unless heard in a later round (no ping-pong)
            block = (msg.epoch, msg.instance, msg.sender)
            self.newest_round[block] = newest = max(self.newest_round.get(block, 0), msg.serial)
            answer = key in self.said and key != self.waiting_for and newest == msg.serial
            if answer and time.monotonic() - self.said[key][1] >= ROUND_RESEND:
                self.send(key)

    def weed(self) -> None:
        """Drop the filed messages ``keeps`` no longer takes (a new goal set tells what fits it)."""
        for heard in self.records.values():
            for sender in [s for s, msg in heard.items() if not self.keeps(msg)]:
                del heard[sender]

    def send(self, key: tuple[int, int, int]) -> None:
        """Publish (again) our message of this round."""
        msg, _ = self.said[key]
        keys = self.bus.keys
        self.bus.publish((keys.boards if isinstance(msg, Boards) else keys.auction)(msg.epoch, self.sender), msg)
        self.said[key] = (msg, time.monotonic())
        self.counts.sent += 1


@dataclass
class Publishing:
    """Real time: when a host publishes its auction message and what it knows of the others' boards."""

    serial: int = 0  # our messages so far
    last_sent: float = -math.inf  # monotonic time of our last message
    instance_stamp: float = -math.inf  # display time the current instance started
    board_changed: float = 0.0  # monotonic time of the last change of the board
    mismatch: bool = False  # a message of this instance came from a host with another board


@dataclass
class Blocks:
    """Lock-step: the block of phases under way, which may span ticks."""

    stamp: float = -math.inf  # display time of the last block's tick
    block: BlockRounds | None = None
    # rounds per tick bounded: the round said at the last tick, heard at this one
    open_round: tuple[BlockRounds, tuple[int, int, int], set[int], float] | None = None
    warm: bool = False  # the goal set's auction began from the coordinator's warm start


@dataclass
class AuctionTimes:
    """When things happened, for the auction's latency (the robots' bid positions compensate it) and statistics."""

    now: float = 0.0  # display time of the last tick
    frozen_at: dict[int, float] = field(default_factory=dict)  # block of instances -> display time its positions froze
    latency: float = 0.0  # display seconds from freezing a block's positions to adopting its agreement
    epoch_wall: float = 0.0  # monotonic time the goal set under way arrived


class AuctionLink:
    """The auction of one host's robots: goal sets in, agreed goals out through ``on_agreed``. ``where``: the robots'
    bid positions now (asked again before a block freezes them); ``lockstep``: the rounds (None: real time)."""

    def __init__(
        self,
        bus: Bus,
        robots: list[int],
        params: RobotParams,
        on_agreed: OnAgreed,
        where: Where | None = None,
        lockstep: LockStepRounds | None = None,
    ) -> None:
        self.bus, self.robots, self.params, self.on_agreed = bus, sorted(robots), params, on_agreed
        self.where, self.rounds = where, lockstep
        self.counts = AuctionCounts()
        # Lock-step reads the others' messages only within its rounds: they wait in zenoh's channel (pulled)
        kind, key = (Boards, "boards") if math.isfinite(self.reach) else (Bid, "auction")
        inbox: Inbox[Any] = bus.subscribe(bus.keys.all_of(key), kind, pulled=self.lockstep)
        self.exchange = RoundExchange(bus, self.robots, inbox, self.counts, self._keeps)
        self.exchange.rounds = lockstep or REAL_TIME
        self.part: Participant | None = None
        self.local: LocalAuction | None = None  # the range-limited auction, in place of part
        self.goal_set: Goals | None = None
        self.reported = -1  # the last agreed instance handed to on_agreed
        self.publishing, self.blocks, self.times = Publishing(), Blocks(), AuctionTimes()

    @property
    def lockstep(self) -> bool:
        """The rounds are tick-synchronous (False: real time)."""
        return self.rounds is not None

    @property
    def sender(self) -> int:
        """The host's name in the auction: its first robot."""
        return self.robots[0]

    @property
    def inbox(self) -> Inbox[Any]:
        """The others' auction messages (the exchange files them in lock-step)."""
        return self.exchange.inbox

    @property
    def reach(self) -> float:
        """m: a robot hears the auction only from robots this close (inf: from all)."""
        return (self.rounds or REAL_TIME).reach

    @property
    def active(self) -> bool:
        return self.part is not None or self.local is not None

    @property
    def _auction(self) -> Participant | LocalAuction | None:
        """The auction under way: the range-limited one, else the participant (None: none yet)."""
        return self.local if self.local is not None else self.part

    @property
    def cold(self) -> bool:
        """The goal set's auction has not agreed yet (its robots have no goal of it, unless carried)."""
        return self._auction is not None and self._auction.agreed_instance < 0

    @property
    def busy(self) -> bool:
        """An instance is open between ticks (real time: lock-step plays its rounds within the tick)."""
        return self.part is not None and not self.part.is_agreed and not self.lockstep

    @property
    def epoch(self) -> int:
        """The goal set of the current auction (0: none yet)."""
        return self._auction.epoch if self._auction is not None else 0

    def idle_robots(self) -> list[int]:
        own = set(self._auction.own) if self._auction is not None else set()
        return [r for r in self.robots if r not in own]

    def on_goals(
        self, goals: Goals, positions: dict[int, np.ndarray], current: dict[int, int] | None = None
    ) -> dict[int, int]:
        """A new goal set: a new auction. Returns the goals the robots carry over from their ``current`` ones to drive
        to until it agrees: by the sets' matching (_warm_start), else a keyframe's correspondence."""
        if self.active and goals.epoch <= self.epoch:
            return {}
        auction = new_auction(goals.epoch, goals.positions, goals.robots.tolist(), self.robots, self.params, self.reach)
        self.goal_set, self.times.epoch_wall, self.reported = goals, time.monotonic(), -1
        self.blocks.block = self.blocks.open_round = None  # a block of the last goal set is given up
        if isinstance(auction, LocalAuction):  # lock-step only: a cold start at the next tick
            self.local, self.blocks.stamp = auction, -np.inf
            return {}
        before, self.part = self.part, auction
        warm, keyframe = goals.warm_start, goals.correspondence
        if self.lockstep:  # the block begins at the next tick, as the central engine starts a new image
            self.blocks.stamp = -np.inf
            self.exchange.weed()  # bids filed before the set came: _keeps checks them now
            # with rounds per tick bounded, from the warm start: a cold one would span many ticks
            first = self._first_warm_start(goals)
            self.blocks.warm = bool(self.params.rounds_per_tick) and (
                first or (before is not None and self._warm_start(before, goals))
            )
            if self.blocks.warm and warm is not None and first:
                return self.part.start_from(goals.robots[warm.matched], warm.prices)
            if self.blocks.warm and before is not None and warm is not None:
                return self.part.carry(before, warm.matched, current=current, prices=warm.prices)
            return {}
        carried = {}
        if before is not None and warm is not None and self._warm_start(before, goals):
            carried = self.part.carry(before, warm.matched, current=current, prices=warm.prices)
        elif keyframe is not None and before is not None and before.epoch == keyframe.follows:
            close = before.agreed_instance >= 0 and frames_close(before.goals, goals.positions, keyframe.previous)
            carried = self.part.carry(before, keyframe.previous, claim=close, current=current)
        self._try_start(positions)
        return carried

    @staticmethod
    def _warm_start(before: Participant, goals: Goals) -> bool:
        """Whether the auction starts warm from the coordinator's WarmStart: the same robots, a last set held alike."""
        return (
            before.common_owner is not None
            and not goals.per_robot
            and goals.warm_start is not None
            and goals.warm_start.matched_from == before.epoch
            and len(before.goals) == len(goals.positions)
            and np.array_equal(before.robots, np.sort(np.asarray(goals.robots, np.int64)))
        )

    @staticmethod
    def _first_warm_start(goals: Goals) -> bool:
        """The run's first goal set, warm-started from where its robots start (WarmStart.matched_from 0)."""
        warm = goals.warm_start
        return warm is not None and warm.matched_from == 0 and not goals.per_robot and len(goals.robots) == goals.count

    def _try_start(self, positions: dict[int, np.ndarray]) -> bool:
        part = self.part
        if part is None or part.started:
            return part is not None
        if not all(r in positions for r in part.own):
            return False
        self._begin(0, positions)
        self._publish()
        return True

    def _begin(self, instance: int, positions: dict[int, np.ndarray]) -> None:
        """Begin an instance (a later one proves ours agreed: the robots take it first), noting when a block froze."""
        part, _ = self._under_way()
        if part.started and not part.is_agreed and instance > part.instance:
            part.adopt_if_settled()
        if self._report() and self.where is not None:
            positions = self.where()
        part.begin(instance, positions)
        block = part.instance // part.phases
        if block not in self.times.frozen_at:
            self.times.frozen_at[block] = self.times.now
            self.times.frozen_at = {b: t for b, t in self.times.frozen_at.items() if b >= block - 4}

    def on_tick(self, stamp: float, positions: dict[int, np.ndarray]) -> None:
        """Each control iteration: start the next instance once the last is agreed (5.1: re-assign every iteration)."""
        self.times.now = max(self.times.now, stamp)
        if self.lockstep:
            self.settle_block(stamp, positions)
            return
        if not self._try_start(positions):
            return
        part, _ = self._under_way()
        if part.is_agreed and stamp - self.publishing.instance_stamp >= self.params.assign_period - 1e-9:
            self.publishing.instance_stamp = stamp
            self._begin(part.instance + 1, positions)
            self._settle()
            self._publish()

    def step(self, sensed: Any) -> None:
        """This tick's step from the robots' bid positions (``where``): on_tick."""
        self.on_tick(sensed.stamp, self.where() if self.where is not None else {})

    def settled_beside(self) -> bool:
        return False  # the bus's rounds are played within the step

    def penalise(self, robot: int, epoch: int, goal: int) -> None:
        auction = self._auction
        if auction is not None and epoch == auction.epoch:
            auction.penalise(robot, goal, self.params.deadlock_cost)
            self.counts.penalties += 1

    def next_due(self) -> float:
        """Seconds until something is due without a message arriving (a resend, a digest, a delay ending)."""
        part = self.part
        if part is None or not part.started or self.lockstep:
            return 1.0
        if self.inbox.has_delayed:
            return 0.005
        busy = max(RESEND_BUSY, RESEND_PER_ROBOT * len(part.robots))
        due = self.publishing.last_sent + (RESEND_IDLE if part.is_agreed else busy)
        if part.claims_changed:
            return 0.0
        if (part.has_news or self.publishing.mismatch) and part.view_complete():
            due = min(due, max(self.publishing.last_sent + DIGEST_EVERY, self.publishing.board_changed + QUIET))
        return max(0.0, due - time.monotonic())

    def poll(self, positions: dict[int, np.ndarray]) -> None:
        """Take in what arrived, bid, check agreement, publish what others need."""
        part = self.part
        arrived = self.inbox.drain()
        if self.lockstep:  # kept for the rounds of the next block (settle_block)
            self.exchange.file(arrived)
            return
        if not arrived and part is not None and part.started and self.next_due() > 0:
            return  # nothing new, nothing due
        theirs: set[int] = set()  # digests of this instance's messages, compared once below
        for _, msg in arrived:
            self.counts.received += 1
            if part is None or msg.epoch != part.epoch or not self._keeps(msg) or not self._try_start(positions):
                continue
            if msg.instance > part.instance:  # the sender saw our instance agreed
                self._begin(msg.instance, positions)
            if part.absorb(msg.instance, msg.serial, msg.digest, part.members_only(msg.records)):
                self.publishing.board_changed = time.monotonic()
            if msg.instance == part.instance:
                theirs.add(msg.digest)
        if part is None or not part.started:
            return
        self.publishing.mismatch |= bool(theirs - {part.board.digest()})
        self._settle()
        if part.claims_changed:
            self.publishing.board_changed = time.monotonic()
        if self.next_due() <= 0:
            self._publish()

    def settle_block(self, stamp: float, positions: dict[int, np.ndarray]) -> None:
        """Lock-step, each tick: every ``assign_period`` a block frozen on this tick's positions, agreed at the same
        tick by every host (with rounds per tick bounded, a tick's last round is heard at the next)."""
        if self.local is not None:
            self._settle_local(stamp, positions)
            return
        part = self.part
        if part is None or not part.own:
            return
        if self.blocks.open_round is not None and self._close_round(*self.blocks.open_round):
            return  # given up
        if self.blocks.block is not None and self.params.stale_block(stamp - self.blocks.stamp):
            # dropped unagreed: the robots keep the last agreement, and the next block begins now
            self.blocks.block, self.counts.dropped = None, self.counts.dropped + 1
        if self.blocks.block is None:
            if not all(r in positions for r in part.own):
                return
            if part.started and stamp - self.blocks.stamp < self.params.assign_period - 1e-9:
                return
            self.blocks.stamp = stamp
            self.blocks.block = BlockRounds(part, positions)
        # the most rounds a tick gives a block: ``rounds_per_tick``, or all it needs (a cold start too)
        cold = part.agreed_instance < 0 and not self.blocks.warm
        budget = self.params.rounds_per_tick if self.params.rounds_per_tick and not cold else sys.maxsize
        for played in range(1, budget + 1):
            opened = self._open_round(self.blocks.block)
            if played == budget:  # heard at the next tick (budget is bounded)
                self.blocks.open_round = opened
                return
            if self._close_round(*opened) or self.blocks.block is None:
                return

    def _open_round(self, block: BlockRounds) -> tuple[BlockRounds, tuple[int, int, int], set[int], float]:
        """Say our robots' bids of the block's next round (quiet robots are not waited for); the round to close."""
        part = block.part
        quiet = block.quiet(part.robots)
        members = set(part.robots[~quiet].tolist())
        speak = not quiet[part.own_rows].all()
        news = block.say()
        key = (part.epoch, block.final, block.round)
        said = Bid(part.epoch, block.final, self.sender, block.round, part.board.digest(), len(news), news)
        self.exchange.open(key, said, speak)
        return block, key, members, self._resend_base(len(members))

    def _close_round(self, block: BlockRounds, key: tuple[int, int, int], members: set[int], base: float) -> bool:
        """Wait for the other hosts' records of an open round and merge them; True: given up."""
        self.blocks.open_round = None
        heard = self.exchange.close(key, members, lambda m: block.robots_of(m.sender, m.records), base)
        if heard is None:
            self._abandon()
            return True
        self.counts.rounds += 1
        if block.hear({sender: msg.records for sender, msg in heard.items()}):
            self.blocks.block = None
            self._report()
        return False

    def _settle_local(self, stamp: float, positions: dict[int, np.ndarray]) -> None:
        """The range-limited auction's block (core.local_auction): the central engine's rounds, heard within reach."""
        local = self.local
        if local is None or not local.own or not all(r in positions for r in local.own):
            return
        if local.started and stamp - self.blocks.stamp < self.params.assign_period - 1e-9:
            return
        self.blocks.stamp = stamp
        local.begin_block(positions)
        waiting = set(local.robots.tolist())
        while True:
            words = local.say()
            key = (local.epoch, local.instance, local.round)
            said = _boards(local, words, self.sender)
            if local.done:  # our robots' last words: said once (and again to whoever missed them)
                self.exchange.say(key, said)
                break
            self.exchange.open(key, said, speak=True)
            heard = self.exchange.close(key, waiting, lambda m: m.words["robot"], self._resend_base(len(waiting)))
            if heard is None:
                self._abandon()
                return
            theirs = [_words(m, local) for m in heard.values()]
            for w in theirs:
                waiting -= set(w.robot[w.ended].tolist())
            local.hear(Words.join([words, *theirs]))
            self.counts.rounds += 1
        self._report()

    def _resend_base(self, members: int) -> float:
        """Lock-step: the first wait before our message goes out again (every resend reaches every host)."""
        swarm = len(self._auction.robots) if self._auction is not None else 0
        return max(ROUND_RESEND, RESEND_PER_ROBOT * max(members, swarm))

    def _keeps(self, msg: Bid | Boards) -> bool:
        """Whether another host's message is one to take: not of an earlier goal set, and a bid of the set under
        way names its robots and goals only (it must not index the auction's arrays); else counted and dropped."""
        if self.active and msg.epoch < self.epoch:
            return False
        part = self.part
        if not isinstance(msg, Bid) or part is None or msg.epoch != part.epoch:
            return True
        records, goals = msg.records, len(part.goals)
        if len(part.members_only(records)) == len(records) and all(-1 <= g < goals for g in records["goal"].tolist()):
            return True
        self.inbox.drops[INCONSISTENT] += 1
        return False

    def stop(self) -> None:
        """The host is shutting down: stop waiting for rounds."""
        self.exchange.stopped = True

    def _abandon(self) -> None:
        """A round never completed: our robots hold their positions, as others may have adopted the block."""
        self.counts.abandoned += 1
        self.blocks.block = None
        own = self._auction.own if self._auction is not None else []
        if self.rounds is not None and self.rounds.on_abandoned is not None and own:
            self.rounds.on_abandoned(list(own))

    def _under_way(self) -> tuple[Participant, Goals]:
        """The participant and goal set of the auction under way (once on_goals has begun one)."""
        if self.part is None or self.goal_set is None:
            raise RuntimeError("no auction under way")
        return self.part, self.goal_set

    def _settle(self) -> None:
        part, _ = self._under_way()
        for _ in range(100):  # the cold start's phases can pass here when one host holds every robot
            part.bid_until_quiet()
            instance = part.instance
            part.check_agreement()
            if part.is_agreed or part.instance == instance:
                break
        self._report()

    def _report(self) -> bool:
        """Hand a new agreement of the auction under way to on_agreed, once per instance; True when there was one."""
        auction, gs = (self.local, self.goal_set) if self.local is not None else self._under_way()
        if gs is None or auction.agreed_instance <= self.reported:
            return False
        if self.reported < 0:  # the first agreement on this goal set
            self.counts.first_agreement_s.append(time.monotonic() - self.times.epoch_wall)
        self.reported = auction.agreed_instance
        self.counts.agreements += 1
        frozen = self.times.frozen_at.get(auction.agreed_instance // auction.phases)  # real time only
        if frozen is not None:
            self.times.latency = min(MAX_LEAD, max(0.0, self.times.now - frozen))
        self.on_agreed(auction.epoch, auction.agreed_instance, dict(auction.agreed), gs.positions, gs.colors)
        return True

    def _publish(self) -> None:
        part, _ = self._under_way()
        digest, items = part.outgoing()
        self.publishing.mismatch = False
        self.publishing.serial += 1
        self.bus.publish(
            self.bus.keys.auction(part.epoch, self.sender),
            Bid(part.epoch, part.instance, self.sender, self.publishing.serial, digest, len(items), items),
        )
        self.publishing.last_sent = time.monotonic()
        self.counts.sent += 1

    def stats(self) -> dict:
        part = self.part
        return {
            "epoch": part.epoch if part else 0,
            "instance": part.instance if part else -1,
            "agreed_instance": part.agreed_instance if part else -1,
            "bids": part.bids if part else 0,
            "messages_sent": self.counts.sent,
            "messages_received": self.counts.received,
            "agreements": self.counts.agreements,
            "deadlock_penalties": self.counts.penalties,
            "latency_s": round(self.times.latency, 3),
            "lockstep_rounds": self.counts.rounds,
            "abandoned_blocks": self.counts.abandoned,
            "dropped_blocks": self.counts.dropped,
            "first_agreement_s": [round(x, 4) for x in self.counts.first_agreement_s],
        }


def frames_close(before: np.ndarray, goals: np.ndarray, previous: np.ndarray) -> bool:
    """Whether keyframes are close enough (mean 1.5 goal spacings) for the auction to start from the carried claims."""
    goals = np.asarray(goals, float)
    ok = previous >= 0
    if len(goals) < 2 or not ok.any():
        return False
    # Imported here: scipy.spatial slows every agent process's start-up, and only keyframes need it.
    from scipy.spatial import cKDTree

    disparity = float(np.hypot(*(goals[ok] - np.asarray(before, float)[previous[ok]]).T).mean())
    spacing = float(np.median(cKDTree(goals).query(goals, k=2)[0][:, 1]))
    return disparity <= 1.5 * spacing


def _boards(local: LocalAuction, words: Words, sender: int) -> Boards:
    """Our robots' words of a round on the wire: known sets that grew, owned records that changed only."""
    flags = words.ended * Boards.ENDED + words.fresh * Boards.FRESH + words.grown * Boards.GROWN
    rows, goals = np.nonzero((words.owner != NO_OWNER) & words.fresh[:, None])
    out = np.zeros(len(words.robot), Boards.WORD)
    out["robot"], out["x"], out["y"] = words.robot, words.xy[:, 0], words.xy[:, 1]
    out["phase"], out["flags"], out["last"] = words.phase, flags, words.last
    out["records"] = np.bincount(rows, minlength=len(words.robot))
    records = np.zeros(len(rows), Boards.RECORD)
    records["goal"], records["price"] = goals, words.price[rows, goals]
    records["robot"], records["flags"] = words.owner[rows, goals], words.released[rows, goals] * RELEASED
    known = np.packbits(words.known[words.grown], axis=1).reshape(-1, (len(local.robots) + 7) // 8)
    fixed = (local.epoch, local.instance, sender, local.round, len(local.goals), len(local.robots), len(out))
    return Boards(*fixed, out, known, records)


def _fits(msg: Boards, local: LocalAuction) -> bool:
    """Whether a message fits this goal set: a damaged or forged one must not index the auction's arrays."""
    w, r = msg.words, msg.records
    grown = int(((w["flags"].astype(np.int64) & Boards.GROWN) != 0).sum())
    return (
        bool(np.isin(w["robot"], local.robots).all() and np.isin(r["robot"], local.robots).all())
        and bool((r["goal"] >= 0).all() and (r["goal"] < len(local.goals)).all())
        and int(w["records"].sum()) == len(r)
        and len(msg.known) >= grown
    )


def _words(msg: Boards, local: LocalAuction) -> Words:
    """Another host's words as the auction reads them (left-out parts empty: they are not read)."""
    g, n = len(local.goals), len(local.robots)
    same_set = msg.goals == g and msg.robots == n  # else a peer's words for another goal set: none read
    w, r = (msg.words, msg.records) if same_set and _fits(msg, local) else (msg.words[:0], msg.records[:0])
    k = len(w)
    flags = w["flags"].astype(np.int64)
    fresh, grown = (flags & Boards.FRESH) != 0, (flags & Boards.GROWN) != 0
    known = np.zeros((k, n), bool)
    known[grown] = np.unpackbits(msg.known[: int(grown.sum())], axis=1, count=n).astype(bool)
    price, owner, released = np.zeros((k, g)), np.full((k, g), NO_OWNER, np.int64), np.zeros((k, g), bool)
    rows, goal = np.repeat(np.arange(k), w["records"]), r["goal"]
    price[rows, goal], owner[rows, goal] = r["price"], r["robot"]
    released[rows, goal] = (r["flags"] & RELEASED) != 0
    xy = np.stack([w["x"], w["y"]], axis=1).astype(float)
    robot, phase, last = (w[key].astype(np.int64) for key in ("robot", "phase", "last"))
    return Words(robot, xy, phase, (flags & Boards.ENDED) != 0, last, fresh, grown, known, price, owner, released)
