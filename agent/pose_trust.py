"""Which tracked positions a robot drives on: a pose further than it could have driven is a tracker glitch, and it
brakes on its last trusted one until ``CONFIRM`` poses agree on the new place (picked up and put down, Fig. 20)."""

from __future__ import annotations

import math
from dataclasses import dataclass

CONFIRM = 3  # poses in a row that agree on a new place before the robot is believed to be there


@dataclass
class _Place:
    tick: int
    x: float
    y: float
    theta: float
    agreeing: int = 1  # poses in a row at this place (a candidate's)


class PoseTrust:
    """Per robot, the last trusted pose and a candidate new place."""

    def __init__(self, v_max: float, dt: float, slack: float) -> None:
        self.v_max, self.dt, self.slack = v_max, dt, slack  # slack: what tracking noise may add to a move (m)
        self.trusted: dict[int, _Place] = {}
        self.candidate: dict[int, _Place] = {}
        self.held = 0  # poses held back so far (robot-ticks braked)

    def _within(self, place: _Place, tick: int, x: float, y: float) -> bool:
        reach = self.v_max * self.dt * max(tick - place.tick, 1) + self.slack
        return math.hypot(x - place.x, y - place.y) <= reach

    def judge(self, robot: int, tick: int, x: float, y: float, theta: float) -> tuple[float, float, float] | None:
        """The pose to drive on, or None to brake: held on the last trusted pose until confirmed."""
        last = self.trusted.get(robot)
        if last is not None and not self._within(last, tick, x, y):
            cand = self.candidate.get(robot)
            agreeing = cand.agreeing + 1 if cand is not None and self._within(cand, tick, x, y) else 1
            if agreeing < CONFIRM:
                self.candidate[robot] = _Place(tick, x, y, theta, agreeing)
                last.tick = max(last.tick, tick - 1)  # braking, it stands: its reach does not grow while held
                self.held += 1
                return None
        self.trusted[robot] = _Place(tick, x, y, theta)  # within reach, or confirmed
        self.candidate.pop(robot, None)
        return (x, y, theta)

    def last(self, robot: int) -> tuple[float, float, float]:
        place = self.trusted[robot]
        return (place.x, place.y, place.theta)
