"""The distributed goal auction (paper 5.1.1) as seen by the robots of one agent host: pure logic,
no zenoh and no clock (the runtime passes messages in and takes records out).

The protocol is an asynchronous forward auction (Bertsekas and Castanon 1991) whose prices and owners
are agreed by max-consensus, as in Zavlanos et al. 2008:

- **Board.** Per goal, the greatest record anyone has seen, ordered by price, then the lower robot id,
  then "released" after "claimed". Records only ever merge by this maximum, so duplicated, reordered
  or lost messages can delay agreement but never give a goal two owners; no two records tie.
- **Bids.** A robot that holds no goal, or whose goal was taken by a greater record, bids on its best
  goal: the price rises by the difference between the best and second-best net value plus epsilon.
  Costs are private: squared distance (eq. 7) plus the robot's own deadlock penalties (5.5.5).
- **Instances.** An auction instance runs on positions frozen when it starts, so costs stay fixed
  while prices settle. Instance k is *agreed* when every robot of the goal set has published, for k,
  a content record (it holds its goal and no other is better by more than epsilon) on distinct goals,
  all written against the same board (equal digests). Such a snapshot is quiescent: every bid anyone
  made is on that board, so nobody can bid again in instance k. Every agent checks this for itself,
  and a record of instance k+1 from anyone proves k was agreed.
- **Warm start.** Instances follow one another, each starting from the prices and owners of the last
  (paper 5.1 re-assigns each iteration); a robot keeps its goal unless another is better by more
  than epsilon plus the hysteresis Delta C. The first instances of a new goal set use decreasing
  epsilon (epsilon scaling), so a cold start needs few price rises.

The agreed assignment costs at most N (epsilon + Delta C) more than the optimum for the frozen
positions (epsilon-complementary slackness against one common price vector).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from .auction import NO_OWNER, epsilon_schedule, net_values

CONTENT = 1  # record flag: the robot holds the goal and is content with it
RELEASED = 2  # record flag: the robot gave the goal up at this price


@dataclass(frozen=True)
class Record:
    """One robot's word on one goal (goal -1: it holds none yet)."""

    robot: int
    goal: int
    price: float
    flags: int
    x: float = 0.0
    y: float = 0.0


@dataclass
class Heard:
    """The newest record of another robot in the current instance, and the board it was written on."""

    instance: int
    serial: int
    record: Record
    digest: int


class Board:
    """Per goal: the greatest (price, lower robot id, released) record seen."""

    def __init__(self, goals: int) -> None:
        self.price = np.zeros(goals)
        self.owner = np.full(goals, NO_OWNER, dtype=np.int64)
        self.released = np.zeros(goals, bool)

    def merge(self, goal: int, price: float, robot: int, released: bool) -> bool:
        """Max-consensus; True when the record is new information."""
        if not 0 <= goal < len(self.price):
            return False
        if self.owner[goal] != NO_OWNER:
            mine = (self.price[goal], -self.owner[goal], self.released[goal])
            if (price, -robot, released) <= mine:
                return False
        self.price[goal], self.owner[goal], self.released[goal] = price, robot, released
        return True

    def holds(self, robot: int, goal: int) -> bool:
        return goal >= 0 and self.owner[goal] == robot and not self.released[goal]

    def digest(self) -> int:
        h = hashlib.blake2b(digest_size=8)
        for a in (self.price, self.owner, self.released):
            h.update(a.tobytes())
        return int.from_bytes(h.digest(), "little")


class Participant:
    """The own robots of one host in the auction of one goal set (epoch)."""

    def __init__(self, epoch: int, goals: np.ndarray, robots: list[int], own: list[int], eps: float,
                 hysteresis: float = 0.0) -> None:
        self.epoch = epoch
        self.goals = np.asarray(goals, float)
        self.robots = sorted(int(r) for r in robots)
        members = set(self.robots)
        self.own = sorted(r for r in own if r in members)
        self.schedule = epsilon_schedule(self.goals, eps, factor=10.0)  # fewer phases: each costs a global snapshot
        self.hysteresis = hysteresis
        self.board = Board(len(self.goals))
        self.instance = -1  # not started: waits for the robots' positions
        self.position: dict[int, np.ndarray] = {}
        self.row = {r: i for i, r in enumerate(self.own)}
        self.cost = np.zeros((len(self.own), len(self.goals)))  # c_ij at the frozen positions, eq. 7
        self.goal = {r: -1 for r in self.own}  # what each own robot claims
        self.penalty = np.zeros((len(self.own), len(self.goals)))  # C_d per robot and goal (deadlocks)
        self.heard: dict[int, Heard] = {}
        self.agreed_instance = -1
        self.agreed: dict[int, int] = {}  # own robot -> its goal in the agreed instance
        self.claims_changed = False  # own claims changed since the last publication
        self.published_digest: int | None = None  # the board digest of the last publication
        self.bids = 0

    # --- the epsilon of an instance ----------------------------------------------------------------
    @property
    def eps(self) -> float:
        return self.schedule[min(max(self.instance, 0), len(self.schedule) - 1)]

    @property
    def slack(self) -> float:
        """Epsilon, plus Delta C once epsilon scaling is over (paper 5.1's hysteresis)."""
        final = self.instance >= len(self.schedule) - 1
        return self.eps + (self.hysteresis if final else 0.0)

    @property
    def started(self) -> bool:
        return self.instance >= 0

    @property
    def is_agreed(self) -> bool:
        return self.started and self.agreed_instance == self.instance

    # --- instances --------------------------------------------------------------------------------
    @property
    def phases(self) -> int:
        """Instances 0 .. phases-1 are the epsilon-scaling phases of the cold start."""
        return len(self.schedule)

    def begin(self, instance: int, positions: dict[int, np.ndarray]) -> None:
        """Start an instance, warm from the current board. The cold start's phases share the
        positions frozen at instance 0; later instances freeze the positions given."""
        if self.started and not self.is_agreed and instance > self.instance:
            self._adopt_if_settled()  # someone reached a later instance: ours was agreed
        if not self.started or instance >= self.phases:
            self.position = {r: np.asarray(positions[r], float) for r in self.own}
            if self.own:
                p = np.array([self.position[r] for r in self.own])
                d = self.goals[None, :, :] - p[:, None, :]
                self.cost = d[..., 0] ** 2 + d[..., 1] ** 2
        self.instance = instance
        self.heard = {r: h for r, h in self.heard.items() if h.instance >= instance}
        self.claims_changed = True  # the new instance's records are news
        self.bid()

    def _adopt_if_settled(self) -> None:
        if self.instance >= self.phases - 1 and self._content_all().all():
            self.agreed_instance = self.instance
            self.agreed = dict(self.goal)

    # --- bidding ----------------------------------------------------------------------------------
    def _values(self, robot: int) -> np.ndarray:
        """Net values -c_ij - b_j of one robot (its private cost includes its deadlock penalties)."""
        i = self.row[robot]
        return -(self.cost[i] + self.penalty[i]) - self.board.price

    def _content_all(self) -> np.ndarray:
        """(K,) bool: each own robot holds its goal and no goal is better by more than the slack."""
        if not self.own:
            return np.zeros(0, bool)
        goal = np.array([self.goal[r] for r in self.own])
        holds = (goal >= 0) & (self.board.owner[goal] == np.array(self.own)) & ~self.board.released[goal]
        values = -(self.cost + self.penalty) - self.board.price[None, :]
        held = values[np.arange(len(goal)), goal]
        return holds & (held >= values.max(axis=1) - self.slack)

    def bid(self) -> bool:
        """One round for the own robots (in id order, each seeing the others' bids); True if any bid."""
        if not self.started:
            return False
        any_bid = False
        content = self._content_all()
        for r, ok in zip(self.own, content):
            if ok or (any_bid and self._content(r)):  # an earlier bid this round may have settled it
                continue
            values = self._values(r)
            best = int(np.argmax(values))  # ties: lowest goal index, the same everywhere
            second = float(np.max(np.delete(values, best))) if len(values) > 1 else values[best] - self.eps
            price = float(self.board.price[best] + (values[best] - second) + self.eps)
            held = self.goal[r]
            if self.board.holds(r, held):  # it gives its goal up for a better one
                self.board.merge(held, float(self.board.price[held]), r, True)
            self.board.merge(best, price, r, False)
            self.goal[r] = best
            self.bids += 1
            any_bid = True
        if any_bid:
            self.claims_changed = True
        return any_bid

    def _content(self, robot: int) -> bool:
        g = self.goal[robot]
        if not self.board.holds(robot, g):
            return False
        values = self._values(robot)
        return bool(values[g] >= values.max() - self.slack)

    def bid_until_quiet(self, max_rounds: int = 100_000) -> int:
        """Rounds until no own robot wants to bid (own robots outbid each other without messages)."""
        rounds = 0
        while rounds < max_rounds and self.bid():
            rounds += 1
        return rounds

    def penalise(self, robot: int, goal: int, cost: float) -> None:
        """Deadlock (5.5.5): the robot's cost of this goal rises by C_d for good."""
        if robot in self.row and 0 <= goal < len(self.goals):
            self.penalty[self.row[robot], goal] += cost

    # --- messages ---------------------------------------------------------------------------------
    @property
    def has_news(self) -> bool:
        """Own claims changed, or the board did since the last publication (others need our digest)."""
        return self.started and (self.claims_changed or self.board.digest() != self.published_digest)

    def outgoing(self) -> tuple[int, list[Record]]:
        """The digest and records to publish now (marks them published)."""
        self.claims_changed = False
        self.published_digest = self.board.digest()
        return self.published_digest, self.records()

    def records(self) -> list[Record]:
        """What the own robots say now: a claim each, and the goals they released that still carry
        their release on the board (so that others learn the price even if a message was lost)."""
        out = []
        for r, content in zip(self.own, self._content_all()):
            g = self.goal[r]
            x, y = (float(v) for v in self.position.get(r, (0.0, 0.0)))
            holds = self.board.holds(r, g)
            flags = CONTENT if content else 0
            out.append(Record(r, g if holds else -1, float(self.board.price[g]) if holds else 0.0, flags, x, y))
        mine = set(self.own)
        for g in np.flatnonzero(self.board.released):
            owner = int(self.board.owner[g])
            if owner in mine:
                out.append(Record(owner, int(g), float(self.board.price[g]), RELEASED))
        return out

    def absorb(self, instance: int, serial: int, digest: int, records: list[Record]) -> bool:
        """Merge another host's records; True when the board changed. Records of the current instance
        are remembered per robot (the newest by serial) for the agreement check."""
        changed = False
        for rec in records:
            if rec.goal >= 0:
                changed |= self.board.merge(rec.goal, rec.price, rec.robot, bool(rec.flags & RELEASED))
            if rec.flags & RELEASED or rec.robot in self.goal:
                continue
            old = self.heard.get(rec.robot)
            if instance == self.instance and (old is None or old.instance < instance or serial > old.serial):
                self.heard[rec.robot] = Heard(instance, serial, rec, digest)
        return changed

    def _settled_view(self, same_board: bool) -> bool:
        """Every robot content on a distinct goal, as far as this host knows: own robots now, the
        others by their newest records of this instance, which still hold on our board (and, with
        ``same_board``, were written against a board with our digest)."""
        if not self.started or not self._content_all().all():
            return False
        digest = self.board.digest() if same_board else None
        taken = {self.goal[r] for r in self.own}
        if len(taken) < len(self.own):
            return False
        for r in self.robots:
            if r in self.goal:
                continue
            h = self.heard.get(r)
            if h is None or h.instance != self.instance or (same_board and h.digest != digest):
                return False
            rec = h.record
            if not (rec.flags & CONTENT) or rec.goal in taken or not self.board.holds(r, rec.goal) \
                    or self.board.price[rec.goal] != rec.price:
                return False
            taken.add(rec.goal)
        return True

    def view_complete(self) -> bool:
        """Nobody is bidding as far as we know: the moment to tell others our board's digest (earlier,
        while bids fly, digests would be stale at once)."""
        return self._settled_view(same_board=False)

    def check_agreement(self) -> bool:
        """True (once per instance) when this host sees instance k agreed; sets ``agreed``. An agreed
        phase of the cold start only moves on to the next phase."""
        if self.is_agreed or not self._settled_view(same_board=True):
            return False
        if self.instance < self.phases - 1:  # a cold-start phase: go on with a smaller epsilon
            self.begin(self.instance + 1, self.position)
            return False
        self.agreed_instance = self.instance
        self.agreed = dict(self.goal)
        return True
