"""One control step for a batch of robots: preferred velocity, collision avoidance, wheel commands.

Pure, and per robot it reads its own row only (agent.core.control), so K robots in a host drive as K processes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import numpy as np

from .control import Batch, Settings, preferred_velocities, step
from .params import SETTINGS, RobotParams


class Rows:
    """A dataclass of per-robot arrays (a field may itself be Rows): a smaller batch cut out, put back."""

    def rows(self, index: np.ndarray | slice) -> Self:
        """The robots at rows ``index`` (a smaller batch)."""
        return type(self)(*(value[index] for value in vars(self).values()))

    def put(self, index: np.ndarray | slice, other: Self) -> None:
        """Overwrite the rows ``index`` with a smaller batch's values for those robots."""
        for name, value in vars(self).items():
            if isinstance(value, Rows):
                value.put(index, getattr(other, name))
            else:
                value[index] = getattr(other, name)


STATE_COLUMNS = ("x", "y", "vx", "vy", "radius", "age", "cooperative")  # a heard state's row


@dataclass
class NeighbourStates(Rows):
    """What a batch of B robots heard: a table of S states, one row each (:data:`STATE_COLUMNS`: position
    and collision-free velocity as broadcast, radius, seconds since stamped (message stamps, never a wall
    clock), 1 where it runs the same ORCA, 0 a dynamic obstacle), and each robot's up to M of them."""

    index: np.ndarray  # (B,M) int64: rows of ``table``, nearest first; -1 where none
    table: np.ndarray  # (S,7)

    def rows(self, index: np.ndarray | slice) -> NeighbourStates:
        return NeighbourStates(self.index[index], self.table)

    @classmethod
    def empty(cls, batch: int, m: int = 0) -> NeighbourStates:
        return cls(np.full((batch, m), -1, np.int64), np.zeros((0, len(STATE_COLUMNS))))

    @classmethod
    def padded(cls, position, velocity, radius, age, valid, cooperative=True) -> NeighbourStates:
        """From (B,M) arrays of a slot per neighbour (``valid``: a state heard there)."""
        valid = np.asarray(valid, bool)
        columns = [np.reshape(np.broadcast_to(a, valid.shape), -1) for a in (radius, age, cooperative)]
        table = np.column_stack([np.reshape(position, (-1, 2)), np.reshape(velocity, (-1, 2)), *columns])
        return cls(np.where(valid, np.arange(valid.size).reshape(valid.shape), -1), table.astype(float))

    @property
    def valid(self) -> np.ndarray:
        return self.index >= 0

    def column(self, name: str, padding: float = 0.0) -> np.ndarray:
        """(B,M) one column of the states each robot heard (``padding`` where none)."""
        values = self.table[np.maximum(self.index, 0), STATE_COLUMNS.index(name)] if len(self.table) else 0.0
        return np.where(self.valid, values, padding)

    # the same as (B,M) arrays, a slot per neighbour (padding: nowhere, radius 1, cooperative)
    position = property(lambda self: np.stack([self.column("x"), self.column("y")], axis=-1))
    velocity = property(lambda self: np.stack([self.column("vx"), self.column("vy")], axis=-1))
    radius = property(lambda self: self.column("radius", padding=1.0))
    age = property(lambda self: self.column("age"))
    cooperative = property(lambda self: self.column("cooperative", padding=1.0) != 0.0)


@dataclass
class StepResult(Rows):
    velocity: np.ndarray  # (B,2) collision-free holonomic velocity v_cf (broadcast to neighbours)
    command: np.ndarray  # (B,2) holonomic (vx, vy) or wheel speeds (v_left, v_right)
    pref_velocity: np.ndarray  # (B,2) eq. 9
    fallback: np.ndarray  # (B,) bool: the LP was infeasible and the fallback ran


def polygon_segments(vertices) -> np.ndarray:
    """Edges (S,2,2) of a closed polygon: counter-clockwise for an obstacle, clockwise for an enclosing
    wall (RVO2's convention: the free side on the right)."""
    vert = np.asarray(vertices, dtype=float)
    return np.stack([vert, np.roll(vert, -1, axis=0)], axis=1)


def arena_segments(xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    """Walls enclosing the rectangle [xmin,xmax] x [ymin,ymax] (clockwise)."""
    return polygon_segments([(xmin, ymin), (xmin, ymax), (xmax, ymax), (xmax, ymin)])


def static_segments(
    arena: tuple[float, float, float, float] | None, obstacles: list[list[tuple[float, float]]]
) -> np.ndarray:
    """Edges (S,2,2) of the arena wall and the static obstacles (counter-clockwise polygons)."""
    parts = [polygon_segments(o) for o in obstacles]
    if arena is not None:
        parts.append(arena_segments(*arena))
    return np.concatenate(parts) if parts else np.zeros((0, 2, 2))


_SETTINGS: dict[tuple, Settings] = {}


def settings_of(params: RobotParams) -> Settings:
    """The compiled core's settings of ``params``, made once per all but the radius (a late agent grows it
    every tick: RobotParams.grown copies the settings found here along)."""
    found = params.__dict__.get(SETTINGS)
    if found is None:
        key = tuple(value for name, value in vars(params).items() if name != "radius")
        found = _SETTINGS.get(key)
        if found is None:
            found = _SETTINGS[key] = Settings(params)
        object.__setattr__(params, SETTINGS, found)  # a cache beside the fields: equality and to_dict ignore it
    return found


@dataclass(frozen=True)
class Surroundings:
    """What a batch decides within besides its own and heard states: static segments, the perturbation's
    seed and tick, whether an auction acts on deadlocks (else the counts wait), the hearing range (speeds
    within heard_speed_limit), and the threads sharing the rows (the same bits)."""

    segments: np.ndarray | None = None
    seed: int = 0
    tick: int = 0
    watch_deadlocks: bool = False
    reach: float = np.inf
    threads: int = 1


@dataclass
class OwnStates:
    """What each robot of a batch knows of itself when it steps (rows = robots)."""

    ids: np.ndarray  # (B,) the robots' ids (they seed the symmetry-breaking perturbation)
    position: np.ndarray  # (B,2)
    heading: np.ndarray  # (B,)
    velocity: np.ndarray  # (B,2) the last tick's v_cf: ORCA's v_opt
    goal: np.ndarray  # (B,2) NaN: none
    # (B,2): finite rows replace eq. 9 (eq. 27's hold; a moving goal's feed-forward, eq. 28)
    preferred: np.ndarray | None = None
    speed_cap: np.ndarray | None = None  # (B,) m/s its preferred and new velocities keep within (None: v_max)
    chosen: np.ndarray | None = None  # (B,2) whether it barely moves reads this (policy.Memory.chosen; None: velocity)


def control_step(
    params: RobotParams, own: OwnStates, neighbours: NeighbourStates, around: Surroundings = Surroundings()
) -> StepResult:
    """Paper 5.2-5.4 for a batch: preferred velocity (eq. 9), ORCA or NH-ORCA, controls."""
    core = settings_of(params)
    moved = own.velocity if own.chosen is None else own.chosen
    pref = preferred_velocities(
        core, own.ids, own.position, moved, own.goal, own.preferred, around.seed, around.tick, own.speed_cap
    )
    robots = Batch(own.position, own.velocity, pref, own.heading, params.radius, cap=own.speed_cap)
    v_cf, command, fallback, _, _ = step(core, robots, neighbours, around.segments, around.threads)
    return StepResult(v_cf, command, pref, fallback)
