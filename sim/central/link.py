"""How robots hear each other inside one process: the central engine's and the loss study's link.

A state of tick k reaches the others at tick k + 1, as over the bus in lock-step. A seeded draw per
(receiver, sender) and tick may lose it (``drop``) or make it a tick late (``late``), as under
``--faults state:drop=P,delay=S``; ``reach`` limits whom a robot hears. A robot not heard for long
is seen where the tracker sees it, as agents see it in the tracker's frames (with_bodies).
"""

from __future__ import annotations

from typing import cast

import numpy as np

from agent.core.step import NeighbourStates
from agent.loop import Sensed
from agent.neighbour_table import Heard, nearest_heard, with_bodies
from transport.codec import Poses


class InProcessLink:
    """The states of one tick, heard by every robot at the next (optionally lost or late)."""

    def __init__(
        self, robots: int, *, drop: float = 0.0, late: float = 0.0, seed: int = 0, reach: float = np.inf
    ) -> None:
        if not (0.0 <= drop and 0.0 <= late and drop + late <= 1.0):
            raise ValueError(f"drop and late must be probabilities with drop + late <= 1, not {drop}, {late}")
        if not reach > 0:
            raise ValueError(f"the communication range must be a positive distance, not {reach}")
        self.robots, self.drop, self.late, self.reach = robots, drop, late, float(reach)
        self.threads = 1  # that share the neighbour search of every robot at once (set by the engine)
        self.impaired = drop > 0 or late > 0
        self.rng = np.random.default_rng(seed)
        self.last: Heard | None = None  # what everybody heard (no impairment)
        n = robots if self.impaired else 0
        self.heard_stamp = np.full((n, n), -np.inf)  # [receiver, sender]: stamp of the newest state heard (-inf: none)
        self.heard_pos, self.heard_vel = np.zeros((n, n, 2)), np.zeros((n, n, 2))
        self.delayed: tuple[np.ndarray, Heard] | None = None  # states of the last tick that arrive a tick late
        self._template: Heard | None = None  # every robot's ids, radii and kinds (impaired)
        self.on_time = self.draws = 0

    def start(self, states: Heard, greeted: np.ndarray) -> None:
        """Before tick 0: every robot (rows by id) where it stands; those ``greeted`` are heard by all, as
        lock-step agents keep their neighbours' hellos before they start (agent.clocks.LockStep.greet)."""
        self._template = states
        if not self.impaired:
            self.last = Heard(*(np.asarray(x)[greeted] for x in vars(states).values()))
            return
        self._arrive(np.broadcast_to(greeted, (self.robots, self.robots)), states)

    def broadcast(self, states: Heard) -> None:
        """Every robot's state of this tick (rows by robot id)."""
        self._template = states
        if not self.impaired:
            self.last = states
            return
        n = self.robots
        if self.delayed is not None:  # last tick's late states arrive first, so this tick's overwrite them
            self._arrive(*self.delayed)
        u = self.rng.random((n, n))
        arrive, late = u >= self.drop + self.late, (u >= self.drop) & (u < self.drop + self.late)
        self.on_time, self.draws = self.on_time + int(arrive.sum()), self.draws + n * n
        self._arrive(arrive, states)
        self.delayed = (late, states)

    def _arrive(self, arrive: np.ndarray, states: Heard) -> None:
        self.heard_stamp = np.where(arrive, states.stamp[None, :], self.heard_stamp)
        self.heard_pos = np.where(arrive[..., None], states.position[None], self.heard_pos)
        self.heard_vel = np.where(arrive[..., None], states.velocity[None], self.heard_vel)

    def neighbours(self, sensed: Sensed) -> NeighbourStates:
        """Each robot's nearest neighbours as it last heard them, by the agents' rule (nearest_heard), and
        where the tracker sees those it has not heard for long (with_bodies)."""
        p, stamp = sensed.params, sensed.stamp
        within = min(p.neighbour_dist, self.reach)
        if self._template is None:
            return NeighbourStates.empty(len(sensed.ids), p.max_neighbours)
        bodies = self._bodies(sensed)
        if not self.impaired:
            heard = with_bodies(cast(Heard, self.last), bodies, stamp, p)
            return nearest_heard(sensed.ids, sensed.position, stamp, heard, within, p.max_neighbours, self.threads)
        index, t = NeighbourStates.empty(len(sensed.ids), p.max_neighbours).index, self._template
        tables: list[np.ndarray] = []  # each robot's states heard, in the rows of ``index``
        rows = 0  # the rows of those tables so far
        for b, i in enumerate(np.asarray(sensed.ids).tolist()):
            known = np.isfinite(self.heard_stamp[i])
            heard = Heard(
                t.ids[known],
                self.heard_pos[i, known],
                self.heard_vel[i, known],
                t.radius[known],
                self.heard_stamp[i, known],
                t.cooperative[known],
            )
            heard = with_bodies(heard, bodies, stamp, p)
            one = nearest_heard([i], sensed.position[b : b + 1], stamp, heard, within, p.max_neighbours)
            chosen = one.index[0][one.index[0] >= 0]  # the rows of its own table this robot heard
            index[b, : len(chosen)] = np.arange(rows, rows + len(chosen))
            tables.append(one.table[chosen])
            rows += len(chosen)
        return NeighbourStates(index, np.concatenate([np.zeros((0, 7)), *tables]))

    def _bodies(self, sensed: Sensed) -> np.ndarray:
        """Where the tracker sees the agents' robots (not the scripted movers), as the Poses records of its
        frames: ``sensed`` holds every robot, rows by id."""
        t = cast(Heard, self._template)  # rows by id too
        return Poses.records_of(t.ids[t.cooperative], sensed.position[t.cooperative])

    @property
    def heard_on_time(self) -> float:
        """Share of (receiver, sender) states heard at the next tick (every one on a link without impairment)."""
        return self.on_time / self.draws if self.draws else 1.0
