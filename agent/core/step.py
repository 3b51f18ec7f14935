"""One control step for a batch of robots: preferred velocity, collision avoidance, wheel commands.

Pure: arrays in, arrays out. The same function serves one robot in its own process, K robots in an
agent host, and the central engine that steps every robot with perfect information. Per robot the
result does not depend on the other robots of the batch (elementwise arithmetic only), so a host of
K robots drives exactly as K separate processes would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np

from .neighbours import perturb_preferred_velocity, perturbation_one, prepare_neighbours, splitmix64
from .orca import arena_segments, orca_velocity, polygon_segments, preferred_velocity
from .params import DIFFDRIVE, RobotParams


@dataclass
class NeighbourStates:
    """What a batch of B robots heard from up to M neighbours each (padded; ``valid`` marks real ones)."""

    position: np.ndarray  # (B,M,2) as broadcast
    velocity: np.ndarray  # (B,M,2) their collision-free velocity
    radius: np.ndarray  # (B,M)
    age: np.ndarray  # (B,M) seconds since the state was stamped (from message stamps, never a wall clock)
    valid: np.ndarray  # (B,M) bool
    cooperative: np.ndarray  # (B,M) bool: runs the same ORCA (False: a dynamic obstacle)

    @classmethod
    def empty(cls, batch: int, m: int = 0) -> NeighbourStates:
        return cls(
            np.zeros((batch, m, 2)),
            np.zeros((batch, m, 2)),
            np.ones((batch, m)),
            np.zeros((batch, m)),
            np.zeros((batch, m), bool),
            np.ones((batch, m), bool),
        )

    def rows(self, index: np.ndarray) -> NeighbourStates:
        """What the robots at rows ``index`` of the batch heard (a smaller batch)."""
        return NeighbourStates(
            self.position[index],
            self.velocity[index],
            self.radius[index],
            self.age[index],
            self.valid[index],
            self.cooperative[index],
        )


@dataclass
class StepResult:
    velocity: np.ndarray  # (B,2) collision-free holonomic velocity v_cf (broadcast to neighbours)
    command: np.ndarray  # (B,2) holonomic (vx, vy) or wheel speeds (v_left, v_right)
    pref_velocity: np.ndarray  # (B,2) eq. 9
    fallback: np.ndarray  # (B,) bool: the LP was infeasible and the fallback ran


def static_segments(
    arena: tuple[float, float, float, float] | None, obstacles: list[list[tuple[float, float]]]
) -> np.ndarray:
    """Edges (S,2,2) of the arena wall and the static obstacles (counter-clockwise polygons)."""
    parts = [polygon_segments(o) for o in obstacles]
    if arena is not None:
        parts.append(arena_segments(*arena))
    return np.concatenate(parts) if parts else np.zeros((0, 2, 2))


_COS, _SIN = np.cos(-np.pi / 4), np.sin(-np.pi / 4)  # 45 degrees clockwise
_f64 = partial(np.ascontiguousarray, dtype=float)


def keep_right_when_blocked(pref: np.ndarray, velocity: np.ndarray, v_pref: float) -> np.ndarray:
    """A robot that wants to move but barely does (a symmetric jam: ORCA's reciprocal half-planes
    can cancel exactly) turns its preferred velocity 45 degrees to the right. Every robot applying
    the same rule turns a standoff into a roundabout. Stateless, so every process agrees."""
    want = np.hypot(pref[:, 0], pref[:, 1])
    moving = np.hypot(velocity[:, 0], velocity[:, 1])
    blocked = (want > 0.5 * v_pref) & (moving < 0.25 * want)
    # elementwise, not a matrix product: BLAS may sum differently for different batch sizes
    turned = np.stack([_COS * pref[:, 0] - _SIN * pref[:, 1], _SIN * pref[:, 0] + _COS * pref[:, 1]], axis=1)
    return np.where(blocked[:, None], turned, pref)


def _preferred_one(params, robot_ids, position, velocity, goal, seed, tick, preferred) -> np.ndarray | None:
    """control_step's preferred velocity for a batch of one robot on Python floats and ints: eq. 9,
    a given row, keep right when blocked, the perturbation; the same operations in the same order
    as the numpy code (numpy's per-call overhead dominates on arrays of one). None where the
    arguments are not plain float and integer arrays."""
    ids = np.asarray(robot_ids)
    if ids.dtype.kind not in "iu" or ids.size != 1:
        return None
    position, velocity, goal = np.asarray(position), np.asarray(velocity), np.asarray(goal)
    if any(a.dtype != np.float64 for a in (position, velocity, goal)):
        return None
    (px, py), (vx, vy), (gx, gy) = position[0].tolist(), velocity[0].tolist(), goal[0].tolist()
    v_pref, k_a = float(params.v_pref), float(params.k_a)
    # orca.preferred_velocity
    ex, ey = gx - px, gy - py
    dist = math.sqrt(ex * ex + ey * ey)  # nan stays nan
    if math.isfinite(dist) and dist > 0.0:
        gain = v_pref / dist if dist > k_a else v_pref / k_a
        pref_x, pref_y = ex * gain, ey * gain
    else:
        pref_x, pref_y = 0.0, 0.0
    if preferred is not None:
        given = np.asarray(preferred)
        if given.dtype != np.float64:
            return None
        gx, gy = given[0].tolist()
        if math.isfinite(gx) and math.isfinite(gy):
            pref_x, pref_y = gx, gy
    # keep_right_when_blocked (numpy's hypot, not math's: they may round differently)
    want = float(np.hypot(pref_x, pref_y))
    if want > 0.5 * v_pref and float(np.hypot(vx, vy)) < 0.25 * want:
        pref_x, pref_y = _COS * pref_x - _SIN * pref_y, _SIN * pref_x + _COS * pref_y
    # neighbours.perturb_preferred_velocity where the preferred velocity is not zero
    if pref_x != 0 or pref_y != 0:
        dx, dy = perturbation_one(int(ids.reshape(-1)[0]), seed, tick)
        pref_x, pref_y = pref_x + dx, pref_y + dy
    return np.array([[pref_x, pref_y]])


def control_step(
    params: RobotParams,
    robot_ids: np.ndarray,
    position: np.ndarray,
    heading: np.ndarray,
    velocity: np.ndarray,
    goal: np.ndarray,
    neighbours: NeighbourStates,
    segments: np.ndarray | None = None,
    *,
    seed: int = 0,
    tick: int = 0,
    preferred: np.ndarray | None = None,
    compiled: bool = False,
) -> StepResult:
    """Paper 5.2-5.4 for a batch: preferred velocity (eq. 9), ORCA or NH-ORCA, controls.

    preferred (B,2), optional: rows with finite values replace eq. 9 (eq. 27 held in an animation
    frame, or the feed-forward toward a moving goal of a dynamic image, agent.core.animation and
    agent.core.goal_motion); NaN rows use eq. 9.
    compiled: holonomic robots get the same velocities, bit for bit, from the compiled core
    (agent.core.orca_kernel: the central engine's fast path; agent processes never load numba)."""
    if compiled and params.kinematics != DIFFDRIVE:
        return _compiled_step(params, robot_ids, position, velocity, goal, neighbours, segments, seed, tick, preferred)
    pref = None
    if len(position) == 1:
        pref = _preferred_one(params, robot_ids, position, velocity, goal, seed, tick, preferred)
    if pref is None:
        pref = preferred_velocity(position, goal, params.v_pref, params.k_a)
        if preferred is not None:
            given = np.isfinite(preferred).all(axis=1)
            pref = np.where(given[:, None], np.where(given[:, None], preferred, 0.0), pref)
        pref = keep_right_when_blocked(pref, velocity, params.v_pref)
        # A tiny deterministic perturbation breaks the symmetric head-on configurations that deadlock ORCA.
        pref = np.where(
            np.any(pref != 0, axis=1, keepdims=True), perturb_preferred_velocity(pref, robot_ids, seed, tick), pref
        )
    nb = prepare_neighbours(
        neighbours.position,
        neighbours.velocity,
        neighbours.radius,
        neighbours.age,
        neighbours.valid,
        max_speed=params.v_max,
        timeout=params.stale_after,
        noise=params.noise_bound,
        cooperative=neighbours.cooperative,
        committed=params.dt,
    )
    if params.kinematics == DIFFDRIVE:
        from .nhorca import nh_orca_wheel_speeds  # a holonomic robot's process never loads NH-ORCA

        res = nh_orca_wheel_speeds(
            position,
            heading,
            velocity,
            pref,
            params.radius,
            nb.position,
            nb.velocity,
            nb.radius,
            nb.responsibility,
            nb.valid,
            segments,
            params=params,
            nbr_growth=nb.growth,
            nbr_lead=nb.lead,
        )
        command = np.stack([res.wheel_left, res.wheel_right], axis=1)
        return StepResult(res.velocity, command, pref, res.fallback)
    v_cf, fallback = orca_velocity(
        position,
        velocity,
        pref,
        params.radius,
        params.v_max,
        nb.position,
        nb.velocity,
        nb.radius,
        nb.responsibility,
        nb.valid,
        segments,
        tau=params.tau,
        tau_obst=params.tau_obst,
        dt=params.dt,
        margin=params.noise_bound,
        nbr_growth=nb.growth,
        nbr_lead=nb.lead,
    )
    return StepResult(v_cf, v_cf, pref, fallback)


def _compiled_step(
    params: RobotParams,
    robot_ids: np.ndarray,
    position: np.ndarray,
    velocity: np.ndarray,
    goal: np.ndarray,
    neighbours: NeighbourStates,
    segments: np.ndarray | None,
    seed: int,
    tick: int,
    preferred: np.ndarray | None,
) -> StepResult:
    """control_step for holonomic robots, compiled (agent.core.orca_kernel): the same result."""
    from .orca_kernel import control_core, preferred_core

    given = np.full((len(position), 2), np.nan) if preferred is None else _f64(preferred)
    seed_key = splitmix64(np.uint64(seed % 2**64))
    pref = preferred_core(
        _f64(position),
        _f64(goal),
        given,
        _f64(velocity),
        np.ascontiguousarray(robot_ids).astype(np.uint64),
        float(params.v_pref),
        float(params.k_a),
        seed_key,
        np.uint64(tick % 2**64),
    )
    seg = np.zeros((0, 2, 2)) if segments is None else _f64(segments).reshape(-1, 2, 2)
    v_cf, fallback = control_core(
        position,
        velocity,
        pref,
        params.radius,
        params.v_max,
        neighbours.position,
        neighbours.velocity,
        neighbours.radius,
        neighbours.age,
        neighbours.valid,
        neighbours.cooperative,
        seg,
        params.tau,
        params.tau_obst,
        params.dt,
        params.noise_bound,
        params.stale_after,
        params.noise_bound,
        params.dt,
    )
    return StepResult(v_cf, v_cf, pref, fallback)
