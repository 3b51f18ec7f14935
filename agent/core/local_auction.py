"""The goal auction over a limited communication range (paper 5.1.1): pure logic, no zenoh and no clock.

Each robot bids against a board of its own, merged every round with those it hears within ``reach``, and ends a
phase once the newest change it knows of is older than its eccentricity in rounds (docs/lockstep_auction.md,
"Over a limited communication range"). Hosts and the central engine run the same rounds, bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from .bidder import NO_OWNER, Auction, Participant, frozen_positions
from .bidding import bid_on_own_boards, hear_words, merge_boards
from .params import RobotParams


class Words(NamedTuple):
    """What robots say in one round (rows by robot)."""

    robot: np.ndarray  # (K,) int64
    xy: np.ndarray  # (K, 2) float64 of float32 values, as the wire carries them
    phase: np.ndarray  # (K,) int64
    ended: np.ndarray  # (K,) bool: the block is agreed (it says so once, then stops)
    last: np.ndarray  # (K,) int64: the latest round of change it knows of
    fresh: np.ndarray  # (K,) bool: the board changed since the robot's last word (else it may be left out)
    grown: np.ndarray  # (K,) bool: the known set grew since the robot's last word (else it may be left out)
    known: np.ndarray  # (K, N) bool: the robots it has heard of, columns by the goal set's robots in order
    price: np.ndarray  # (K, G)
    owner: np.ndarray  # (K, G) int64, NO_OWNER: none
    released: np.ndarray  # (K, G) bool

    @staticmethod
    def join(parts: list[Words]) -> Words:
        return Words(*(np.concatenate(cols) for cols in zip(*parts, strict=True)))


class LocalAuction(Auction):
    """A host's own robots in the range-limited auction of one goal set (epoch): each one's board and block
    state as flat attributes (the compiled rounds read them by name)."""

    def __init__(
        self,
        epoch: int,
        goals: np.ndarray,
        robots: list[int],
        own: list[int],
        eps: float,
        hysteresis: float,
        reach: float,
    ) -> None:
        super().__init__(epoch, goals, robots, own, eps, hysteresis)
        self.reach = float(reach)
        k, g, n = len(self.own), len(self.goals), len(self.robots)
        if g < n:
            raise ValueError(f"{n} robots cannot share {g} goals one to one")
        self.price = np.zeros((k, g))
        self.owner = np.full((k, g), NO_OWNER, np.int64)
        self.released = np.zeros((k, g), bool)
        self.goal = np.full(k, -1, np.int64)  # what each own robot claims on its board
        self.penalty = np.zeros((k, g))  # C_d in force this block
        self.pending: np.ndarray = np.zeros((k, g))  # declared during this block: in force from the next
        self.block = -1  # the rest of a robot's state is its block's (begin_block)
        self.agreed: dict[int, int] = {}

    # --- the interface the lock-step drivers share with agent.core.bidder.Participant ---------------
    @property
    def started(self) -> bool:
        return self.block >= 0

    @property
    def instance(self) -> int:
        """The block's final phase, as Participant numbers instances (blocks of ``phases``)."""
        return max(self.block, 0) * self.phases + self.phases - 1

    @property
    def done(self) -> bool:
        """Every own robot has ended the block and said so."""
        return bool(self.said_end.all())

    def begin_block(self, positions: Mapping[int, np.ndarray] | np.ndarray) -> None:
        """Freeze the own robots' positions, bring declared penalties into force and start, warm."""
        xy = frozen_positions(positions, self.own)
        self.block += 1
        self.penalty += self.pending
        self.pending[:] = 0.0
        d = self.goals[None, :, :] - xy[:, None, :]
        self.cost = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + self.penalty
        # what taking a goal held out of reach costs on top (see _bid): more than any other goal
        self.taken_cost = 2.0 * self.cost.max(axis=1, initial=0.0) + 1.0
        # the graph is judged on positions as the wire carries them, the same in every engine
        self.xy = xy.astype(np.float32).astype(float)
        # a warm block starts at the final phase: a phase's end costs its eccentricity, and few robots bid
        k = len(self.own)
        self.phase = np.full(k, 0 if self.block == 0 else self.phases - 1, np.int64)
        self.last = np.zeros(k, np.int64)  # the latest round of change it knows of
        self.known = np.zeros((k, len(self.robots)), bool)  # the robots it has heard of
        self.known[np.arange(k), self.own_rows] = True
        self.grew = np.zeros(k, np.int64)  # the last round the known set grew
        self.board_changed = np.ones(k, np.int64)  # the last round the board changed: a new block's is news
        self.ended = np.zeros(k, bool)
        self.said_end = np.zeros(k, bool)
        self.round = 0

    # --- a round -------------------------------------------------------------------------------------
    def say(self) -> Words:
        """Round r: every own robot still in the block bids if it must, then says its word (the end once)."""
        self.round += 1
        r = self.round
        active = np.flatnonzero(~self.ended)
        if len(active):
            bid = self._bid(active)
            self.last[bid] = r
            self.board_changed[bid] = r
        speaking = np.flatnonzero(~self.said_end)
        self.said_end[self.ended] = True
        fresh, grown = self.board_changed >= r - 1, (self.grew >= r - 1) | (r == 1)
        said = (self.own_ids, self.xy, self.phase, self.ended, self.last, fresh, grown, self.known)
        board = (self.price, self.owner, self.released)
        return Words(*(column[speaking] for column in (*said, *board)))  # Words' fields, in order

    def hear(self, words: Words) -> None:
        """Round r: the words said (own robots' too) merged into each own robot's board within reach (only
        what changed since the speaker's last word); then each checks whether its phase ended."""
        r = self.round
        active = np.flatnonzero(~self.ended)
        if len(active) == 0:
            return
        changed, told = hear_words(self, active, words, r)  # who hears whom; phases, known sets, lasts
        if told.any():  # max-consensus of the boards each was told into its own
            merged = merge_boards(self, active, told, words)
            self.board_changed[active[merged]] = r
            changed |= merged
        self.last[active[changed]] = r
        self._check_end(active, r)
        if self.ended.all() and self.agreed_instance != self.instance:
            self.agreed_instance = self.instance
            self.agreed = dict(zip(self.own, self.goal.tolist(), strict=True))

    def _check_end(self, rows: np.ndarray, r: int) -> None:
        """A phase is over in a robot's part once its newest change is older than its eccentricity (its
        known set stopped growing: ``grew`` hops). The final phase's end ends the block."""
        rows = rows[~self.ended[rows] & (self.grew[rows] < r)]
        over = rows[self.last[rows] < r - self.grew[rows]]
        final = self.phase[over] == self.phases - 1
        self.ended[over[final]] = True
        going_on = over[~final]
        self.phase[going_on] += 1
        self.last[going_on] = r

    def _bid(self, rows: np.ndarray) -> np.ndarray:
        """Own robots (rows) not content at their phase's slack bid; returns the rows that bid."""
        eps, slack = np.asarray(self.schedule)[self.phase[rows]], self.slacks[self.phase[rows]]
        # a goal held by a robot out of reach costs more than any other, so a split graph stays one-to-one
        owner = self.owner[rows]
        col = np.minimum(np.searchsorted(self.robots, np.maximum(owner, 0)), len(self.robots) - 1)
        known = np.take_along_axis(self.known[rows], col, axis=1)
        taken = (owner != NO_OWNER) & ~self.released[rows] & ~known
        bid = bid_on_own_boards(self, np.ascontiguousarray(rows, np.int64), slack, eps, taken.view(np.uint8))
        self.bids += len(bid)
        return bid


def new_auction(
    epoch: int, goals: np.ndarray, robots: list[int], own: list[int], params: RobotParams, reach: float
) -> Participant | LocalAuction:
    """The auction of a goal set for the ``own`` robots: a board each over a finite ``reach``, else one."""
    if np.isfinite(reach):
        return LocalAuction(epoch, goals, robots, own, params.assign_eps, params.assign_hysteresis, reach)
    return Participant(epoch, goals, robots, own, params.assign_eps, params.assign_hysteresis)
