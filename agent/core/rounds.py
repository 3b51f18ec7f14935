"""Lock-step: one block of epsilon-scaling phases (paper 5.1.1) bid in numbered message rounds.

In round r every host's robots that are not content bid against the board as merged after round
r - 1 (Jacobi), and every host merges everyone's records of round r onto the same board. Pure: the
caller carries each round's records to the other hosts and back (agent.assignment over the bus;
sim.central.engine with no other host). A block may span ticks: the caller decides how many rounds a tick
gets (``RobotParams.rounds_per_tick``), and the block is agreed at the same round everywhere.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .bidder import RELEASED, SETTLED, Participant


def claims(records: np.ndarray) -> np.ndarray:
    """The claims among a round's records (the rest are releases)."""
    return records[(records["flags"] & RELEASED) == 0]


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
        self._flags = np.zeros(int(part.robots.max(initial=0)) + 1, np.uint8)  # each robot's newest claim flags

    def say(self) -> np.ndarray:
        """Bid the next round; returns our records of it. After the first round only the claims that
        changed and the releases: everyone merged the rest already, and merging a record twice
        changes no board (max-consensus)."""
        part = self.part
        self.round += 1
        self._before = part.board.digest()
        part.bid()
        mine = part.round_records()
        k = self._claims
        news = mine if self._last is None else np.concatenate([mine[:k][mine[:k] != self._last], mine[k:]])
        self._last = mine[:k]
        return news

    def robots_of(self, sender: int, records: np.ndarray) -> np.ndarray:
        """The robots a host speaks for: those of its first round's claims."""
        if sender not in self._robots_of:
            self._robots_of[sender] = claims(records)["robot"]
        return self._robots_of[sender]

    def hear(self, heard: Mapping[int, np.ndarray]) -> bool:
        """Merge the other hosts' records of this round (sender -> records) and close the round;
        True: the block is agreed, at this round for every host."""
        part = self.part
        for sender, records in heard.items():
            records = part.members_only(records)
            self.robots_of(sender, records)
            part.absorb(part.instance, self.round, 0, records)
            theirs = claims(records)
            self._flags[theirs["robot"]] = theirs["flags"]
        # settled: every robot's claim says so this round, ours as just said, the others by their newest
        assert self._last is not None
        settled = bool(((self._last["flags"] & SETTLED) != 0).all()) and all(
            bool(((self._flags[self._robots_of[s]] & SETTLED) != 0).all()) for s in heard
        )
        return part.close_round(part.board.digest() == self._before, settled)
