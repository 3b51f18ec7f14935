"""A robot's view of its neighbours, built only from their broadcasts."""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter

import numpy as np

from transport.codec import State
from transport.keys import cells_of
from transport.plausible import AHEAD, FUTURE, INCONSISTENT, stamp_agrees

from .core.grid import nearest, neighbour_rows
from .core.step import NeighbourStates

_tick = attrgetter("tick")


class NeighbourTable:
    """Latest broadcast states per robot id, keeping the two newest so a lock-step tick can use
    exactly the states of the previous tick (the same information whatever the arrival order).

    A state may not claim a tick beyond the table's clock (``advance``: the tick its robots step)
    by more than transport.plausible.AHEAD, nor a stamp other than its tick's start: kept as the
    newest, a state from the future would push the honest ones out."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.now: int | None = None  # the tick the table's robots step (None: not known yet)
        self._states: dict[int, list[State]] = {}

    def advance(self, tick: int) -> None:
        """The table's robots step ``tick`` now. A clock that went back (the tracker restarted,
        counting from 0 again) makes every state held newer than anything to come: forget them."""
        if self.now is not None and tick < self.now:
            self._states.clear()
        elif self.now is None:  # states heard before the first tick were taken unchecked
            for robot, kept in list(self._states.items()):
                kept[:] = [s for s in kept if s.tick <= tick + AHEAD]
                if not kept:
                    del self._states[robot]
        self.now = tick

    def update(self, state: State) -> str | None:
        """Keep the two newest states by tick, oldest first; None, or why the state was refused."""
        if self.now is not None and state.tick > self.now + AHEAD:
            return FUTURE
        if not stamp_agrees(state.tick, state.stamp, self.dt):
            return INCONSISTENT
        kept = self._states.get(state.robot)
        if kept is None:
            self._states[state.robot] = [state]
            return None
        if kept[-1].tick == state.tick or kept[0].tick == state.tick:
            return None  # duplicate (of one of the at most two kept)
        kept.append(state)
        if state.tick < kept[-2].tick:  # out of order (rare): sort only then
            kept.sort(key=_tick)
        if len(kept) > 2:
            del kept[0]
        return None

    def forget_outside(
        self, cells: set[tuple[int, int]], cell_size: float, keep: set[int] | frozenset[int] = frozenset()
    ) -> int:
        """Drop robots whose newest state lies in a cell we no longer listen to, except ``keep``
        (robots whose agent died: their bodies stand where they were last heard). We cannot hear the
        others any more, and an aged state's uncertainty grows without bound: a phantom obstacle.
        Returns how many were dropped."""
        if not self._states:
            return 0
        at = cells_of([(kept[-1].x, kept[-1].y) for kept in self._states.values()], cell_size).tolist()
        return self._forget([r for r, (cx, cy) in zip(self._states, at) if (cx, cy) not in cells and r not in keep])

    def forget_silent(self, before: float, keep: set[int] | frozenset[int] = frozenset()) -> int:
        """Drop robots whose newest state is stamped before ``before`` (display time), except ``keep``
        (as in forget_outside). A robot near ours is heard every period; one silent for longer has left
        our cells, and its last state, in a cell we still listen to, would stay for good as a phantom
        obstacle. Returns how many were dropped."""
        return self._forget([r for r, kept in self._states.items() if kept[-1].stamp < before and r not in keep])

    def _forget(self, robots: list[int]) -> int:
        for r in robots:
            del self._states[r]
        return len(robots)

    def __len__(self) -> int:
        return len(self._states)

    def __contains__(self, robot: int) -> bool:
        return robot in self._states

    def latest_before(self, tick: int) -> list[State]:
        """For each robot, its newest state stamped before ``tick``."""
        out = []
        for kept in self._states.values():
            for s in reversed(kept):
                if s.tick < tick:
                    out.append(s)
                    break
        return out

    def gather(
        self,
        robot_ids: list[int],
        positions: np.ndarray,
        stamp: float,
        tick: int,
        neighbour_dist: float,
        max_neighbours: int,
        stopped: dict[int, float] | None = None,
    ) -> NeighbourStates:
        """Padded neighbour arrays for a batch: the nearest ``max_neighbours`` within ``neighbour_dist``.

        ``stopped``: robots whose agent is dead (liveliness lost), with how far they may have moved
        after their last state. Their bodies stand still (the world or hardware proxy stops a robot
        whose agent died), so they are static obstacles at their last position, grown by that
        distance, instead of silent robots whose possible position grows with age without bound."""
        states = self.latest_before(tick)
        if not states:
            return NeighbourStates.empty(len(robot_ids))
        rows = np.array(
            [(s.robot, s.x, s.y, s.vx, s.vy, s.radius, s.stamp, s.flags & State.DYNAMIC) for s in states], float
        )  # one pass over the states, one array
        heard = Heard(
            rows[:, 0].astype(np.int64), rows[:, 1:3], rows[:, 3:5], rows[:, 5].copy(), rows[:, 6], rows[:, 7] == 0
        )
        if stopped:
            for i, s in enumerate(states):
                if s.robot in stopped:
                    heard.velocity[i], heard.stamp[i], heard.cooperative[i] = 0.0, stamp, False
                    heard.radius[i] += stopped[s.robot]
        return nearest_heard(robot_ids, positions, stamp, heard, neighbour_dist, max_neighbours)


@dataclass
class Heard:
    """The newest state heard of each of S robots, as arrays (any order)."""

    ids: np.ndarray  # (S,) robot ids
    position: np.ndarray  # (S,2) as broadcast
    velocity: np.ndarray  # (S,2) its collision-free velocity
    radius: np.ndarray  # (S,)
    stamp: np.ndarray  # (S,) display time of the state
    cooperative: np.ndarray  # (S,) bool: runs the same ORCA (False: a dynamic obstacle)


def nearest_heard(
    robot_ids,
    positions: np.ndarray,
    stamp: float,
    heard: Heard,
    neighbour_dist: float,
    max_neighbours: int,
    threads: int = 1,
) -> NeighbourStates:
    """Padded neighbour arrays for a batch at display time ``stamp``: each robot's nearest
    ``max_neighbours`` heard states within ``neighbour_dist`` of it (never its own), nearest first,
    ties by robot id (agent.core.grid.nearest), so every process and engine picks the same neighbours
    from the same states, for one robot, a host's K or all of them (on ``threads`` threads)."""
    batch = len(robot_ids)
    if len(heard.ids) == 0:
        return NeighbourStates.empty(batch)
    f64 = np.ascontiguousarray
    idx = nearest(
        f64(positions, dtype=float).reshape(batch, 2),
        f64(robot_ids, dtype=np.int64).reshape(batch),
        f64(heard.position, dtype=float),
        f64(heard.ids, dtype=np.int64),
        float(neighbour_dist),
        int(max_neighbours),
        threads=threads,
    )
    table = np.empty((len(heard.ids), 7))  # per state: x, y, vx, vy, radius, age, cooperative
    table[:, 0:2], table[:, 2:4], table[:, 4] = heard.position, heard.velocity, heard.radius
    table[:, 5], table[:, 6] = stamp - np.asarray(heard.stamp, float), heard.cooperative
    return NeighbourStates(*neighbour_rows(idx, table))
