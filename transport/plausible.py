"""What a well-formed message may claim, bounded by what its receiver already knows.

A decoder checks that a message is well formed; this checks that its tick is believable. A frame's
stamp is the start of its tick (tick x dt: the clock, the trackers and the agents all stamp so), so a
frame whose two disagree was damaged. A tick may not lie ahead of the receiver's own clock by more
than ``AHEAD`` ticks, and may not be older than the newest the receiver holds from that sender: the
newest tick wins, so one frame from the future would otherwise make every honest frame after it
look old. A sender that really went back (a tracker or a clock restarted, counting from 0 again)
is heard again once its old line has been silent for ``RESYNC`` seconds while the new one speaks.
Each refusal names its reason, counted by the receiver with the decoder's drops.
"""

from __future__ import annotations

import math

AHEAD = 2  # ticks a frame may lie ahead of the receiver's clock: keys travel apart, one period of jitter and a spare
RESYNC = 1.0  # s an accepted line stays silent, while older ticks keep coming, before the sender counts as restarted
STAMP_SLACK = 1e-6  # s: tick x dt against the stamp, for the rounding of two float products

FUTURE, STALE, INCONSISTENT = "future", "stale", "inconsistent"


def goal_set_believable(epoch: int, stamp: float, newest: int, now: float | None) -> bool:
    """A goal set's epoch may skip at most ``AHEAD`` of the newest heard (the coordinator counts
    them one by one), and its publication stamp may not lie ``RESYNC`` beyond the display time
    ``now`` the receiver knows (None: it knows none yet)."""
    return (newest == 0 or epoch <= newest + AHEAD) and (now is None or stamp <= now + RESYNC)


def stamp_agrees(tick: int, stamp: float, dt: float) -> bool:
    """The stamp is the start of the tick."""
    return abs(stamp - tick * dt) <= STAMP_SLACK * max(1.0, abs(stamp))


class TickLine:
    """One sender's ticks as one receiver believes them: the newest accepted, and when.

    ``admit`` takes a tick and the receiver's clock (``now``: the tick it believes current, None
    where it has no clock of its own) and returns None to take the message, or why not. With
    ``period`` set and no ``now`` given, the receiver's clock is the wall clock since the line
    began, ``period`` seconds a tick: a real-time sender cannot run ahead of it. A line silent for
    ``RESYNC`` begins anew with the next tick, whatever it is: a sender restarted, a clock that
    jumped, or a first tick that was itself wrong.
    """

    def __init__(self, period: float | None = None) -> None:
        self.period = period
        self.newest: int | None = None
        self.heard_at = -math.inf  # wall time (monotonic) of the newest accepted tick
        self._began: tuple[int, float] = (0, -math.inf)  # (tick, wall time) the wall-clock bound counts from

    def admit(self, tick: int, wall: float, now: float | None = None) -> str | None:
        fresh = self.newest is None or wall - self.heard_at >= RESYNC
        walled = now is None and self.period is not None and not fresh
        if walled and self.period is not None:
            now = self._began[0] + (wall - self._began[1]) / self.period
        if now is not None and tick > now + AHEAD:
            return FUTURE
        if not fresh and self.newest is not None and tick <= self.newest:
            return STALE
        if fresh or (walled and now is not None and tick > now):
            # a new line, or ticks that came sooner than the first did (it was late): count from here
            self._began = (tick, wall)
        self.newest, self.heard_at = tick, wall
        return None

    def forget(self) -> None:
        """The sender is gone (its liveliness token was withdrawn): its next tick begins a new line."""
        self.newest, self.heard_at = None, -math.inf
