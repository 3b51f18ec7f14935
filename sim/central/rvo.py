"""A central, synchronous ORCA stepper over all robots with perfect information, with RVO2's API shape
(like its doStep: one snapshot, every robot's new velocity, then all move): the engine
bench/bench_orca.py runs beside RVO2 itself.

Neighbours come from agent.core.grid and velocities from agent.core.control, both compiled: the
same code as every robot's, with perfect information.
"""

from __future__ import annotations

import numpy as np

from agent.core.control import Batch, Obstacles, Settings, perturbation, step_known
from agent.core.grid import nearest
from agent.core.params import EPUCK
from agent.core.step import polygon_segments

__all__ = ["CentralOrca"]


class CentralOrca:
    """RVO2-like simulator: ``add_agent``, ``add_obstacle``, ``set_pref_velocity``, ``do_step``.

    Agent defaults mirror RVO2's ``setAgentDefaults`` (neighbour distance, max neighbours, horizons,
    radius, max speed). The options go to the control core (agent.core.control): ``safety_margin`` is
    added to every radius in the robots' ORCA lines (not to the bodies, nor to the safety lines),
    ``safety=False`` gives RVO2's semantics; ``perturbation`` > 0 adds the seeded symmetry breaking
    of `perturbation` (robot id = agent index, tick = step).

    Neighbours, as RVO2's: up to max_neighbors agents closer than neighbor_dist (centre to centre),
    nearest first, equal distances by index.
    """

    def __init__(
        self,
        time_step: float,
        neighbor_dist: float,
        max_neighbors: int,
        time_horizon: float,
        time_horizon_obst: float,
        radius: float,
        max_speed: float,
        *,
        safety_margin: float = 0.0,
        safety: bool = True,
        perturbation: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.time_step = float(time_step)
        self.neighbor_dist = float(neighbor_dist)
        self.max_neighbors = int(max_neighbors)
        self.time_horizon = float(time_horizon)
        self.time_horizon_obst = float(time_horizon_obst)
        self.default_radius = float(radius)
        self.default_max_speed = float(max_speed)
        self.safety_margin = float(safety_margin)
        self.safety = bool(safety)
        self.perturbation = float(perturbation)
        self.seed = int(seed)
        self._settings: tuple | None = None  # (what it was made of, the core's Settings)
        self._obstacles: Obstacles | None = None  # the segments as the core reads them
        self.position = np.zeros((0, 2))
        self.velocity = np.zeros((0, 2))
        self.pref_velocity = np.zeros((0, 2))
        self.radius = np.zeros(0)
        self.max_speed = np.zeros(0)
        self.segments = np.zeros((0, 2, 2))
        self.global_time = 0.0
        self.steps = 0
        self.fallback_count = 0  # robot-steps where the linear program was infeasible
        self.last_fallback = np.zeros(0, dtype=bool)

    @property
    def num_agents(self) -> int:
        return len(self.radius)

    def add_agent(
        self, position, velocity=(0.0, 0.0), radius: float | None = None, max_speed: float | None = None
    ) -> int:
        self.position = np.vstack([self.position, np.asarray(position, dtype=float)])
        self.velocity = np.vstack([self.velocity, np.asarray(velocity, dtype=float)])
        self.pref_velocity = np.vstack([self.pref_velocity, np.zeros(2)])
        self.radius = np.append(self.radius, self.default_radius if radius is None else radius)
        self.max_speed = np.append(self.max_speed, self.default_max_speed if max_speed is None else max_speed)
        return self.num_agents - 1

    def add_obstacle(self, vertices) -> None:
        """A polygon, counter-clockwise (clockwise for an enclosing wall), as in RVO2."""
        self.segments = np.concatenate([self.segments, polygon_segments(vertices)])
        self._obstacles = None

    def set_pref_velocity(self, agent: int, velocity) -> None:
        self.pref_velocity[agent] = velocity

    def set_pref_velocities(self, velocities: np.ndarray) -> None:
        self.pref_velocity[:] = velocities

    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """Up to max_neighbors agents closer than neighbor_dist, nearest first (ties by index):
        (index (N,M), valid (N,M)); invalid slots hold 0."""
        idx = self._neighbours_grid()
        return np.where(idx >= 0, idx, 0), idx >= 0

    def _neighbours_grid(self) -> np.ndarray:
        """(N, M) indices, -1 past the last: RVO2's rule (d^2 < neighbor_dist^2), ties by index."""
        index = np.arange(self.num_agents, dtype=np.int64)
        p = np.ascontiguousarray(self.position, dtype=float)
        return nearest(p, index, p, index, self.neighbor_dist, self.max_neighbors, False)

    def preferred(self) -> np.ndarray:
        """The preferred velocities of this step, perturbed if asked for."""
        if not self.perturbation:
            return self.pref_velocity
        return self.pref_velocity + perturbation(np.arange(self.num_agents), self.seed, self.steps, self.perturbation)

    def compute_new_velocities(self) -> tuple[np.ndarray, np.ndarray]:
        """The new velocities (N,2) and fallback flags (N,): infeasible at the full horizon."""
        horizons = (self.time_horizon, self.time_horizon_obst, self.time_step)
        if self._settings is None or self._settings[0] != (horizons, self.safety, self.safety_margin):
            core = Settings(
                EPUCK, safety=self.safety, margin=self.safety_margin, timeout=0.0, noise=0.0, horizons=horizons
            )
            self._settings = ((horizons, self.safety, self.safety_margin), core)
        if self._obstacles is None:
            self._obstacles = Obstacles(self.segments)
        robots = Batch(self.position, self.velocity, self.preferred(), None, self.radius, self.max_speed)
        return step_known(self._settings[1], robots, self._neighbours_grid(), self._obstacles)

    def do_step(self) -> None:
        new_velocity, fallback = self.compute_new_velocities()
        self.velocity = new_velocity
        self.position = self.position + new_velocity * self.time_step
        self.last_fallback = fallback
        self.fallback_count += int(fallback.sum())
        self.global_time += self.time_step
        self.steps += 1
