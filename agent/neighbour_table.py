"""A robot's view of its neighbours, built only from their broadcasts."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from operator import attrgetter

import numpy as np

from transport.codec import BEFORE_START, State
from transport.keys import cells_of
from transport.plausible import AHEAD, FUTURE, INCONSISTENT, stamp_agrees

from .core.grid import nearest
from .core.grid import unheard as bodies_unheard
from .core.params import RobotParams
from .core.step import NeighbourStates
from .loop import Sensed


class NeighbourTable:
    """The two newest broadcast states per robot (a lock-step tick uses exactly the previous tick's). A state from
    the future (beyond AHEAD) or with a wrong stamp is refused: kept as newest, it would push the honest ones out."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.now: int | None = None  # the tick the table's robots step (None: not known yet)
        self._states: dict[int, list[State]] = {}

    def advance(self, tick: int) -> None:
        """The table's robots step ``tick`` now; a clock that went back (the tracker restarted) forgets every state."""
        if self.now is not None and tick < self.now:
            self._states.clear()
        elif self.now is None:  # states heard before the first tick were taken unchecked
            plausible = {r: [s for s in kept if s.tick <= tick + AHEAD] for r, kept in self._states.items()}
            self._states = {r: kept for r, kept in plausible.items() if kept}
        self.now = tick

    def update(self, state: State) -> str | None:
        """Keep the two newest states by tick, oldest first; None, or why the state was refused."""
        if self.now is not None and state.tick > self.now + AHEAD:
            return FUTURE
        if not stamp_agrees(state.tick, state.stamp, self.dt):
            return INCONSISTENT
        kept = self._states.setdefault(state.robot, [])
        for k, known in enumerate(kept):
            if known.tick == state.tick:
                # a duplicate; or the body node's standing body (its agent silent) beside its agent's state of
                # the tick: the body's wins whichever came first, as the body stands, and a run stays one run
                if state.flags & State.DYNAMIC and not known.flags & State.DYNAMIC:
                    kept[k] = state
                return None
        kept.append(state)
        if len(kept) > 1 and state.tick < kept[-2].tick:  # out of order (rare): sort only then
            kept.sort(key=attrgetter("tick"))
        if len(kept) > 2:
            del kept[0]
        return None

    def forget_outside(
        self, cells: set[tuple[int, int]], cell_size: float, keep: set[int] | frozenset[int] = frozenset()
    ) -> int:
        """Drop (and count) robots last heard in a cell we no longer hear, phantom obstacles, except ``keep`` (dead)."""
        if not self._states:
            return 0
        at = cells_of([(kept[-1].x, kept[-1].y) for kept in self._states.values()], cell_size).tolist()
        return self._forget([r for r, (cx, cy) in zip(self._states, at) if (cx, cy) not in cells and r not in keep])

    def forget_silent(
        self, now: float, after: float, around: np.ndarray, reach: Callable[[np.ndarray, np.ndarray], np.ndarray],
        keep: set[int] | frozenset[int] = frozenset(),
    ) -> int:  # fmt: skip
        """Drop (and count) robots silent for longer than ``after`` at ``now`` (gone: phantom obstacles), except
        ``keep`` and those that may touch a robot at ``around`` (K,2): last heard within ``reach(radius, age)`` of
        one (robots stand for such a one, agent.core.control.touch_reach), however long their states are lost."""
        silent = [(r, kept[-1]) for r, kept in self._states.items() if kept[-1].stamp < now - after and r not in keep]
        if not silent or not len(around):
            return self._forget([r for r, _ in silent])
        last = np.array([(s.x, s.y, s.radius, s.stamp) for _, s in silent])
        gap = np.hypot(*(last[:, None, :2] - np.asarray(around)[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        near = gap < reach(last[:, 2], now - last[:, 3])
        return self._forget([r for (r, _), n in zip(silent, near.tolist()) if not n])

    def _forget(self, robots: list[int]) -> int:
        for r in robots:
            del self._states[r]
        return len(robots)

    def __len__(self) -> int:
        return len(self._states)

    def __contains__(self, robot: int) -> bool:
        return robot in self._states

    def latest_before(self, tick: int) -> list[State]:
        """For each robot, its newest state stamped before ``tick`` (kept: at most two, oldest first)."""
        return [kept[-1] if kept[-1].tick < tick else kept[0] for kept in self._states.values() if kept[0].tick < tick]

    def gather(
        self, sensed: Sensed, heard_within: float, stopped: dict[int, float], bodies: np.ndarray | None
    ) -> NeighbourStates:
        """Padded neighbour arrays for a batch: the states heard within ``heard_within``; ``stopped``: dead
        agents' robots (static, grown by a last move); ``bodies``: where the tracker saw robots this tick."""
        p, states = sensed.params, self.latest_before(sensed.tick)
        rows = np.array(
            [(s.robot, s.x, s.y, s.vx, s.vy, s.radius, s.stamp, s.flags & State.DYNAMIC) for s in states], float
        ).reshape(-1, 8)  # one pass over the states, one array
        # no robot of the display is smaller than its robots (a forged state's tiny radius is not believed)
        radius = np.maximum(rows[:, 5], p.radius)
        heard = Heard(rows[:, 0].astype(np.int64), rows[:, 1:3], rows[:, 3:5], radius, rows[:, 6], rows[:, 7] == 0)
        for i, s in enumerate(states):
            if s.robot in stopped:
                heard.velocity[i], heard.stamp[i], heard.cooperative[i] = 0.0, sensed.stamp, False
                heard.radius[i] += stopped[s.robot]
        if bodies is not None:
            heard = with_bodies(heard, bodies, sensed.stamp, p)
        return nearest_heard(sensed.ids, sensed.position, sensed.stamp, heard, heard_within, p.max_neighbours)


class TrackedBodies:
    """Where the tracker saw other robots at the last few ticks: a host hears every robot's pose in its
    frames, a robot alone the bodies near it after its own pose (transport.bus.Bus.publish_poses). A
    neighbour whose states are all lost is then still seen, and not driven into (with_bodies)."""

    KEPT = 8  # ticks: a step may act on a tick after later poses arrived

    def __init__(self) -> None:
        self._by_tick: dict[int, np.ndarray] = {}
        self._stepped: int | None = None  # the tick asked for last: the one the robots step

    def hear(self, tick: int, records: np.ndarray) -> None:
        """A Poses frame's records of a tick (on zenoh's thread: the dict is replaced whole). Beyond KEPT
        ticks, those furthest from the tick stepped go: a flood of copies from the future or the past
        (damaged, forged, replayed) cannot push out the frames of the ticks the robots step."""
        if tick == BEFORE_START:
            return
        by_tick = {**self._by_tick, tick: records}
        if len(by_tick) > self.KEPT:  # one more than kept: the furthest, first or last, goes (of two as far, the later)
            near = tick if self._stepped is None else self._stepped
            first, last = min(by_tick), max(by_tick)
            del by_tick[first if near - first > last - near else last]
        self._by_tick = by_tick

    def at(self, tick: int) -> np.ndarray | None:
        """The Poses records the tracker sent of ``tick``, the tick the robots step (None: none heard)."""
        if tick != BEFORE_START:
            self._stepped = tick
        return self._by_tick.get(tick)


def with_bodies(heard: Heard, bodies: np.ndarray, stamp: float, params: RobotParams) -> Heard:
    """``heard``, and each body the tracker saw (``bodies``: Poses records) of a robot with no state newer
    than ``stale_after``, or whose state puts it farther from that body than it could have driven since
    (v_max) and a radius, in place of that state: where it was seen, standing, not cooperating, and stale
    by one tick. Its velocity unknown, robots steer around it as around a stale neighbour, and stand where
    it may touch them (agent.core.control), rather than drive into a robot whose states were lost, or whose
    body is not where it says (driven by someone else, a forged state)."""
    unheard = bodies_unheard(
        np.asarray(heard.ids, np.int64), heard.position, heard.stamp, bodies, stamp, params.stale_after, params.v_max,
        params.radius,
    )  # fmt: skip
    if not unheard.any():
        return heard
    seen = bodies[unheard]
    ids = seen["robot"].astype(np.int64)
    kept = ~np.isin(heard.ids, ids)
    n = len(ids)
    return Heard(
        np.concatenate([heard.ids[kept], ids]),
        np.concatenate([heard.position[kept], np.stack([seen["x"], seen["y"]], axis=1).astype(float)]),
        np.concatenate([heard.velocity[kept], np.zeros((n, 2))]),
        np.concatenate([heard.radius[kept], np.full(n, params.radius)]),
        np.concatenate([heard.stamp[kept], np.full(n, stamp - params.stale_after - params.dt)]),
        np.concatenate([heard.cooperative[kept], np.zeros(n, bool)]),
    )


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
    """The nearest heard states (ties by id), so every engine picks the same neighbours: each robot's rows of
    one table of them."""
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
    return NeighbourStates(idx, table)
