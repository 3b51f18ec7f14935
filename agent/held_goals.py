"""The goals robots hold: the one goal bookkeeping of every engine (agent.loop.Robots.goals).

Rows by robot. A robot holds the goal its agreed assignment gave it (paper 5.1), or none: where the
goal stood when its goal set was published (``goal0``), where it is now (``goal``: a moving goal
set's goal moves, eq. 28; a robot with no goal of a goal set may still be sent somewhere, to a
scene's own goal or its target's position), its key (the goal set's epoch, the goal's index or
NO_GOAL), the auction instance that agreed it, and the LED colour it shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .core.policy import NO_GOAL

IDLE_COLOR = (40, 40, 40)


@dataclass
class HeldGoals:
    goal0: np.ndarray  # (N,2) NaN: none
    goal: np.ndarray  # (N,2) NaN: none
    key: np.ndarray  # (N,2) int64 (epoch, goal index)
    instance: np.ndarray  # (N,) int64
    color: np.ndarray  # (N,3) uint8

    @classmethod
    def new(cls, n: int) -> HeldGoals:
        key = np.zeros((n, 2), np.int64)
        key[:, 1] = NO_GOAL
        color = np.tile(np.array(IDLE_COLOR, np.uint8), (n, 1))
        return cls(np.full((n, 2), np.nan), np.full((n, 2), np.nan), key, np.zeros(n, np.int64), color)

    def drive_to(
        self, rows: np.ndarray, epoch: int, instance: int, index: np.ndarray, positions: np.ndarray, colors: np.ndarray
    ) -> None:
        """The robots at ``rows`` were agreed goals ``index`` of goal set ``epoch``: each drives to its
        goal and lights its colour."""
        self.goal0[rows] = self.goal[rows] = positions[index]
        self.key[rows, 0], self.key[rows, 1] = epoch, index
        self.instance[rows] = instance
        self.color[rows] = colors[index]

    def hold(self, rows: np.ndarray) -> None:
        """These robots hold no goal (they stand where they are) and keep their colour."""
        self.goal0[rows] = self.goal[rows] = np.nan
        self.key[rows, 1] = NO_GOAL

    def idle(self, rows: np.ndarray) -> None:
        """These robots hold no goal and show the idle colour (not a pixel of the image shown)."""
        self.hold(rows)
        self.color[rows] = IDLE_COLOR

    def has_goal(self, rows: np.ndarray | slice) -> np.ndarray:
        return self.key[rows, 1] >= 0

    def targets(self, rows: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
        """What the policy steers these robots to (agent.loop.Robots.goals): a held goal as its set
        was published (the policy moves it, eq. 28), else where the robot was sent; and the keys (a
        copy, also of every row: the tick's intent keeps them while new goals are taken up)."""
        return np.where(self.has_goal(rows)[:, None], self.goal0[rows], self.goal[rows]), self.key[rows].copy()
