"""How late an agent acts on its pose, and how far its robot may stray meanwhile (real time: docs/overload.md)."""

from __future__ import annotations

from collections import deque

WINDOW = 50  # ticks over which the quickest pose is remembered, so that a loaded spell ages out


class Lateness:
    """The age of a tick's pose when the agent acts on it, beyond the quickest seen lately."""

    def __init__(self, dt: float, command_margin: float, window: int = WINDOW) -> None:
        self.most = dt + command_margin  # a later command never drives: its body stands
        self._quickest: deque[float] = deque(maxlen=window)  # wall time minus stamp, per tick
        self.worst = 0.0  # the worst lateness acted on (s), for the host's statistics
        self.total, self.count = 0.0, 0  # ... and their sum over the ticks acted on

    def arrived(self, stamp: float, wall: float) -> None:
        """A tick's first pose, stamped ``stamp`` (display time), taken at ``wall`` (monotonic)."""
        self._quickest.append(wall - stamp)

    def at(self, stamp: float, wall: float) -> float:
        """How late acting at ``wall`` on a pose stamped ``stamp`` is, in seconds (0 on time)."""
        if not self._quickest:
            return 0.0
        late = min(max(wall - stamp - min(self._quickest), 0.0), self.most)
        self.worst = max(self.worst, late)
        self.total, self.count = self.total + late, self.count + 1
        return late

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0


def strayed(late: float, v_max: float) -> float:
    """How far a body may be from where its plan starts when a command late by ``late`` takes over (a reversal)."""
    return 2.0 * v_max * late
