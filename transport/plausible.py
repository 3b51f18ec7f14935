"""What a well-formed message may claim, bounded by what its receiver already knows.

A frame's stamp is the start of its tick (tick x dt): if the two disagree it was damaged. A tick may lie
at most ``AHEAD`` ticks ahead of the receiver's clock and not be older than the newest held from that
sender (else one frame from the future would make every honest one after it look old); a sender that
really went back (restarted) is heard again once its new line has gone on for ``RESYNC`` s (TickLine).
Each refusal names its reason, counted by the receiver with the decoder's drops.
"""

from __future__ import annotations

import dataclasses
import math
from typing import cast

from .codec import Goals, Tick

AHEAD = 2  # ticks a frame may lie ahead of the receiver's clock: keys travel apart, one period of jitter and a spare
RESYNC = 1.0  # s a new line of ticks goes on (and the old one is silent, or behind it) before it is believed
DRIFT = 0.01  # how much faster than the receiver's a sender's clock may run (two machines' clocks differ)
STAMP_SLACK = 1e-6  # s: tick x dt against the stamp, for the rounding of two float products

FUTURE, STALE, INCONSISTENT = "future", "stale", "inconsistent"
MISADDRESSED = "misaddressed"  # a record for another robot than its key (or its sender) names
CONFLICTING = "conflicting"  # a second, different command for a robot's tick: two controllers drive it


class Clock:
    """The world's clock as a receiver believes it: a tick's stamp is its start, and the world
    publishes every tick, so a clock may not skip more than ``AHEAD`` past the newest. With ``period``
    (a world in real time) nor run ahead of the wall clock since its first tick: forged clocks, each
    ``AHEAD`` past the last, would otherwise carry it to any tick."""

    def __init__(self, period: float | None = None) -> None:
        self.line = TickLine(period)

    @property
    def newest(self) -> int | None:
        return self.line.newest

    def admit(self, clock: Tick, wall: float) -> str | None:
        if not stamp_agrees(clock.tick, clock.stamp, clock.dt):
            return INCONSISTENT
        return self.line.admit(clock.tick, wall, None if self.line.period else self.line.newest)


class GoalSets:
    """Which goal sets a receiver believes are the coordinator's, which counts epochs one by one, a new
    one only for a change: an epoch skips at most ``AHEAD`` past the newest heard; a goal set is stamped
    at most ``RESYNC`` beyond the receiver's display time; its goals lie in the arena; an epoch heard again
    holds the same goal set; a new epoch holds a goal set not already heard under another epoch.

    ``newest``: the newest epoch known at the start, 0 for a receiver that starts with the run (so it takes
    no forged first epoch), None for one that may join a run under way (it takes the first it hears)."""

    KEPT = 8  # epochs remembered

    def __init__(self, arena: tuple[float, float, float, float] | None = None, newest: int | None = None) -> None:
        self.arena = arena
        self.newest = newest
        self._sent: dict[int, bytes] = {}  # epoch -> its goal set as first heard
        self._content: dict[bytes, int] = {}  # a goal set without its epoch -> its epoch

    def rejoin(self) -> None:
        """The receiver's link came back: the epochs published meanwhile never reached it, so it takes the next
        it hears, however far ahead, as one that joins a run under way does (the coordinator repeats only its
        newest set, and an epoch refused as too far ahead would be refused for good)."""
        self.newest = None

    def admit(self, goals: Goals, now: float | None) -> str | None:
        """None to take the goal set, or why not. ``now``: the display time the receiver knows."""
        too_far = self.newest is not None and goals.epoch > self.newest + AHEAD
        if too_far or (now is not None and goals.timing.stamp > now + RESYNC):
            return FUTURE
        if self.arena is not None and len(goals.positions):
            low, high = goals.positions.min(axis=0), goals.positions.max(axis=0)
            if (low < self.arena[:2]).any() or (high > self.arena[2:]).any():
                return "invalid"
        sent = goals.encode()
        first = self._sent.get(goals.epoch)
        if first is not None:
            return None if first == sent else "conflict"
        content = dataclasses.replace(goals, epoch=0).encode()
        if content in self._content:
            return "replayed"
        self._sent[goals.epoch], self._content[content] = sent, goals.epoch
        self.newest = max(self.newest or 0, goals.epoch)
        for old in sorted(self._sent)[: -self.KEPT]:
            del self._sent[old]
        self._content = {c: e for c, e in self._content.items() if e in self._sent}
        return None


def stamp_agrees(tick: int, stamp: float, dt: float) -> bool:
    """The stamp is the start of the tick."""
    return abs(stamp - tick * dt) <= STAMP_SLACK * max(1.0, abs(stamp))


class TickLine:
    """One sender's ticks as one receiver believes them: the newest accepted, and when.

    ``admit`` takes a tick and the receiver's clock (``now``: the tick it believes current, None: none)
    and returns None to take the message, or why not. With ``period`` and no ``now``, the clock is the
    wall clock since the line began, ``period`` s a tick, so a real-time sender cannot run ahead of it.
    A refused tick may begin a new line (a restart, a jumped clock, a wrong first tick), taken once it has
    gone on tick after tick for ``RESYNC`` s (with ``period``, no faster than the wall clock and DRIFT) and
    runs ahead of the old line or the old one was as silent. Copies of old frames, or forged ones in no
    order, never make such a line.
    """

    def __init__(self, period: float | None = None) -> None:
        self.period = period
        self.newest: int | None = None
        self.heard_at = -math.inf  # wall time (monotonic) of the newest accepted tick
        self._began: tuple[int, float] = (0, -math.inf)  # (tick, wall time) the wall-clock bound counts from
        self._first: tuple[int, float] = (0, -math.inf)  # (tick, wall time) the line's first: _began moves past it
        # by at most _slack, so that forged ticks, each a little sooner, cannot carry the bound along
        self._new_line: tuple[float, int, int] | None = None  # (wall time it began, its newest tick, its first)

    def admit(self, tick: int, wall: float, now: float | None = None) -> str | None:
        walled = now is None and self.period is not None and self.newest is not None
        if walled and self.period is not None:
            now = self._began[0] + (wall - self._began[1]) / self.period
        in_line = self.newest is None or tick > self.newest
        if in_line and (now is None or tick <= now + AHEAD):
            if self.newest is None:
                self._began = self._first = (tick, wall)
            elif walled and now is not None and tick > now and self._sooner_than_first(tick, wall) <= self._slack(wall):
                self._began = (tick, wall)  # ticks sooner than the first: it was late, or the sender's clock is faster
            self._new_line = None
            self.newest, self.heard_at = tick, wall
            return None
        line = self._new_line
        if line is not None and line[1] < tick <= line[1] + AHEAD:
            line = (line[0], tick, line[2])
        else:
            line = (wall, tick, tick)
        self._new_line = line
        ahead = self.newest is not None and tick > self.newest
        # in real time a new line too keeps the wall clock's pace: forged ticks sent fast never make one
        paced = self.period is None or line[1] - line[2] <= (1.0 + DRIFT) * (wall - line[0]) / self.period + AHEAD
        if wall - line[0] >= RESYNC and paced and (ahead or wall - self.heard_at >= RESYNC):
            self._began = self._first = (tick, wall)
            self._new_line = None
            self.newest, self.heard_at = tick, wall
            return None
        return FUTURE if ahead or self.newest is None else STALE

    def _slack(self, wall: float) -> float:
        """How many seconds sooner than the line's first foretold a tick may come: RESYNC (the first came
        late), and DRIFT of the time since (the sender's clock runs a little faster)."""
        return RESYNC + DRIFT * (wall - self._first[1])

    def _sooner_than_first(self, tick: int, wall: float) -> float:
        """How many seconds sooner ``tick`` came than the line's first tick foretold (period s a tick)."""
        period = cast(float, self.period)
        return (tick - self._first[0]) * period - (wall - self._first[1])
