"""Wall and CPU time per part of each control step of the central engine.

``start()`` opens a tick, ``lap(part)`` charges the time since the last lap to ``part``; the auction's
own time on the second thread is kept in ``beside``. CPU time is read only when asked: it is dearer.
"""

from __future__ import annotations

import time

import numpy as np

# The parts of a control step, in the order its tables list them.
PARTS = ("tracker", "assignment", "preferred", "record", "neighbours", "control", "world", "other")


class StepClock:
    """Seconds per part and tick: ``wall[part][tick]`` and ``cpu[part][tick]``."""

    def __init__(self, cpu: bool = False) -> None:
        self.read_cpu = time.process_time if cpu else lambda: 0.0
        self.wall: dict[str, list[float]] = {part: [] for part in PARTS}
        self.cpu: dict[str, list[float]] = {part: [] for part in PARTS}
        self.beside: list[float] = []  # per tick: wall seconds of the auction on the second thread (0: none)
        self.bids: list[int] = []  # per tick: the bids of that auction's block
        self.reassigned: list[int] = []  # per tick: the robots whose goal that block changed
        self._last = (0.0, 0.0)

    def start(self) -> None:
        """A new tick: every part starts at zero."""
        for seconds in (*self.wall.values(), *self.cpu.values(), self.beside):
            seconds.append(0.0)
        self.bids.append(0)
        self.reassigned.append(0)
        self._last = (time.perf_counter(), self.read_cpu())

    def lap(self, part: str) -> None:
        now = (time.perf_counter(), self.read_cpu())
        self.wall[part][-1] += now[0] - self._last[0]
        self.cpu[part][-1] += now[1] - self._last[1]
        self._last = now

    def add_beside(self, seconds: float, bids: int, reassigned: int) -> None:
        """A warm auction's wall seconds on its own thread this tick, its bids and the goals it changed."""
        self.beside[-1] += seconds
        self.bids[-1] += bids
        self.reassigned[-1] += reassigned

    def arrays(self, cpu: bool = False) -> dict[str, np.ndarray]:
        """(ticks,) seconds per part, wall time (or this process's CPU time)."""
        return {part: np.array(spent) for part, spent in (self.cpu if cpu else self.wall).items()}
