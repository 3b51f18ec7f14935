"""The goals robots hold, by row: the one goal bookkeeping of every engine (agent.loop.Robots.goals)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .core.policy import NO_GOAL, no_goal_keys

IDLE_COLOR = (40, 40, 40)


@dataclass
class HeldGoals:
    """Each robot's agreed goal (5.1) or none, where it is now (eq. 28), its key, agreeing instance and LED colour."""

    goal0: np.ndarray  # (N,2) NaN: none
    goal: np.ndarray  # (N,2) NaN: none
    key: np.ndarray  # (N,2) int64 (epoch, goal index)
    instance: np.ndarray  # (N,) int64
    color: np.ndarray  # (N,3) uint8

    @classmethod
    def new(cls, n: int) -> HeldGoals:
        key = no_goal_keys(n)
        color = np.tile(np.array(IDLE_COLOR, np.uint8), (n, 1))
        return cls(np.full((n, 2), np.nan), np.full((n, 2), np.nan), key, np.zeros(n, np.int64), color)

    def drive_to(
        self, rows: np.ndarray, epoch: int, instance: int, index: np.ndarray, positions: np.ndarray, colors: np.ndarray
    ) -> None:
        """The robots at ``rows`` were agreed goals ``index`` of goal set ``epoch``: they drive there, lit."""
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
        """What the policy steers these robots to (a held goal as published, else where sent) and a copy of the keys."""
        return np.where(self.has_goal(rows)[:, None], self.goal0[rows], self.goal[rows]), self.key[rows].copy()
