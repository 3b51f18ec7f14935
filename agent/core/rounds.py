"""Lock-step: one block of epsilon-scaling phases (paper 5.1.1) bid in numbered message rounds
(docs/lockstep_auction.md). Pure: the caller carries the records and decides the rounds a tick gets.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .bidder import RECORD, RELEASED, SETTLED, Participant

# a record as its bytes: compared whole, not field by field (numpy compares structured arrays slowly)
RECORD_BYTES = np.dtype((np.void, RECORD.itemsize))


class BlockRounds:
    """The rounds of one block, begun on frozen positions, warm from the participant's board."""

    def __init__(self, part: Participant, positions: Mapping[int, np.ndarray] | np.ndarray) -> None:
        part.begin_block(positions)
        self.part = part
        self.final = part.instance + part.phases - 1  # the block's final phase: it names the block on the wire
        self.round = 0
        self._claims = len(part.own)  # round_records: a claim per own robot, in order, then the releases
        self._last: np.ndarray | None = None  # our claims as last said
        self._before = 0  # the board's digest before this round's bids
        self._robots_of: dict[int, np.ndarray] = {}  # sender -> its robots, from its full first round
        self._steady = False  # the last round kept the phase (and so the costs): quiet() may hold
        self.open = False  # a round said and not yet heard (the tick's last, heard at the next tick)

    def say(self) -> np.ndarray:
        """Bid the next round; returns our records (after the first, only changed claims and releases)."""
        part = self.part
        self.round += 1
        self.open = True
        self._before = part.board.digest()
        part.bid()
        mine = part.round_records()
        k = self._claims
        if self._last is None:
            news = mine
        else:  # one mask over the records (numpy concatenates structured arrays field by field, slowly)
            said = np.ones(len(mine), bool)
            said[:k] = mine[:k].view(RECORD_BYTES) != self._last.view(RECORD_BYTES)
            news = mine[said]
        self._last = mine[:k]
        # noted beside the others' claims as absorb notes them: each robot's newest claim in one place
        rows = part.own_rows
        part.heard_instance[rows], part.heard_flags[rows] = part.instance, self._last["flags"]
        part.heard_goal[rows], part.heard_price[rows] = self._last["goal"], self._last["price"]
        return news

    def _newest(self, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each robot's newest claim this block (flags, goal, price): ours as said, others' as heard."""
        part = self.part
        row = np.searchsorted(part.robots, robots)
        flags = np.where(part.heard_instance[row] > self.final - part.phases, part.heard_flags[row], 0)  # this block's
        return flags, part.heard_goal[row], part.heard_price[row]

    def _settled(self, heard: Mapping[int, np.ndarray]) -> bool:
        """Whether the newest claim of each robot, ours and those of the hosts ``heard``, is SETTLED."""
        theirs = np.concatenate([self._robots_of[s] for s in heard] or [np.zeros(0, np.int64)])
        return bool(((self._newest(np.concatenate([self.part.own_ids, theirs]))[0] & SETTLED) != 0).all())

    def quiet(self, robots: np.ndarray) -> np.ndarray:
        """Per robot: nothing to say next round, alike on every host: its newest claim was SETTLED, the
        board still holds it and the phase (so costs) held; prices only rise, so it bids nothing."""
        robots = np.asarray(robots, np.int64)
        if not self._steady or self._last is None:
            return np.zeros(len(robots), bool)
        board, (flags, goal, price) = self.part.board, self._newest(robots)
        at = np.maximum(goal, 0)
        held = (goal >= 0) & (board.owner[at] == robots) & ~board.released[at] & (board.price[at] == price)
        return ((flags & SETTLED) != 0) & held

    def robots_of(self, sender: int, records: np.ndarray) -> np.ndarray:
        """The robots a host speaks for: its first round's claims, of this goal set's robots only."""
        if sender not in self._robots_of:
            recs = self.part.members_only(records)
            self._robots_of[sender] = recs[(recs["flags"] & RELEASED) == 0]["robot"]  # claims, not releases
        return self._robots_of[sender]

    def hear(self, heard: Mapping[int, np.ndarray]) -> bool:
        """Merge the other hosts' records of this round (sender -> records) and close the round;
        True: the block is agreed, at this round for every host."""
        part = self.part
        self.open = False
        for sender, records in heard.items():
            self.robots_of(sender, records)
        records = np.zeros(0, RECORD)
        if heard:  # one merge of every host's records: a robot per host sends a record or two each
            # (joined as bytes: numpy concatenates structured arrays field by field, slowly)
            joined = b"".join([np.asarray(records, RECORD).tobytes() for records in heard.values()])
            records = part.members_only(np.frombuffer(joined, RECORD))
            part.absorb(part.instance, self.round, 0, records)
        if self.round == 1:  # every robot's claim, and so its frozen position, is in: the next block's tilt
            claims = records[(records["flags"] & RELEASED) == 0]
            robots = np.concatenate([part.own_ids, claims["robot"].astype(np.int64)])
            position = np.concatenate([part.position, np.column_stack([claims["x"], claims["y"]])])
            part.note_block_positions(robots, position)
        # settled: every robot's newest claim says so (a quiet() host said nothing: settled)
        phase = part.instance
        agreed = part.close_round(part.board.digest() == self._before, lambda: self._settled(heard))
        self._steady = part.instance == phase
        return agreed
