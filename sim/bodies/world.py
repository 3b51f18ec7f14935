"""The simulated world: N disc robots, their kinematics, actuation noise, arena and obstacles, contacts.

Pure and deterministic (the same calls give bit-identical poses). Contacts are recorded, never resolved:
collision avoidance is the controller's job, and this world measures how well it does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from shapely.geometry import Polygon

from agent.core.params import DIFFDRIVE, EPUCK, HOLONOMIC, KINEMATICS
from coordinator.scene import take_due
from sim.bodies.geometry import (
    make_arena,
    make_polygon,
    polygon_signed_distance,
    rect_signed_distance,
    wrap_angle,
)
from sim.bodies.kinematics import Bodies, actuate, drive, limit
from sim.bodies.proximity import close_pairs, nearest_other

_KINDS = ("robot", "obstacle", "wall")
_KIND_ORDER = {k: n for n, k in enumerate(_KINDS)}
_Overlaps = list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]  # kind, i, j, depth (rows, H) per group


def _number(name: str, value: Any, *, zero: bool = False) -> float:
    """``value`` as a finite float above 0 (at least 0 with ``zero``), or a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, not {value!r}")
    v = float(value)
    if not (math.isfinite(v) and (v >= 0.0 if zero else v > 0.0)):
        raise ValueError(f"{name} must be a finite {'non-negative' if zero else 'positive'} number, not {value!r}")
    return v


@dataclass(frozen=True)
class Body:
    """What the world knows of one robot's body (defaults: the paper's e-puck, Table 1)."""

    kinematics: str  # HOLONOMIC | DIFFDRIVE
    radius: float
    v_max: float
    wheel_base: float = EPUCK.wheel_base
    omega_max: float = EPUCK.omega_max

    def __post_init__(self) -> None:
        if self.kinematics not in KINEMATICS:
            raise ValueError(f"kinematics must be {HOLONOMIC!r} or {DIFFDRIVE!r}, not {self.kinematics!r}")
        for name in ("radius", "v_max", "wheel_base", "omega_max"):
            _number(f"body {name}", getattr(self, name))

    @classmethod
    def from_params(cls, params: Any) -> Body:
        """The body part of an ``agent.core.params.RobotParams`` (or anything with those fields)."""
        return cls(*(getattr(params, f.name) for f in fields(cls)))


@dataclass
class Contact:
    """One contact event (touching is not contact). ``j``: the other robot, the obstacle index, or -1
    (wall). It spans the substeps with overlap (``t_end`` None while ongoing); ``max_depth`` is the deepest
    seen. ``World.step`` returns the live object, so it later shows both."""

    kind: str
    i: int
    j: int
    t_start: float
    t_end: float | None
    max_depth: float


@dataclass(frozen=True)
class ActuationNoise:
    """Actuation noise: ``relative`` to the command, ``absolute`` (m/s) for a moving robot, drawn from
    ``seed`` and held for ``period`` s on a fixed grid of world time, so no call order or chunking of
    ``step`` changes it. The noisy command is clipped to the limits again."""

    relative: float = 0.02
    absolute: float = 0.0
    period: float = EPUCK.dt
    seed: int = 0


DEFAULT_NOISE = ActuationNoise()


def _copy_of(name: str, doc: str) -> Any:
    """A read-only World property: a copy of its motion's array ``name``."""
    return property(lambda world: getattr(world._m, name).copy(), doc=doc + " A copy.")


def _checked_bodies(bodies: Sequence[Body], poses: np.ndarray) -> tuple[list[Body], np.ndarray]:
    """The bodies as a list and their poses as an (N, 3) float array, or a ValueError saying what is wrong."""
    bodies = list(bodies)
    if not bodies:
        raise ValueError("a world needs at least one robot body")
    for k, b in enumerate(bodies):
        if not isinstance(b, Body):
            raise ValueError(f"bodies[{k}] must be a Body, not {type(b).__name__}")
    try:
        p = np.array(poses, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("poses must be an (N, 3) array of numbers (x, y, theta)") from None
    if p.shape != (len(bodies), 3):
        raise ValueError(f"poses must have shape ({len(bodies)}, 3) to match the bodies, not {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("poses must be finite")
    return bodies, p


class World:
    """N disc robots (a mixed swarm allowed) in a plane with optional arena walls and polygon obstacles;
    limits, noise and exact arcs are sim.bodies.kinematics's."""

    def __init__(
        self,
        bodies: Sequence[Body],
        poses: np.ndarray,
        *,
        arena: tuple[float, float, float, float] | None = None,
        obstacles: Sequence[Sequence[tuple[float, float]]] = (),
        noise: ActuationNoise = DEFAULT_NOISE,
        substep: float = 0.01,
    ) -> None:
        bodies, p = _checked_bodies(bodies, poses)
        noise_rel = _number("actuation noise", noise.relative, zero=True)
        noise_abs = _number("absolute actuation noise", noise.absolute, zero=True)
        self.substep = _number("substep", substep)  # the longest integration and contact-check interval (s)
        noise_period = _number("noise period", noise.period)
        seed = noise.seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, not {seed!r}")
        arena = make_arena(arena)
        polygons = [make_polygon(v, k) for k, v in enumerate(obstacles)]

        self.bodies = tuple(bodies)
        self._n = n = len(bodies)
        self._is_diff = np.array([b.kinematics == DIFFDRIVE for b in bodies])
        radius, self._v_max, wheel_base, omega_max = (
            np.array([getattr(b, name) for b in bodies], dtype=float)
            for name in ("radius", "v_max", "wheel_base", "omega_max")
        )
        self._bodies_c = Bodies(self._v_max, self._is_diff, wheel_base, omega_max, noise_rel, noise_abs)

        self._noise = _HeldNoise(n, noise_period, int(seed))
        self._m = _Motion.at_rest(p)
        self._watch = _ContactWatch(radius, arena, polygons)
        self._check_start = False
        self.last_substeps = 0  # number of substeps the last step() ran
        self._substep_times: tuple[tuple[float, int], np.ndarray] = ((math.nan, 0), np.zeros(0))  # (dt, k), its times
        self._unchecked: tuple | None = None  # a step whose contacts are not yet detected (step(check=False))
        self._step_min_clearance = self._watch.detect(self._m.pos[None], np.zeros(1), 0.0, first_row=0)[1]

    @classmethod
    def from_params(cls, params: Any, poses: np.ndarray, **kwargs: Any) -> World:
        """A world from one ``RobotParams`` (for every robot) or a sequence of them (one per robot)."""
        if isinstance(params, (list, tuple)):
            return cls([Body.from_params(p) for p in params], poses, **kwargs)
        return cls([Body.from_params(params)] * len(np.asarray(poses)), poses, **kwargs)

    @property
    def poses(self) -> np.ndarray:
        """(N, 3) x, y, theta (theta in [-pi, pi)); a copy."""
        out = np.empty((self._n, 3))  # not column_stack, which costs four times as much
        out[:, :2], out[:, 2] = self._m.pos, self._m.theta
        return out

    velocities = _copy_of("vel", "(N, 2) world-frame velocity over the last substep (displacement / substep).")
    commands = _copy_of("cmd", "(N, 2) current commands after clipping to the limits.")
    path_length = _copy_of("path", "(N,) distance travelled along the path (arc length), teleports excluded.")
    commands_applied = _copy_of("n_cmd", "(N,) number of set_command calls per robot.")

    @property
    def time(self) -> float:
        return self._m.time

    @property
    def min_clearance(self) -> float:
        """Exact smallest robot-robot clearance (centre distance minus both radii; negative: overlap)
        over every substep state so far; +inf with fewer than two robots."""
        self.check()
        return self._watch.min_clearance

    def step_min_clearance(self) -> float:
        """``min_clearance`` over the states of the last step, its start included (before any step: t = 0)."""
        self.check()
        return self._step_min_clearance

    @property
    def contacts(self) -> list[Contact]:
        """Every contact event so far, in order of start (a new list of the live event objects)."""
        self.check()
        return list(self._watch.events)

    @property
    def active_contacts(self) -> list[Contact]:
        """The ongoing contact events."""
        self.check()
        return sorted(self._watch.active.values(), key=_contact_order)

    def _index(self, i: Any) -> int:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < self._n:
            raise ValueError(f"robot index must be an integer in [0, {self._n}), not {i!r}")
        return int(i)

    def set_command(self, i: int, a: float, b: float) -> None:
        """Holonomic: world-frame (vx, vy); diffdrive: linear wheel speeds (v_left, v_right), m/s."""
        i = self._index(i)
        try:
            a, b = float(a), float(b)
        except (TypeError, ValueError):
            raise ValueError(f"command for robot {i} must be two numbers, not ({a!r}, {b!r})") from None
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"command for robot {i} must be finite, not ({a}, {b})")
        vmax = self._v_max[i]
        if self._is_diff[i]:
            a, b = min(max(a, -vmax), vmax), min(max(b, -vmax), vmax)
        else:
            norm = math.hypot(a, b)
            if norm > vmax:
                a, b = a * vmax / norm, b * vmax / norm
        self._m.cmd[i] = (a, b)
        self._m.n_cmd[i] += 1

    def set_commands(self, commands: np.ndarray) -> None:
        """Every robot's command at once, (N, 2) rows as ``set_command`` takes them, clipped the same way
        (sim.bodies.kinematics.limit, whose norm may differ from math.hypot in the last bit)."""
        c, bad = limit(self._bodies_c, commands)
        if bad >= 0:
            raise ValueError(f"command for robot {bad} must be finite, not {tuple(c[bad])}")
        self._m.cmd[:] = c
        self._m.n_cmd += 1

    def stop(self, i: int) -> None:
        """Zero robot i's command (e.g. its agent crashed); it stays zero until the next set_command."""
        self._m.cmd[self._index(i)] = 0.0

    def teleport(self, i: int, pose: tuple[float, float, float]) -> None:
        """Move robot i to pose (x, y, theta) as if picked up by hand: velocity zero, no path length, the
        command kept; the new state's contacts are checked at the start of the next step."""
        i = self._index(i)
        try:
            x, y, th = (float(v) for v in pose)
        except (TypeError, ValueError):
            raise ValueError(f"teleport pose must be three numbers (x, y, theta), not {pose!r}") from None
        if not all(math.isfinite(v) for v in (x, y, th)):
            raise ValueError(f"teleport pose must be finite, not {pose!r}")
        self._m.pos[i] = (x, y)
        self._m.theta[i] = wrap_angle(th)
        self._m.vel[i] = 0.0
        self._check_start = True

    def teleport_due(self, events: list[dict], t: float) -> None:
        """The scene's scripted teleports due by time t (``events`` sorted by time, taken off as done)."""
        for event in take_due(events, t):
            self.teleport(event["robot"], tuple(event["pose"]))

    def step(self, dt: float, *, check: bool = True) -> list[Contact]:
        """Advance by dt s in ceil(dt / substep) equal substeps, each checked for contacts; the contact events
        that started. ``check=False`` defers that to `check()`, for the engine to overlap with its auction."""
        dt = _number("dt", dt)
        before = self.check()
        k = max(1, math.ceil(dt / self.substep - 1e-9))
        h = dt / k
        if self._substep_times[0] != (dt, k):  # substep times relative to the start of the step (a step's as the last)
            self._substep_times = ((dt, k), np.linspace(0.0, dt, k + 1))
        tk = self._substep_times[1]
        m = self._m
        t0 = m.time

        index, bounds = self._noise.segments(t0, dt)
        eps = 1e-9 * self._noise.period

        pos, theta = m.pos.copy(), m.theta.copy()
        traj = np.empty((k + 1, self._n, 2))
        traj[0] = pos
        ends = np.empty((1, self._n, 2))
        motion = 0.0  # bound on any robot's distance from its start (sum of the longest arcs)
        row = 1
        for seg, (sa, sb) in enumerate(zip(bounds[:-1], bounds[1:])):
            if seg:
                self._noise.draw(index + seg)  # the period after the last segment's
            moving = actuate(self._bodies_c, m.cmd, self._noise.values, theta)
            end = k + 1 if seg == len(bounds) - 2 else int(np.searchsorted(tk, sb + eps, side="right"))
            length = sb - sa
            drive(moving, 0.0, tk[row:end] - sa, pos, traj[row:end])  # the substeps in the segment
            row = end
            drive(moving, 0.0, np.array([length]), pos, ends)  # and its end
            pos = ends[0].copy()
            speed, omega = np.abs(moving[:, 0]), moving[:, 3]
            theta = theta + omega * length
            m.path += speed * length
            motion += float(speed.max()) * length

        m.advance(dt)
        times = t0 + tk
        times[-1] = m.time
        self._unchecked = (traj, times, motion * (1.0 + 1e-9), 0 if self._check_start else 1)

        # velocity: the last substep's chord, computed directly (no cancellation) within the last segment
        if dt - h >= bounds[-2] - eps:
            drive(moving, dt - h - bounds[-2], np.array([h]), np.zeros((self._n, 2)), ends)
            m.vel = ends[0] / h
        else:
            m.vel = (traj[k] - traj[k - 1]) / h
        m.pos = traj[k].copy()
        m.theta = wrap_angle(theta)
        self._check_start = False
        self.last_substeps = k
        return before + (self.check() if check else [])

    def check(self) -> list[Contact]:
        """Detect the contacts of a step run with ``check=False``; the contact events that started in it."""
        if self._unchecked is None:
            return []
        traj, times, motion, first_row = self._unchecked
        self._unchecked = None
        started, self._step_min_clearance = self._watch.detect(traj, times, motion, first_row)
        return started


class _HeldNoise:
    """The actuation noise (ActuationNoise): an (N, 4) standard-normal draw from the world's own
    generator on entering each ``period`` of world time, held for the period whatever the commands."""

    def __init__(self, robots: int, period: float, seed: int) -> None:
        self.period = period
        self.values = np.zeros((robots, 4))
        self.index: int | None = None  # the noise period self.values belongs to
        self.rng = np.random.default_rng(seed)

    def draw(self, index: int) -> None:
        self.values = self.rng.standard_normal((len(self.values), 4))
        self.index = index

    def segments(self, t0: float, dt: float) -> tuple[int, list[float]]:
        """A step's segments of constant actuation, split where a new noise period starts inside it:
        the noise period at its start (its noise drawn) and the segments' bounds (s from t0)."""
        period = self.period
        eps = 1e-9 * period
        index = math.floor((t0 + eps) / period)
        if index != self.index:
            self.draw(index)
        cuts = []
        boundary = (index + 1) * period
        while boundary < t0 + dt - eps:
            cuts.append(boundary - t0)
            boundary += period
        return index, [0.0, *cuts, dt]


@dataclass
class _Motion:
    """What steps, commands and teleports change."""

    pos: np.ndarray  # (N, 2)
    theta: np.ndarray  # (N,) in [-pi, pi)
    cmd: np.ndarray  # (N, 2) after clipping to the limits
    vel: np.ndarray  # (N, 2)
    path: np.ndarray  # (N,) arc length, teleports excluded
    n_cmd: np.ndarray  # (N,) set_command calls
    t_sum: float = 0.0  # time, kept as a compensated (Neumaier) sum: repeated steps of dt add up exactly
    t_comp: float = 0.0

    @classmethod
    def at_rest(cls, poses: np.ndarray) -> _Motion:
        n = len(poses)
        zeros = np.zeros((n, 2))
        return cls(
            poses[:, :2].copy(), wrap_angle(poses[:, 2]), zeros, zeros.copy(), np.zeros(n), np.zeros(n, np.int64)
        )

    @property
    def time(self) -> float:
        return self.t_sum + self.t_comp

    def advance(self, dt: float) -> None:
        s = self.t_sum
        t = s + dt
        if abs(s) >= abs(dt):
            self.t_comp += (s - t) + dt
        else:
            self.t_comp += (dt - t) + s
        self.t_sum = t


class _ContactWatch:
    """The robots' contacts with each other, the walls and the obstacles over a step's substep states;
    the next step's search starts from ``closest``, the pair closest in the last step."""

    def __init__(
        self, radius: np.ndarray, arena: tuple[float, float, float, float] | None, obstacles: list[Polygon]
    ) -> None:
        self.radius, self.r_max, self.n = radius, float(radius.max()), len(radius)
        self.arena, self.obstacles = arena, obstacles
        self.obstacle_bounds = np.array([o.bounds for o in obstacles], dtype=float).reshape(-1, 4)
        self.events: list[Contact] = []
        self.active: dict[tuple[str, int, int], Contact] = {}
        self.min_clearance = math.inf
        self.closest: tuple[int, int] | None = None  # the pair closest during the last step

    def detect(self, traj: np.ndarray, times: np.ndarray, motion: float, first_row: int) -> tuple[list[Contact], float]:
        """Contacts and clearance over the states traj (rows, N, 2) at times (rows,); ``motion`` bounds
        any robot's distance from traj[0]. Rows before ``first_row`` (checked last step) count only for
        the clearance."""
        groups: _Overlaps = []
        step_min = math.inf

        # robot-robot: the pairs within a search radius of each other at the start of the step
        if self.n >= 2:
            step_min, closest, ii, jj, depth = self._robot_pairs(traj, motion, first_row)
            self.closest = closest
            if ii.size:
                groups.append(("robot", ii, jj, depth))
        rows = traj[first_row:]
        if rows.shape[0]:
            groups += self._wall_overlaps(traj[0], rows, motion)
            groups += self._obstacle_overlaps(traj[0], rows, motion)
        self.min_clearance = min(self.min_clearance, step_min)
        return self._update_events(groups, times[first_row:]), step_min

    def _wall_overlaps(self, start: np.ndarray, rows: np.ndarray, motion: float) -> _Overlaps:
        """The robots over a wall in any row: only robots that start within r + motion of one can reach it."""
        if self.arena is None:
            return []
        r = self.radius
        xmin, ymin, xmax, ymax = self.arena
        x, y = start[:, 0], start[:, 1]
        reach = r + motion + 1e-9
        near = np.flatnonzero((x - xmin < reach) | (xmax - x < reach) | (y - ymin < reach) | (ymax - y < reach))
        if not near.size:
            return []
        return _overlapping("wall", -1, near, r[near] - rect_signed_distance(rows[:, near], self.arena))

    def _obstacle_overlaps(self, start: np.ndarray, rows: np.ndarray, motion: float) -> _Overlaps:
        """The robots over an obstacle in any row: only robots whose swept disc may reach its bounding box."""
        out: _Overlaps = []
        r = self.radius
        reach = r + motion + 1e-9
        x, y = start[:, 0], start[:, 1]
        for o, (poly, (x0, y0, x1, y1)) in enumerate(zip(self.obstacles, self.obstacle_bounds)):
            near = np.flatnonzero((x > x0 - reach) & (x < x1 + reach) & (y > y0 - reach) & (y < y1 + reach))
            if near.size == 0:
                continue
            sd = polygon_signed_distance(poly, rows[:, near].reshape(-1, 2)).reshape(rows.shape[0], near.size)
            out += _overlapping("obstacle", o, near, r[near] - sd)
        return out

    def _robot_pairs(
        self, traj: np.ndarray, motion: float, first_row: int
    ) -> tuple[float, tuple[int, int], np.ndarray, np.ndarray, np.ndarray]:
        """The exact smallest robot-robot clearance over the rows, a pair that has it, and the overlapping
        pairs (i, j, depth (rows - first_row, H))."""
        r = self.radius
        base = 2.0 * self.r_max + 2.0 * motion  # any pair that can overlap is within this
        base += 1e-9 * (1.0 + base)
        found = None
        if self.closest is not None:
            # the last step's closest pair bounds this step's minimum (the budget gives up after a teleport)
            a, b = self.closest
            upper = math.hypot(*(traj[0, a] - traj[0, b])) - r[a] - r[b]
            found = close_pairs(traj, r, max(upper, 0.0) + base, motion, first_row, bound=upper, budget=64 * self.n)
        if found is None:
            # pairs beyond base + margin keep a clearance above margin in every row
            margin = 0.5 * self.r_max
            found = close_pairs(traj, r, base + margin, motion, first_row)
            assert found is not None  # without a budget the search is never given up
            if not found[0] < margin:
                # none came that close: bound the search by a pair of nearest neighbours in row 0
                radius = self._nearest_clearance(traj[0], base + margin) + base
                found = close_pairs(traj, r, radius, motion, first_row)
                assert found is not None
        step_min, a, b, pairs, depth = found
        return step_min, (a, b), pairs[:, 0], pairs[:, 1], depth

    def _nearest_clearance(self, xy: np.ndarray, reach: float) -> float:
        """The least clearance (at least 0) of a robot and its nearest neighbour, an upper bound on the
        closest pair's; the reach grows until some robot has a neighbour in it."""
        while True:
            other, apart = nearest_other(xy, reach)
            has = other >= 0
            if has.any():
                gaps = apart[has] - self.radius[has] - self.radius[other[has]]
                return max(float(gaps.min()), 0.0)
            reach *= 4.0

    def _update_events(self, groups: _Overlaps, times: np.ndarray) -> list[Contact]:
        """Start, extend and end contact events from the overlap depths (positive = overlap) per row."""
        started: list[Contact] = []
        active = self.active
        seen: set[tuple[str, int, int]] = set()
        t_list = times.tolist()
        for kind, ii, jj, depth in groups:
            over = depth > 0.0
            steady = np.all(over, axis=0).tolist()  # overlapping in every row: at most a deeper max
            peak = depth.max(axis=0).tolist()
            for c, (i, j) in enumerate(zip(ii.tolist(), jj.tolist())):
                key = (kind, i, j)
                seen.add(key)
                event = active.get(key)
                if event is not None and steady[c]:
                    if peak[c] > event.max_depth:
                        event.max_depth = peak[c]
                    continue
                for row, t in enumerate(t_list):
                    d = float(depth[row, c])
                    if d > 0.0:
                        if event is None:
                            event = Contact(kind, i, j, t, None, d)
                            started.append(event)
                        elif d > event.max_depth:
                            event.max_depth = d
                    elif event is not None:
                        event.t_end = t
                        event = None
                if event is None:
                    active.pop(key, None)
                else:
                    active[key] = event
        if t_list:
            for key in [k for k in active if k not in seen]:  # no overlap in any row: ended at the first
                active.pop(key).t_end = t_list[0]
        started.sort(key=_contact_order)
        self.events.extend(started)
        return started


def _overlapping(kind: str, j: int, near: np.ndarray, depth: np.ndarray) -> _Overlaps:
    """The robots ``near`` whose depth (rows, near) over the wall or obstacle ``j`` is positive in some row."""
    hit = np.flatnonzero(np.any(depth > 0.0, axis=0))
    return [(kind, near[hit], np.full(hit.size, j), depth[:, hit])] if hit.size else []


def _contact_order(c: Contact) -> tuple[float, int, int, int]:
    return (c.t_start, _KIND_ORDER[c.kind], c.i, c.j)
