"""How robots hear each other inside one process: the central engine's and the loss study's link.

A state of tick k reaches the others at tick k + 1, as over the bus in lock-step. A seeded draw per
(receiver, sender) and tick may lose it (``drop``) or make it a tick late (``late``), as under
``--faults state:drop=P,delay=S``; ``reach`` limits whom a robot hears.
"""

from __future__ import annotations

import numpy as np

from agent.core.step import NeighbourStates
from agent.neighbour_table import Heard, nearest_heard


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
        if not self.impaired:
            self.last = Heard(*(np.asarray(x)[greeted] for x in vars(states).values()))
            return
        self._template = states
        self.heard_stamp[:, greeted] = states.stamp[greeted]
        self.heard_pos[:, greeted], self.heard_vel[:, greeted] = states.position[greeted], states.velocity[greeted]

    def broadcast(self, states: Heard) -> None:
        """Every robot's state of this tick (rows by robot id)."""
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
        self._template = states

    def _arrive(self, arrive: np.ndarray, states: Heard) -> None:
        self.heard_stamp = np.where(arrive, states.stamp[None, :], self.heard_stamp)
        self.heard_pos = np.where(arrive[..., None], states.position[None], self.heard_pos)
        self.heard_vel = np.where(arrive[..., None], states.velocity[None], self.heard_vel)

    def neighbours(
        self, robot_ids: np.ndarray, position: np.ndarray, stamp: float, neighbour_dist: float, max_neighbours: int
    ) -> NeighbourStates:
        """Each robot's nearest neighbours as it last heard them, by the agents' rule (nearest_heard)."""
        neighbour_dist = min(neighbour_dist, self.reach)
        if not self.impaired:
            if self.last is None:
                return NeighbourStates.empty(len(robot_ids))
            return nearest_heard(robot_ids, position, stamp, self.last, neighbour_dist, max_neighbours, self.threads)
        out = NeighbourStates.empty(len(robot_ids), max_neighbours)
        if self._template is None:
            return out
        t = self._template
        for b, i in enumerate(np.asarray(robot_ids).tolist()):
            known = np.isfinite(self.heard_stamp[i])
            heard = Heard(
                t.ids[known],
                self.heard_pos[i, known],
                self.heard_vel[i, known],
                t.radius[known],
                self.heard_stamp[i, known],
                t.cooperative[known],
            )
            one = nearest_heard([i], position[b : b + 1], stamp, heard, neighbour_dist, max_neighbours)
            k = one.position.shape[1]
            for name in ("position", "velocity", "radius", "age", "valid", "cooperative"):
                getattr(out, name)[b, :k] = getattr(one, name)[0]
        return out

    @property
    def heard_on_time(self) -> float:
        """Share of (receiver, sender) states heard at the next tick (every one on a link without impairment)."""
        return self.on_time / self.draws if self.draws else 1.0
