"""The compiled control core (agent.core.orca_kernel) against the numpy core it stands in for in the
central engine: `prepare_neighbours` then `orca_velocity` (safety lines, shrinking horizon, RVO2's
fallback). The same velocities and fallback flags to the bit, on crowds dense enough that every
branch runs: feasible programs, programs feasible only at a shorter horizon, and the fallback."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent.core.neighbours import prepare_neighbours
from agent.core.orca import arena_segments, orca_velocity, polygon_segments
from agent.core.orca_kernel import control_core
from agent.core.params import RobotParams

P = RobotParams()


def crowd(seed: int, n: int, m: int, side: float, stale: bool) -> dict:
    """n robots in a square of the given side, each with m neighbour states drawn from the others
    (some invalid, some late, some stale, some not cooperating, a few not finite)."""
    rng = np.random.default_rng(seed)
    position = rng.uniform(0.0, side, (n, 2))
    velocity = rng.uniform(-P.v_max, P.v_max, (n, 2))
    pref = rng.uniform(-P.v_max, P.v_max, (n, 2))
    pick = np.stack([rng.permutation(np.delete(np.arange(n), i))[:m] for i in range(n)])
    order = np.argsort(np.hypot(*(position[pick] - position[:, None]).transpose(2, 0, 1)), axis=1)
    pick = np.take_along_axis(pick, order, axis=1)  # nearest first, as the engines give them
    nbr = {
        "position": position[pick] + rng.normal(0.0, 0.002, (n, m, 2)),
        "velocity": velocity[pick].copy(),
        "radius": np.full((n, m), P.radius),
        "age": np.zeros((n, m)) if not stale else rng.choice([0.0, 0.05, 0.3, 0.9, -0.1], (n, m)),
        "valid": rng.random((n, m)) > 0.1,
        "cooperative": rng.random((n, m)) > 0.1,
    }
    if stale:
        nbr["position"][rng.random((n, m)) < 0.02] = np.nan
    return {"position": position, "velocity": velocity, "pref": pref, "nbr": nbr}


def numpy_core(c: dict, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b = c["nbr"]
    nb = prepare_neighbours(
        b["position"],
        b["velocity"],
        b["radius"],
        b["age"],
        b["valid"],
        max_speed=P.v_max,
        timeout=P.stale_after,
        noise=P.noise_bound,
        cooperative=b["cooperative"],
        committed=P.dt,
    )
    return orca_velocity(
        c["position"],
        c["velocity"],
        c["pref"],
        P.radius,
        P.v_max,
        nb.position,
        nb.velocity,
        nb.radius,
        nb.responsibility,
        nb.valid,
        segments,
        tau=P.tau,
        tau_obst=P.tau_obst,
        dt=P.dt,
        margin=P.noise_bound,
        nbr_growth=nb.growth,
        nbr_lead=nb.lead,
    )


def compiled_core(c: dict, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b = c["nbr"]
    return control_core(
        c["position"],
        c["velocity"],
        c["pref"],
        P.radius,
        P.v_max,
        b["position"],
        b["velocity"],
        b["radius"],
        b["age"],
        b["valid"],
        b["cooperative"],
        segments.reshape(-1, 2, 2),
        P.tau,
        P.tau_obst,
        P.dt,
        P.noise_bound,
        P.stale_after,
        P.noise_bound,
        P.dt,
    )


@pytest.mark.parametrize("seed, side, stale", [(0, 3.0, False), (1, 1.2, False), (2, 0.9, True), (3, 2.0, True)])
def test_compiled_core_equals_the_numpy_core_bit_for_bit(seed, side, stale):
    c = crowd(seed, n=300, m=12, side=side, stale=stale)
    segments = np.concatenate(
        [arena_segments(0.0, 0.0, side, side), polygon_segments([(0.4, 0.4), (0.6, 0.4), (0.6, 0.6), (0.4, 0.6)])]
    )
    want_v, want_fallback = numpy_core(c, segments)
    got_v, got_fallback = compiled_core(c, segments)
    np.testing.assert_array_equal(got_fallback, want_fallback)
    np.testing.assert_array_equal(got_v, want_v)


def test_the_crowds_reach_every_branch():
    """The dense crowds above are infeasible for many robots (the fallback and the shorter horizons
    run), the sparse one for few: otherwise the equality would say little about those branches."""
    c = crowd(1, n=300, m=12, side=1.2, stale=False)
    _, fallback = compiled_core(c, arena_segments(0.0, 0.0, 1.2, 1.2))
    assert 30 < fallback.sum() < 300
    c = crowd(0, n=300, m=12, side=3.0, stale=False)
    _, fallback = compiled_core(c, arena_segments(0.0, 0.0, 3.0, 3.0))
    assert fallback.sum() < 100


def test_no_segments_and_no_neighbours():
    c = crowd(4, n=20, m=0, side=5.0, stale=False)
    want = numpy_core(c, np.zeros((0, 2, 2)))
    got = compiled_core(c, np.zeros((0, 2, 2)))
    np.testing.assert_array_equal(got[0], want[0])
    # alone in free space a robot takes its preferred velocity, clipped to the speed disk
    speed = np.hypot(*c["pref"].T)
    alone = speed <= P.v_max
    np.testing.assert_array_equal(got[0][alone], c["pref"][alone])


@pytest.mark.parametrize("segments, given", [(None, False), ("arena", False), ("arena", True)])
def test_control_step_compiled_is_the_control_step(segments, given):
    """The central engine's switch (`control_step(..., compiled=True)`): the same step result, the
    preferred velocity included (eq. 9, a robot without a goal or at it, given rows, turning right
    when blocked, the perturbation), with or without obstacle edges."""
    from agent.core.step import NeighbourStates, control_step

    rng = np.random.default_rng(6)
    c = crowd(5, n=200, m=10, side=1.5, stale=True)
    b = c["nbr"]
    nbrs = NeighbourStates(b["position"], b["velocity"], b["radius"], b["age"], b["valid"], b["cooperative"])
    goal = rng.uniform(0.0, 1.5, (200, 2))
    goal[:10] = np.nan  # no goal
    goal[10:20] = c["position"][10:20]  # at its goal
    goal[20:40] = c["position"][20:40] + rng.uniform(-0.05, 0.05, (20, 2))  # within K_a
    velocity = c["velocity"].copy()
    velocity[40:60] = 0.0  # wants to move and does not: blocked
    preferred = None
    if given:
        preferred = np.full((200, 2), np.nan)
        preferred[60:90] = rng.uniform(-0.3, 0.3, (30, 2))
        preferred[90:95, 0] = 0.1  # half a row: eq. 9
    seg = None if segments is None else arena_segments(0.0, 0.0, 1.5, 1.5)
    holonomic = dataclasses.replace(P, kinematics="holonomic")  # the switch is for holonomic robots
    args = (holonomic, np.arange(200) * 7 + 3, c["position"], np.zeros(200), velocity, goal, nbrs, seg)
    want = control_step(*args, seed=3, tick=7, preferred=preferred)
    got = control_step(*args, seed=3, tick=7, preferred=preferred, compiled=True)
    for name in ("velocity", "command", "pref_velocity", "fallback"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert want.fallback.any()  # the crowd is dense enough for the fallback to matter
    assert (want.pref_velocity[:10] == 0.0).all()  # no goal, no perturbation


@pytest.mark.parametrize("seed, side, safety", [(7, 1.2, True), (8, 1.2, False), (9, 3.0, False)])
def test_central_core_equals_orca_velocity_bit_for_bit(seed, side, safety):
    """The central engine's entry (agent.core.rvo.CentralOrca): neighbours are rows of the batch,
    known now and cooperating (responsibility 0.5, no growth), radius and speed per robot, RVO2's
    program without ``safety`` (no safety lines, least violation at the full horizon)."""
    from agent.core.orca_kernel import central_core

    rng = np.random.default_rng(seed)
    n, m = 300, 12
    c = crowd(seed, n=n, m=m, side=side, stale=False)
    radius = rng.uniform(0.5, 1.5, n) * P.radius
    vmax = rng.uniform(0.5, 1.5, n) * P.v_max
    pick = np.stack([rng.permutation(np.delete(np.arange(n), i))[:m] for i in range(n)])
    dist = np.hypot(*(c["position"][pick] - c["position"][:, None]).transpose(2, 0, 1))
    pick = np.take_along_axis(pick, np.argsort(dist, axis=1), axis=1)
    valid = rng.random((n, m)) > 0.1
    segments = np.concatenate(
        [arena_segments(0.0, 0.0, side, side), polygon_segments([(0.4, 0.4), (0.6, 0.4), (0.6, 0.6), (0.4, 0.6)])]
    )
    want_v, want_fallback = orca_velocity(
        c["position"],
        c["velocity"],
        c["pref"],
        radius,
        vmax,
        c["position"][pick],
        c["velocity"][pick],
        radius[pick],
        np.full((n, m), 0.5),
        valid,
        segments,
        tau=P.tau,
        tau_obst=P.tau_obst,
        dt=P.dt,
        safety=safety,
        margin=P.noise_bound,
    )
    got_v, got_fallback = central_core(
        c["position"],
        c["velocity"],
        c["pref"],
        radius,
        vmax,
        np.where(valid, pick, -1),
        segments,
        P.tau,
        P.tau_obst,
        P.dt,
        P.noise_bound,
        safety,
    )
    assert 0 < want_fallback.sum() < n  # the fallback ran for some, not all
    np.testing.assert_array_equal(got_fallback, want_fallback)
    np.testing.assert_array_equal(got_v, want_v)
