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


class _StepCache:
    """What the engine keeps between steps so that a step rebuilds nothing that has not changed: the core's
    settings and obstacles, the agent indices, the core's views of the rows and the buffers this engine owns."""

    def __init__(self) -> None:
        self.settings: tuple | None = None  # (what it was made of, the core's Settings)
        self.obstacles: Obstacles | None = None  # the segments as the core reads them (None: to rebuild)
        self.index = np.zeros(0, dtype=np.int64)
        self.ids = np.zeros(0, dtype=np.uint64)
        self.batches: list[tuple[tuple[np.ndarray, ...], Batch]] = []
        self.owned: dict[str, np.ndarray] = {}

    def core_settings(self, horizons: tuple[float, float, float], o: Options) -> Settings:
        if self.settings is None or self.settings[0] != (horizons, o):
            core = Settings(EPUCK, safety=o.safety, margin=o.safety_margin, timeout=0.0, noise=0.0, horizons=horizons)
            self.settings = ((horizons, o), core)
        return self.settings[1]

    def core_obstacles(self, segments: np.ndarray) -> Obstacles:
        if self.obstacles is None:
            self.obstacles = Obstacles(segments)
        return self.obstacles

    def agent_index(self, num_agents: int) -> np.ndarray:
        if len(self.index) != num_agents:
            self.index = np.arange(num_agents, dtype=np.int64)
            self.ids = self.index.astype(np.uint64)
        return self.index

    def buffer(self, name: str, like: np.ndarray) -> np.ndarray:
        """This engine's own (N,2) array ``name``, reused step after step."""
        buf = self.owned.get(name)
        if buf is None or buf.shape != like.shape:
            buf = self.owned[name] = np.empty(like.shape)
        return buf


class CentralOrca:
    """RVO2-like simulator: ``add_agent``, ``add_obstacle``, ``set_pref_velocity``, ``do_step``.

    Its constructor is RVO2's: the time step, then the agent defaults (``defaults``, RVO2's ``setAgentDefaults``).
    After the first step ``position`` and ``velocity`` are the engine's own arrays, written in place by later
    steps: copy them to keep a state.
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
        self._cache = _StepCache()

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
        self._cache.obstacles = None

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
        index = self._cache.agent_index(self.num_agents)
        p = np.ascontiguousarray(self.position, dtype=float)
        return nearest(p, index, p, index, self.defaults.neighbor_dist, self.defaults.max_neighbors, False)

    def preferred(self) -> np.ndarray:
        """The preferred velocities of this step, perturbed if asked for (in a buffer rewritten each step)."""
        if not self.options.perturbation:
            self.pref_velocity = np.ascontiguousarray(self.pref_velocity, dtype=float)
            return self.pref_velocity
        self._cache.agent_index(self.num_agents)
        shift = perturbation(self._cache.ids, self.options.seed, self.steps, self.options.perturbation)
        return np.add(self.pref_velocity, shift, out=self._cache.buffer("pref", shift))

    def _rows(self, pref: np.ndarray) -> Batch:
        """The core's view of the rows, made once per set of arrays (steps write them in place)."""
        for (p, v, w, r, s), rows in self._cache.batches:
            if p is self.position and v is self.velocity and w is pref and r is self.radius and s is self.max_speed:
                return rows
        self.position, self.velocity, self.radius, self.max_speed = (
            np.ascontiguousarray(a, dtype=float) for a in (self.position, self.velocity, self.radius, self.max_speed)
        )
        arrays = (self.position, self.velocity, np.ascontiguousarray(pref, dtype=float), self.radius, self.max_speed)
        rows = Batch(arrays[0], arrays[1], arrays[2], None, arrays[3], arrays[4])
        # two views alive: the velocities alternate between two buffers
        self._cache.batches = [*self._cache.batches[-1:], (arrays, rows)]
        return rows

    def _step_core(self) -> tuple[np.ndarray, np.ndarray]:
        """The new velocities (N,2) in the spare velocity buffer, and fallback flags (N,)."""
        cache = self._cache
        horizons = (self.defaults.time_horizon, self.defaults.time_horizon_obst, self.time_step)
        settings = cache.core_settings(horizons, self.options)
        obstacles = cache.core_obstacles(self.segments)
        robots = self._rows(self.preferred())
        spare = cache.buffer("velocity a", self.velocity)
        if spare is self.velocity:
            spare = cache.buffer("velocity b", self.velocity)
        return step_known(settings, robots, self._neighbours_grid(), obstacles, out=spare)

    def do_step(self) -> None:
        new_velocity, fallback = self._step_core()
        owned = self._cache.owned
        self.velocity = new_velocity
        if self.position is not owned.get("position"):
            self.position = owned["position"] = self.position.copy()
        # position + v dt, as one expression would, in place
        self.position += np.multiply(new_velocity, self.time_step, out=self._cache.buffer("motion", new_velocity))
        self.fallback_count += int(np.count_nonzero(fallback))
        self.steps += 1
