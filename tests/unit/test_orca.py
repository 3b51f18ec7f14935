"""Holonomic ORCA (agent.core.control) against the geometric definitions of eq. 9-12, obstacles, and
the neighbour preparation for real communication."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agent.core import control
from agent.core.control import Batch, Settings, obstacle_line, orca_line, perturbation, preferred_velocity
from agent.core.params import EPUCK
from agent.core.step import NeighbourStates, arena_segments, polygon_segments

coord = st.floats(-5.0, 5.0, allow_nan=False)
speed = st.floats(-2.0, 2.0, allow_nan=False)


def in_vo(w, p, big_r, tau):
    """Eq. 10: does relative velocity w reach the disk D(p, R) within tau?"""
    ww = w @ w
    t = np.clip((w @ p) / ww, 0.0, tau) if ww > 0 else 0.0
    return np.linalg.norm(t * w - p) < big_r


def vo_boundary(p, big_r, tau, n=20000):
    """Dense samples of the boundary of VO^tau: the cut-off arc facing the origin and both legs."""
    dist = np.linalg.norm(p)
    base = np.arctan2(p[1], p[0])
    half = np.arcsin(big_r / dist)
    s0 = np.sqrt(dist**2 - big_r**2) / tau
    pts = []
    for sign in (-1.0, 1.0):
        a = base + sign * half
        s = np.linspace(s0, s0 + 20.0, n)
        pts.append(np.stack([s * np.cos(a), s * np.sin(a)], -1))
    # near arc: from the centre p/tau, the tangent points are at angle base+pi -/+ (pi/2 - half)
    arc = base + np.pi + np.linspace(-(np.pi / 2 - half), np.pi / 2 - half, n)
    pts.append(p / tau + (big_r / tau) * np.stack([np.cos(arc), np.sin(arc)], -1))
    return np.concatenate(pts)


def one_line(p_i, v_i, r_i, p_j, v_j, r_j, c, tau, dt=0.1):
    line = orca_line((*p_i, *v_i, r_i), (*p_j, *v_j, r_j, c), tau, dt)
    return np.array(line[:2]), np.array(line[2:])


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(
    coord,
    coord,
    speed,
    speed,
    speed,
    speed,
    st.floats(0.1, 1.0),
    st.floats(0.1, 1.0),
    st.floats(0.5, 5.0),
    st.sampled_from([0.5, 1.0]),
)
def test_orca_half_plane_matches_the_velocity_obstacle(px, py, vix, viy, vjx, vjy, r_i, r_j, tau, c):
    p = np.array([px, py])
    big_r = r_i + r_j
    assume(np.linalg.norm(p) > big_r + 1e-3)
    v_i, v_j = np.array([vix, viy]), np.array([vjx, vjy])
    v_rel = v_i - v_j
    # v_rel on the line through p (or 0): both legs are equally near, and either is a right answer
    assume(abs(p[0] * v_rel[1] - p[1] * v_rel[0]) > 1e-3 * np.linalg.norm(p))
    point, direction = one_line(np.zeros(2), v_i, r_i, p, v_j, r_j, c, tau)
    boundary = vo_boundary(p, big_r, tau)
    nearest = boundary[np.argmin(np.linalg.norm(boundary - v_rel, axis=1))]
    u = nearest - v_rel  # eq. 11, numerically
    # the point v_opt + c u lies on the line
    off = direction[0] * (v_i[1] + c * u[1] - point[1]) - direction[1] * (v_i[0] + c * u[0] - point[0])
    assert abs(off) < 5e-3
    assert np.allclose(point, v_i + c * u, atol=5e-3)
    # the line is normal to u (u is along the VO's normal at v_rel + u)
    if np.linalg.norm(u) > 1e-2:
        assert abs(direction @ u) / np.linalg.norm(u) < 1e-2
    # its left (permissible) normal is the VO's outward normal at v_rel + u
    normal = np.array([-direction[1], direction[0]])
    assert not in_vo(nearest + 1e-2 * normal, p, big_r, tau)
    assert in_vo(nearest - 1e-2 * normal, p, big_r, tau)


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(
    coord,
    coord,
    speed,
    speed,
    speed,
    speed,
    st.floats(0.1, 1.0),
    st.floats(0.1, 1.0),
    st.floats(0.5, 5.0),
    st.integers(0, 2**32 - 1),
)
def test_velocities_in_the_half_plane_with_full_responsibility_leave_the_vo(
    px, py, vix, viy, vjx, vjy, r_i, r_j, tau, seed
):
    p = np.array([px, py])
    big_r = r_i + r_j
    assume(np.linalg.norm(p) > big_r + 1e-3)
    v_i, v_j = np.array([vix, viy]), np.array([vjx, vjy])
    point, direction = one_line(np.zeros(2), v_i, r_i, p, v_j, r_j, 1.0, tau)
    rng = np.random.default_rng(seed)
    for v in rng.uniform(-6, 6, (200, 2)):
        if direction[0] * (v[1] - point[1]) - direction[1] * (v[0] - point[0]) > 1e-9:
            assert not in_vo(v - v_j, p, big_r * (1 - 1e-9), tau)


def test_overlapping_robots_separate_within_one_control_period():
    rng = np.random.default_rng(3)
    dt = 0.1
    for _ in range(200):
        p = rng.uniform(-0.5, 0.5, 2)
        r_i, r_j = rng.uniform(0.3, 0.6, 2)
        v_i, v_j = rng.uniform(-1, 1, (2, 2))
        point, direction = one_line(np.zeros(2), v_i, r_i, p, v_j, r_j, 1.0, tau=2.0, dt=dt)
        for v in rng.uniform(-20, 20, (50, 2)):
            if direction[0] * (v[1] - point[1]) - direction[1] * (v[0] - point[0]) >= 0:
                assert np.linalg.norm(p - dt * (v - v_j)) >= (r_i + r_j) * (1 - 1e-9)


def test_velocities_in_obstacle_half_planes_keep_the_radius_from_the_edges():
    rng = np.random.default_rng(4)
    square = polygon_segments([(1, 1), (3, 1), (3, 3), (1, 3)])  # counter-clockwise
    segments = np.concatenate([square, arena_segments(-5, -5, 5, 5)])
    pos = rng.uniform(-4.5, 4.5, (400, 2))
    radius, tau_obst = 0.3, 2.0
    t = np.linspace(0.0, tau_obst, 41)
    for b in range(400):
        lines = np.array([obstacle_line(pos[b], radius, seg, tau_obst) for seg in segments])
        for v in rng.uniform(-3, 3, (20, 2)):
            p, d = lines[:, :2], lines[:, 2:]
            if np.all(d[:, 0] * (v[1] - p[:, 1]) - d[:, 1] * (v[0] - p[:, 0]) >= 0):
                path = pos[b] + t[:, None] * v
                for a, e in segments:
                    s = np.clip(((path - a) @ (e - a)) / ((e - a) @ (e - a)), 0, 1)
                    gap = np.linalg.norm(path - (a + s[:, None] * (e - a)), axis=1)
                    start = np.linalg.norm(pos[b] - (a + s[0] * (e - a)))
                    assert np.all(gap >= min(radius, start) - 1e-9)


def test_obstacle_lines_beyond_reach_constrain_no_reachable_velocity():
    # walls 9.9 m away, reach 0.2 m in tau_obst: every velocity of the speed disk (0.1 m/s) is allowed
    for seg in arena_segments(-10, -10, 10, 10):
        px, py, dx, dy = obstacle_line((0.0, 0.0), 0.1, seg, 2.0)
        assert dx * py - dy * px < -0.1  # the disk's worst point, det(d, -0.1 n - p), is permitted


def test_preferred_velocity_follows_eq_9():
    pos = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    goal = np.array([[3.0, 4.0], [0.03, 0.04], [1.0, 1.0], [np.nan, np.nan]])
    v = preferred_velocity(pos, goal, 0.12, 0.1)
    assert np.allclose(v[0], [0.072, 0.096])  # full speed V_p toward the goal
    assert np.allclose(v[1], [0.036, 0.048])  # within K_a: V_p * d / K_a
    assert np.array_equal(v[2], [0.0, 0.0]) and np.array_equal(v[3], [0.0, 0.0])


def test_two_robots_head_on_pass_without_overlap():
    pos = np.array([[-1.0, 0.0], [1.0, 0.0]])
    vel = np.zeros((2, 2))
    goal = -pos
    r, dt = 0.1, 0.1
    core = Settings(EPUCK, margin=0.0, timeout=0.0, noise=0.0, horizons=(2.0, 2.0, dt))
    for _ in range(200):
        pref = preferred_velocity(pos, goal, 0.5, 0.1) + perturbation([0, 1], seed=1)
        vel, fb = control.step_known(core, Batch(pos, vel, pref, None, r, 0.5), np.array([[1], [0]]))
        pos = pos + dt * vel
        assert np.linalg.norm(pos[0] - pos[1]) >= 2 * r
    assert np.allclose(pos, goal, atol=0.02)


def test_neighbour_states_are_extrapolated_by_age_and_stale_ones_become_obstacles():
    pos = np.array([[[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]])
    vel = np.array([[[0.1, 0.0], [0.1, 0.0], [0.1, 0.0]]])
    radius = np.full((1, 3), 0.05)
    age = np.array([[0.0, 0.2, 5.0]])
    core = Settings(replace(EPUCK, v_max=0.13), timeout=1.0, noise=0.002, committed=0.1)
    heard = NeighbourStates.padded(pos, vel, radius, age, np.ones((1, 3), bool), np.ones((1, 3), bool))
    position, _, grown, _, responsibility, _, _ = control.prepare_neighbours(core, heard)
    # fresh: extrapolated by the committed time only (0.1 of its 0.2 s); stale: last known position
    assert np.allclose(position[0, :, 0], [1.0, 2.01, 3.0])
    # fresh: grown by noise + (uncommitted age) x max_speed, where any velocity of its own can have
    # taken it since; stale (not extrapolated): x 2 max_speed, its velocity may have reversed
    assert np.allclose(grown[0], [0.052, 0.05 + 0.002 + 0.1 * 0.13, 0.05 + 0.002 + 0.9 * 0.26])
    assert np.array_equal(responsibility[0], [0.5, 0.5, 1.0])
    nan = NeighbourStates.padded(
        np.full((1, 1, 2), np.nan), vel[:, :1], radius[:, :1], age[:, :1], np.ones((1, 1), bool), np.ones((1, 1), bool)
    )
    position, *_, valid = control.prepare_neighbours(core, nan)
    assert not valid.any() and np.isfinite(position).all()


@pytest.mark.parametrize("kinematics", ["holonomic", "diffdrive"])
def test_a_robot_stops_while_a_stale_neighbour_may_be_where_it_touches_it(kinematics):
    """Not heard for 2 s, a neighbour 0.3 m ahead may be anywhere within 2 s x v_max (0.26 m) of where
    it was: steering around that old place keeps nothing clear, so the robot stands (both v_cf and the
    command), where it drives on with the same neighbour heard lately or a stale one out of reach."""
    params = replace(EPUCK, kinematics=kinematics, v_max=0.13, stale_after=0.5)
    core = Settings(params)

    def step(neighbour_x, age):
        heard = NeighbourStates.padded(
            np.array([[[neighbour_x, 0.1]]]), np.zeros((1, 1, 2)), np.full((1, 1), params.radius),
            np.array([[age]]), np.ones((1, 1), bool), np.ones((1, 1), bool),
        )  # fmt: skip
        pref = np.array([[0.12, 0.0]])
        v, command, *_ = control.step(core, Batch(np.zeros((1, 2)), pref, pref, 0.0, params.radius), heard)
        return np.linalg.norm(v[0]), np.abs(command[0]).max()

    assert step(0.3, age=2.0) == (0.0, 0.0)
    speed, command = step(0.3, age=0.2)  # heard lately: passed by, not stopped for
    assert speed > 0.05 and command > 0.0
    speed, command = step(0.7, age=2.0)  # stale but out of reach (0.26 + 2 dt x v_max + the bodies)
    assert speed > 0.1 and command > 0.0


def test_symmetry_breaking_is_tiny_distinct_and_reproducible():
    a = perturbation(np.arange(100), seed=42, tick=7)
    b = perturbation([0], seed=42, tick=7)
    assert np.abs(a).max() <= 1e-4 and len(np.unique(a[:, 0])) == 100
    assert a[0].tobytes() == b[0].tobytes()
    assert not np.array_equal(a, perturbation(np.arange(100), seed=43, tick=7))


def test_a_robot_steps_bit_identically_alone_or_in_a_batch():
    """An agent host runs K robots per process: each robot's velocity must not depend on K, nor on
    how many neighbour slots the batch pads to."""
    rng = np.random.default_rng(11)
    b, m = 120, 8
    pos = rng.uniform(-2, 2, (b, 2))
    heard = NeighbourStates.padded(
        pos[:, None] + rng.uniform(-0.8, 0.8, (b, m, 2)),
        rng.uniform(-0.5, 0.5, (b, m, 2)),
        np.full((b, m), 0.1),
        rng.uniform(0.0, 0.3, (b, m)),
        rng.random((b, m)) < 0.8,
        rng.random((b, m)) < 0.8,
    )
    vel, pref = rng.uniform(-0.5, 0.5, (b, 2)), rng.uniform(-1, 1, (b, 2))
    walls = np.concatenate(
        [arena_segments(-2.2, -2.2, 2.2, 2.2), polygon_segments([(0, 0), (0.5, 0), (0.5, 0.5), (0, 0.5)])]
    )
    core = Settings(replace(EPUCK, v_max=0.6, tau_obst=1.0))
    v, _, fb, _, _ = control.step(core, Batch(pos, vel, pref, None, 0.1), heard, walls)
    assert 10 < fb.sum() < b - 10
    for i in range(b):
        k = m if i % 2 else int(np.nonzero(heard.valid[i])[0].max(initial=0)) + 1  # less padding
        one = NeighbourStates(heard.index[i : i + 1, :k], heard.table)
        vi, _, fbi, _, _ = control.step(
            core, Batch(pos[i : i + 1], vel[i : i + 1], pref[i : i + 1], None, 0.1), one, walls
        )
        assert vi[0].tobytes() == v[i].tobytes() and fbi[0] == fb[i]
