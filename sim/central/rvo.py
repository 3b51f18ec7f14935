"""A central, synchronous ORCA stepper in RVO2's API shape, on the robots' own compiled core.

Like RVO2's doStep: one snapshot, every robot's new velocity, then all move.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.core.control import Batch, Obstacles, Settings, perturbation, step_known
from agent.core.grid import nearest
from agent.core.params import EPUCK
from agent.core.step import polygon_segments


@dataclass(frozen=True)
class Options:
    """What pixelswarm's core adds to RVO2's step: ``safety_margin`` on every radius in the ORCA lines,
    the safety lines (``safety=False``: RVO2's semantics), seeded ``perturbation`` (id = index, tick = step)."""

    safety_margin: float = 0.0
    safety: bool = True
    perturbation: float = 0.0
    seed: int = 0


@dataclass(frozen=True)
class AgentDefaults:
    """RVO2's ``setAgentDefaults``: what every agent added without its own values gets, and how it looks around."""

    neighbor_dist: float
    max_neighbors: int
    time_horizon: float
    time_horizon_obst: float
    radius: float
    max_speed: float


class CentralOrca:
    """RVO2-like simulator: ``add_agent``, ``add_obstacle``, ``set_pref_velocity``, ``do_step``.

    Its constructor is RVO2's: the time step, then the agent defaults (``defaults``, RVO2's ``setAgentDefaults``).
    Each step makes new ``position`` and ``velocity`` arrays.
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
        options: Options = Options(),
    ) -> None:
        self.time_step = float(time_step)
        self.defaults = AgentDefaults(
            float(neighbor_dist),
            int(max_neighbors),
            float(time_horizon),
            float(time_horizon_obst),
            float(radius),
            float(max_speed),
        )
        self.options = options
        self.position = np.zeros((0, 2))
        self.velocity = np.zeros((0, 2))
        self.pref_velocity = np.zeros((0, 2))
        self.radius = np.zeros(0)
        self.max_speed = np.zeros(0)
        self.segments = np.zeros((0, 2, 2))
        self.steps = 0
        self.fallback_count = 0  # robot-steps where the linear program was infeasible
        horizons = (self.defaults.time_horizon, self.defaults.time_horizon_obst, self.time_step)
        self._settings = Settings(
            EPUCK, safety=options.safety, margin=options.safety_margin, timeout=0.0, noise=0.0, horizons=horizons
        )
        self._obstacles = Obstacles(self.segments)  # the segments as the core reads them

    @property
    def num_agents(self) -> int:
        return len(self.radius)

    def add_agent(
        self, position, velocity=(0.0, 0.0), radius: float | None = None, max_speed: float | None = None
    ) -> int:
        d = self.defaults
        self.position = np.vstack([self.position, np.asarray(position, dtype=float)])
        self.velocity = np.vstack([self.velocity, np.asarray(velocity, dtype=float)])
        self.pref_velocity = np.vstack([self.pref_velocity, np.zeros(2)])
        self.radius = np.append(self.radius, d.radius if radius is None else radius)
        self.max_speed = np.append(self.max_speed, d.max_speed if max_speed is None else max_speed)
        return self.num_agents - 1

    def add_obstacle(self, vertices) -> None:
        """A polygon, counter-clockwise (clockwise for an enclosing wall), as in RVO2."""
        self.segments = np.concatenate([self.segments, polygon_segments(vertices)])
        self._obstacles = Obstacles(self.segments)

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
        return nearest(p, index, p, index, self.defaults.neighbor_dist, self.defaults.max_neighbors, False)

    def preferred(self) -> np.ndarray:
        """The preferred velocities of this step, perturbed if asked for."""
        pref = np.ascontiguousarray(self.pref_velocity, dtype=float)
        if not self.options.perturbation:
            return pref
        ids = np.arange(self.num_agents, dtype=np.uint64)
        return pref + perturbation(ids, self.options.seed, self.steps, self.options.perturbation)

    def do_step(self) -> None:
        rows = Batch(self.position, self.velocity, self.preferred(), None, self.radius, self.max_speed)
        self.velocity, fallback = step_known(self._settings, rows, self._neighbours_grid(), self._obstacles)
        self.position = self.position + self.velocity * self.time_step
        self.fallback_count += int(np.count_nonzero(fallback))
        self.steps += 1
