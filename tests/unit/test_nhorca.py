"""NH-ORCA for differential-drive robots (agent.core.control): closed forms against a numerical
simulation of the tracking error, P_AHV, the controls, and a small closed-loop run."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from agent.core import control
from agent.core.control import Batch, Settings, ahv_polygon, controls, min_error_speed, perturbation, tracking_error
from agent.core.params import EPUCK
from agent.core.step import NeighbourStates

DIFFDRIVE = replace(EPUCK, kinematics="diffdrive")
CORE = Settings(DIFFDRIVE, noise=0.0)  # neighbours as they are: no tracking noise to grow them by


def max_trackable_speed(theta, error):
    return float(control.max_trackable_speed(CORE, theta, error))


def nh_orca(position, heading, velocity, pref, heard):
    """One NH-ORCA step: (v_cf, wheel speeds (left, right), fallback, reverse, tracking error)."""
    return control.step(CORE, Batch(position, velocity, pref, heading, EPUCK.radius), heard)


def simulate_error(theta, v_h, v, omega, duration, steps=4000):
    """Largest distance between a unicycle (speed v, turn rate omega, heading 0) and the holonomic
    trajectory t v_h (cos theta, sin theta) over [0, duration], by small exact-arc steps."""
    x = y = h = 0.0
    dt = duration / steps
    worst = 0.0
    for k in range(1, steps + 1):
        mid = h + 0.5 * omega * dt
        x += v * dt * math.cos(mid)
        y += v * dt * math.sin(mid)
        h += omega * dt
        t = k * dt
        worst = max(worst, math.hypot(x - v_h * t * math.cos(theta), y - v_h * t * math.sin(theta)))
    return worst


def epuck_controls(theta, v_h):
    w = math.copysign(min(abs(theta) / EPUCK.t_orient, CORE.omega_cap), theta)
    v = max(0.0, min(float(min_error_speed(v_h, theta)), EPUCK.v_max - abs(w) * EPUCK.wheel_base / 2))
    return v, w, (abs(theta) / abs(w) if w else EPUCK.t_orient)


# angles covering case A (~0.8), case B (0.3, 1.5), case C (> T omega_cap = 1.73), clipped (0.05)
@pytest.mark.parametrize("theta", [0.05, 0.3, 0.8, 1.2, 1.5, 1.8, 2.5, 3.1, -0.8, -2.5])
@pytest.mark.parametrize("error", [0.01, 0.003])
def test_closed_form_max_speed_matches_simulated_tracking_error(theta, error):
    v_max_h = max_trackable_speed(theta, error)
    v, w, duration = epuck_controls(theta, v_max_h)
    err = simulate_error(theta, v_max_h, v, w, duration)
    assert err <= error * (1 + 1e-3)
    if v_max_h < EPUCK.v_max - 1e-12:  # not clipped: the bound is tight
        assert err >= error * (1 - 1e-3)
        v2, w2, d2 = epuck_controls(theta, 1.02 * v_max_h)
        assert simulate_error(theta, 1.02 * v_max_h, v2, w2, d2) > error


@pytest.mark.parametrize("theta", [0.2, 0.7, 1.3, 2.0, 2.9])
def test_min_error_speed_minimises_the_tracking_error(theta):
    v_h, t = 0.1, EPUCK.t_orient
    grid = np.linspace(0.0, 0.2, 401)
    errs = [simulate_error(theta, v_h, v, theta / t, t, steps=400) for v in grid]
    assert abs(grid[int(np.argmin(errs))] - float(min_error_speed(v_h, theta))) <= 0.2 / 400 + 1e-12


def test_ahv_polygon_lies_in_s_ahv_and_contains_the_origin():
    rng = np.random.default_rng(5)
    for error in (EPUCK.error_min, 0.004, EPUCK.error_max):
        heading = rng.uniform(-np.pi, np.pi)
        lines = ahv_polygon(CORE, heading, error)
        vert, p, d = lines[:, :2], lines[:, :2], lines[:, 2:]
        assert np.all(d[:, 0] * (0 - p[:, 1]) - d[:, 1] * (0 - p[:, 0]) > 0)  # origin strictly inside
        for k in range(len(vert)):
            for s in np.linspace(0, 1, 51):
                q = vert[k] + s * (vert[(k + 1) % len(vert)] - vert[k])
                rel = math.atan2(q[1], q[0]) - heading
                bound = max_trackable_speed(math.atan2(math.sin(rel), math.cos(rel)), error)
                assert np.hypot(*q) <= bound * (1 + 1e-9)


def test_controls_respect_wheel_speed_and_turn_rate_limits():
    rng = np.random.default_rng(6)
    vel = rng.uniform(-1, 1, (500, 2)) * rng.choice([0.01, 0.13, 1.0], (500, 1))
    heading = rng.uniform(-np.pi, np.pi, 500)
    reverse = rng.random(500) < 0.3
    v, w = np.array([controls(CORE, vel[i], heading[i], reverse[i]) for i in range(500)]).T
    left, right = v - w * EPUCK.wheel_base / 2, v + w * EPUCK.wheel_base / 2
    assert np.all(np.abs(left) <= EPUCK.v_max * (1 + 1e-12))
    assert np.all(np.abs(right) <= EPUCK.v_max * (1 + 1e-12))
    assert np.all(np.abs(w) <= EPUCK.omega_max)
    assert np.all(v[reverse] <= 0) and np.all(v[~reverse] >= 0)


def test_tracking_errors_leave_the_inflated_disks_apart():
    rng = np.random.default_rng(8)
    pos = rng.uniform(0, 0.6, (40, 2))
    r = np.full(40, EPUCK.radius)
    keep = [0]
    for i in range(1, 40):  # non-overlapping with gaps >= 2 E_min
        if all(np.linalg.norm(pos[i] - pos[j]) >= 2 * EPUCK.radius + 2 * EPUCK.error_min for j in keep):
            keep.append(i)
    pos, r = pos[keep], r[keep]
    n = len(pos)
    others = np.array([[j for j in range(n) if j != i] for i in range(n)])
    found = [tracking_error(CORE, (*pos[i], r[i]), np.column_stack([pos[others[i]], r[others[i]]])) for i in range(n)]
    err = np.array([e for e, _ in found])
    nbr_err = np.array([b for _, b in found])
    assert np.all((err >= EPUCK.error_min) & (err <= EPUCK.error_max))
    for i in range(n):
        for k, j in enumerate(others[i]):
            assert r[i] + err[i] + r[j] + err[j] <= np.linalg.norm(pos[i] - pos[j]) + 1e-12
            assert err[j] <= nbr_err[i, k]


def all_others(pos, vel, cooperative=True):
    """What each robot hears of every other: their states as they are now."""
    n = len(pos)
    others = np.array([[j for j in range(n) if j != i] for i in range(n)]).reshape(n, n - 1)
    shape = others.shape
    return NeighbourStates.padded(
        pos[others],
        vel[others],
        np.full(shape, EPUCK.radius),
        np.zeros(shape),
        np.ones(shape, bool),
        np.full(shape, cooperative),
    )


def run_diffdrive(pos, heading, goal, steps, params=EPUCK):
    """A small closed loop: NH-ORCA on every robot, unicycle kinematics with the wheel speeds."""
    n = len(pos)
    vel = np.zeros((n, 2))
    min_dist = np.inf
    for tick in range(steps):
        pref = np.where(
            np.linalg.norm(goal - pos, axis=1, keepdims=True) > 1e-9,
            (goal - pos)
            * np.minimum(1.0, params.k_a / np.maximum(np.linalg.norm(goal - pos, axis=1, keepdims=True), 1e-12)),
            0.0,
        )
        pref = pref / params.k_a * params.v_pref + perturbation(np.arange(n), seed=3, tick=tick)
        velocity, wheels, *_ = nh_orca(pos, heading, vel, pref, all_others(pos, vel))
        left, right = wheels[:, 0], wheels[:, 1]
        assert np.all(np.abs(left) <= params.v_max + 1e-12)
        assert np.all(np.abs(right) <= params.v_max + 1e-12)
        poses = list(unicycle(pos, heading, wheels, params))
        for at, _ in poses:
            d = np.linalg.norm(at[:, None] - at[None], axis=-1) + np.eye(n) * 1e9
            min_dist = min(min_dist, d.min())
        pos, heading = poses[-1]
        vel = velocity
    return pos, min_dist


def unicycle(pos, heading, wheels, params, sub=20):
    """The poses over one control period on the wheel speeds (left, right), integrated finely."""
    v = 0.5 * (wheels[:, 0] + wheels[:, 1])
    w = (wheels[:, 1] - wheels[:, 0]) / params.wheel_base
    h = params.dt / sub
    for _ in range(sub):
        pos = pos + h * v[:, None] * np.stack([np.cos(heading + 0.5 * w * h), np.sin(heading + 0.5 * w * h)], -1)
        heading = heading + w * h
        yield pos, heading


def test_differential_drive_robots_swap_places_without_contact():
    # a perfectly symmetric ring is ORCA's classic deadlock (deadlock detection handles it); jitter
    ang = np.arange(6) * 2 * np.pi / 6
    rng = np.random.default_rng(0)
    pos = 0.25 * np.stack([np.cos(ang), np.sin(ang)], -1) + rng.uniform(-0.02, 0.02, (6, 2))
    heading = ang + np.pi  # facing the centre
    goal = -pos
    final, min_dist = run_diffdrive(pos, heading, goal, steps=150)
    assert min_dist >= 2 * EPUCK.radius
    assert np.all(np.linalg.norm(final - goal, axis=1) < 0.05)


def test_a_differential_drive_robot_at_its_goal_stands_still():
    """A unicycle cannot close on a point: chasing a goal millimetres away, the paper's control turned
    it on the spot at up to omega_cap for as long as it was shown (3.5 rad/s on average, seen in the
    paper sequence). Within goal_tolerance its preferred velocity is zero, so it stops, and stays."""
    pos, heading, vel, goal = np.array([[0.0, 0.0]]), np.array([np.pi / 2]), np.zeros((1, 2)), np.array([[0.3, 0.05]])
    headings, commands = [], []
    for tick in range(300):
        pref = control.preferred_velocities(CORE, [0], pos, vel, goal, None, seed=3, tick=tick)
        vel, wheels, *_ = nh_orca(pos, heading, vel, pref, NeighbourStates.empty(1))
        *_, (pos, heading) = unicycle(pos, heading, wheels, DIFFDRIVE)
        headings.append(heading[0])
        commands.append(np.abs(wheels).max())
    assert np.linalg.norm(pos[0] - goal[0]) <= DIFFDRIVE.goal_tolerance
    assert np.ptp(headings[150:]) == 0.0 and max(commands[150:]) == 0.0, (np.ptp(headings[150:]), max(commands[150:]))


def test_in_a_crowd_a_robot_makes_way_for_a_mover_that_will_not():
    """Paper 7.4.2's scene, tick 15.1 s: a robot of the disk, its neighbours 0.2-0.4 m around, and a
    mover (no ORCA: it avoids nobody) 0.25 m to its left closing at 0.1 m/s. No velocity keeps every
    line at the full horizon. Shrinking the mover's horizon with the rest (paper 5.3) let the robot
    drive back toward its goal, into the mover's path, until it was too late (a contact 1.6 s later);
    the mover's line keeps the full horizon, so the robot makes way now."""
    params = replace(DIFFDRIVE, radius=0.045)
    others = np.array(
        [[0.206, 0.001], [-0.012, -0.223], [-0.194, -0.111], [-0.145, 0.173], [0.067, 0.239],
         [-0.254, -0.01], [0.198, -0.212], [-0.244, -0.251], [0.291, 0.195], [0.433, 0.016]]
    )  # fmt: skip
    velocity = np.zeros_like(others)
    velocity[2], velocity[5], velocity[7] = [0.01, -0.052], [0.1, -0.004], [-0.002, -0.002]
    mover = np.arange(len(others)) == 5
    shape = (1, len(others))
    heard = NeighbourStates.padded(
        others[None],
        velocity[None],
        np.full(shape, params.radius),
        np.full(shape, 0.1),
        np.ones(shape, bool),
        ~mover[None],
    )
    robot = Batch(np.zeros((1, 2)), [[0.0305, -0.0048]], [[-0.0141, -0.0116]], 0.206, params.radius)
    v_cf, _, fallback, *_ = control.step(Settings(params), robot, heard)
    assert fallback[0]  # nothing keeps every line at the full horizon
    gap = np.linalg.norm(others[5]) - 2 * params.radius
    # away from the mover (it comes from the left), fast enough that it cannot close the gap within tau
    assert v_cf[0, 0] > 0.1 - gap / params.tau, v_cf[0]


def test_mirrored_polygon_drives_backwards_when_forward_is_infeasible():
    # a dynamic obstacle (c = 1) right ahead closing at 0.1 m/s: backing off faster than P_AHV allows
    obstacle = NeighbourStates.padded(
        np.array([[[0.1 + 0.002, 0.0]]]), np.array([[[-0.1, 0.0]]]), np.array([[EPUCK.radius]]),
        np.zeros((1, 1)), np.ones((1, 1), bool), np.zeros((1, 1), bool),
    )  # fmt: skip
    velocity, wheels, fallback, reverse, error = nh_orca(
        np.zeros((1, 2)), [0.0], np.zeros((1, 2)), [[0.12, 0.0]], obstacle
    )
    assert fallback[0] and reverse[0]
    assert velocity[0, 0] < -max_trackable_speed(np.pi, error[0])
    assert wheels[0, 0] < 0 and wheels[0, 1] < 0


@pytest.mark.slow
def test_a_differential_drive_robot_gets_bit_identical_results_alone_or_in_a_batch():
    rng = np.random.default_rng(9)
    b, m = 64, 6
    pos = rng.uniform(0, 0.8, (b, 2))
    heard = NeighbourStates.padded(
        pos[:, None] + rng.uniform(-0.2, 0.2, (b, m, 2)),
        rng.uniform(-0.1, 0.1, (b, m, 2)),
        np.full((b, m), EPUCK.radius),
        np.zeros((b, m)),
        rng.random((b, m)) < 0.8,
        rng.random((b, m)) < 0.5,
    )
    own = (pos, rng.uniform(-np.pi, np.pi, b), rng.uniform(-0.1, 0.1, (b, 2)), rng.uniform(-0.12, 0.12, (b, 2)))
    full = nh_orca(*own, heard)
    assert full[2].any() and not full[2].all()
    for i in range(b):
        one = nh_orca(*(a[i : i + 1] for a in own), heard.rows(slice(i, i + 1)))
        for a, c in zip(full, one):
            assert np.asarray(a)[i].tobytes() == np.asarray(c)[0].tobytes()
