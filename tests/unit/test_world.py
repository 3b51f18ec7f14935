"""Tests of the simulated world (sim/bodies/world.py): kinematics, noise, substeps, contacts, perturbations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import pdist, squareform

from agent.core.params import EPUCK, RobotParams
from sim.bodies.world import ActuationNoise, Body, Contact, World

EPUCK_BODY = Body("diffdrive", radius=0.045, v_max=0.13)
HOLO = Body("holonomic", radius=0.045, v_max=0.13)
FAST_HOLO = Body("holonomic", radius=0.045, v_max=3.0)


def run(world: World, seconds: float, dt: float = 0.1) -> list[Contact]:
    started = []
    for _ in range(round(seconds / dt)):
        started += world.step(dt)
    return started


# ------------------------------------------------------------------ kinematics


def test_set_commands_clips_every_robot_as_set_command_does():
    """The batch setter (the central engine's) against one set_command per robot, on a mixed swarm
    with commands inside, on and beyond the limits: the same commands up to the last bit of the
    norm (numpy's hypot, not math.hypot), the same count of commands applied, the same motion."""
    rng = np.random.default_rng(4)
    bodies = [EPUCK_BODY, HOLO, FAST_HOLO] * 20
    poses = np.column_stack((np.arange(60) * 0.3, np.zeros(60), rng.uniform(-3, 3, 60)))
    one, batch = World(bodies, poses, noise=ActuationNoise(seed=2)), World(bodies, poses, noise=ActuationNoise(seed=2))
    for _ in range(5):
        cmd = rng.normal(0.0, 0.2, (60, 2)) * rng.choice([0.1, 1.0, 30.0], (60, 1))
        cmd[::9] *= 0.13 / np.hypot(cmd[::9, 0], cmd[::9, 1])[:, None]  # exactly on the holonomic limit
        for i, (a, b) in enumerate(cmd):
            one.set_command(i, a, b)
        batch.set_commands(cmd)
        np.testing.assert_allclose(batch.commands, one.commands, rtol=1e-15, atol=1e-17)
        one.step(0.1)
        batch.step(0.1)
    np.testing.assert_array_equal(batch.commands_applied, one.commands_applied)
    np.testing.assert_allclose(batch.poses, one.poses, rtol=1e-12, atol=1e-14)


def test_holonomic_straight_line_exact_with_no_noise():
    w = World([HOLO], [[0.1, -0.2, 0.7]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.06, -0.08)  # |v| = 0.1
    run(w, 2.0)
    assert w.time == 2.0
    np.testing.assert_allclose(w.poses[0], [0.1 + 0.12, -0.2 - 0.16, 0.7], atol=1e-12)
    np.testing.assert_allclose(w.velocities[0], [0.06, -0.08], atol=1e-12)
    assert w.path_length[0] == pytest.approx(0.2, abs=1e-12)


def test_holonomic_speed_limit_clips_the_norm_and_keeps_the_direction():
    w = World([HOLO], [[0.0, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 1.0, 1.0)
    np.testing.assert_allclose(w.commands[0], [0.13 / math.sqrt(2)] * 2)
    w.step(1.0)
    np.testing.assert_allclose(w.poses[0, :2], [0.13 / math.sqrt(2)] * 2, atol=1e-12)
    assert np.hypot(*w.velocities[0]) == pytest.approx(0.13)


def test_speed_limits_hold_with_noise_too():
    n = 200
    bodies = [HOLO] * (n // 2) + [EPUCK_BODY] * (n // 2)
    poses = np.column_stack([np.arange(n) * 1.0, np.zeros(n), np.zeros(n)])
    w = World(bodies, poses, noise=ActuationNoise(relative=0.2, absolute=0.05, seed=3))
    for i in range(n):
        w.set_command(i, 0.2, 0.2)  # beyond the limit for both kinds
    for _ in range(20):
        before = w.poses
        w.step(0.1)
        moved = np.hypot(*(w.poses[:, :2] - before[:, :2]).T)
        assert np.all(moved <= 0.13 * 0.1 + 1e-12)
        assert np.all(np.hypot(*w.velocities.T) <= 0.13 + 1e-12)


def test_diffdrive_straight_line_along_heading():
    th = 0.4
    w = World([EPUCK_BODY], [[1.0, 2.0, th]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.1, 0.1)
    run(w, 3.0)
    expected = [1.0 + 0.3 * math.cos(th), 2.0 + 0.3 * math.sin(th), th]
    np.testing.assert_allclose(w.poses[0], expected, atol=1e-12)
    np.testing.assert_allclose(w.velocities[0], [0.1 * math.cos(th), 0.1 * math.sin(th)], atol=1e-12)
    assert w.path_length[0] == pytest.approx(0.3)


def test_diffdrive_pure_rotation_stays_in_place():
    w = World([EPUCK_BODY], [[0.5, 0.5, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, -0.05, 0.05)
    omega = 0.1 / 0.0525
    run(w, 1.0)
    np.testing.assert_allclose(w.poses[0, :2], [0.5, 0.5], atol=1e-15)
    expected = (omega * 1.0 + math.pi) % (2 * math.pi) - math.pi
    assert w.poses[0, 2] == pytest.approx(expected, abs=1e-12)
    assert w.path_length[0] == 0.0


@pytest.mark.parametrize("dt", [0.1, 0.037, 0.25])
def test_diffdrive_arc_matches_closed_form(dt):
    vl, vr = 0.05, 0.1
    v, omega = (vl + vr) / 2, (vr - vl) / 0.0525
    w = World([EPUCK_BODY], [[0.0, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, vl, vr)
    for _ in range(40):
        w.step(dt)
    t = w.time
    assert t == pytest.approx(40 * dt)
    rho = v / omega
    x, y = rho * math.sin(omega * t), rho * (1 - math.cos(omega * t))
    theta = (omega * t + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(w.poses[0], [x, y, theta], atol=1e-12)
    assert w.path_length[0] == pytest.approx(v * t)


def test_wheel_speeds_are_clipped_to_v_max_each():
    w = World([EPUCK_BODY], [[0.0, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.5, -0.5)
    np.testing.assert_allclose(w.commands[0], [0.13, -0.13])
    w.step(0.1)
    assert w.poses[0, 2] == pytest.approx(-0.26 / 0.0525 * 0.1)  # right wheel slower: clockwise
    w.set_command(0, 1.0, 0.2)
    np.testing.assert_allclose(w.commands[0], [0.13, 0.13])


def test_turn_rate_is_limited_by_omega_max():
    body = Body("diffdrive", radius=0.045, v_max=0.13, omega_max=1.0)
    w = World([body], [[0.0, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, -0.13, 0.13)
    w.step(0.5)
    assert w.poses[0, 2] == pytest.approx(0.5)


def test_mixed_swarm_each_robot_follows_its_own_kinematics():
    w = World([HOLO, EPUCK_BODY], [[0, 0, 1.0], [1, 0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.0, 0.1)  # holonomic: move +y, heading unchanged
    w.set_command(1, 0.0, 0.1)  # diffdrive: left wheel stopped, turns left on an arc
    w.step(1.0)
    np.testing.assert_allclose(w.poses[0], [0, 0.1, 1.0], atol=1e-12)
    assert w.poses[1, 2] == pytest.approx(0.1 / 0.0525)
    assert w.poses[1, 1] > 0


def test_substeps_follow_the_substep_length_and_time_is_exact():
    w = World([HOLO], [[0, 0, 0]])
    w.step(0.1)
    assert w.last_substeps == 10
    w.step(0.025)
    assert w.last_substeps == 3
    w2 = World([HOLO], [[0, 0, 0]], substep=0.05)
    for _ in range(10):
        w2.step(0.1)
    assert w2.last_substeps == 2
    assert w2.time == 1.0


# ------------------------------------------------------------------ noise and determinism


def _noisy_run(seed, order=1):
    n = 6
    bodies = [EPUCK_BODY, HOLO] * (n // 2)
    poses = np.column_stack([np.arange(n) * 0.5, np.zeros(n), np.linspace(0, 1, n)])
    w = World(bodies, poses, noise=ActuationNoise(relative=0.05, absolute=0.002, seed=seed))
    for k in range(30):
        for i in list(range(n))[::order]:
            w.set_command(i, 0.1 * math.sin(k + i), 0.1 * math.cos(k - i))
        w.step(0.1)
    return w


def test_same_seed_same_calls_give_bit_identical_poses():
    a, b = _noisy_run(7), _noisy_run(7)
    assert np.array_equal(a.poses, b.poses)
    assert np.array_equal(a.velocities, b.velocities)
    assert np.array_equal(a.path_length, b.path_length)


def test_noise_does_not_depend_on_the_order_commands_arrive_in():
    assert np.array_equal(_noisy_run(7, order=1).poses, _noisy_run(7, order=-1).poses)


def test_different_seeds_differ_when_noise_is_on():
    assert not np.allclose(_noisy_run(7).poses, _noisy_run(8).poses)


def test_noise_has_the_stated_relative_size():
    n = 4000
    poses = np.column_stack([np.arange(n) * 1.0, np.zeros(n), np.zeros(n)])
    w = World([HOLO] * n, poses, noise=ActuationNoise(relative=0.02, seed=1))
    for i in range(n):
        w.set_command(i, 0.1, 0.0)
    w.step(0.1)  # one noise period: the error is held over it
    dx, dy = w.poses[:, 0] - np.arange(n), w.poses[:, 1]
    assert np.mean(dx) == pytest.approx(0.01, abs=2e-5)
    assert np.std(dx) == pytest.approx(0.0002, rel=0.1)  # 2 % of 0.1 m/s over 0.1 s
    assert np.std(dy) == pytest.approx(0.0002, rel=0.1)
    start = w.poses[:, 0]
    w.step(0.9)  # nine more periods, independent draws: the error over them grows as sqrt(9)
    assert np.std(w.poses[:, 0] - start) == pytest.approx(0.0002 * 3, rel=0.1)


def test_noise_does_not_depend_on_how_time_is_chunked_into_steps():
    # lock-step calls step(0.1); a real-time loop may call step(0.01) ten times: same world
    poses = [[0, 0, 0.3], [0.5, 0, 0.0], [1.0, 0, 2.0]]
    bodies = [EPUCK_BODY, HOLO, EPUCK_BODY]
    one = World(bodies, poses, noise=ActuationNoise(relative=0.1, absolute=0.01, seed=4))
    many = World(bodies, poses, noise=ActuationNoise(relative=0.1, absolute=0.01, seed=4))
    odd = World(bodies, poses, noise=ActuationNoise(relative=0.1, absolute=0.01, seed=4))
    for k in range(20):
        for w in (one, many, odd):
            for i in range(3):
                w.set_command(i, 0.1 * math.sin(k + i), 0.1 * math.cos(k))
        one.step(0.1)
        for _ in range(10):
            many.step(0.01)
        for dt in (0.03, 0.05, 0.02):  # steps that do not match the noise period
            odd.step(dt)
        np.testing.assert_allclose(many.poses, one.poses, atol=1e-12)
        np.testing.assert_allclose(odd.poses, one.poses, atol=1e-12)
        np.testing.assert_allclose(many.velocities, one.velocities, atol=1e-9)
    np.testing.assert_allclose(many.path_length, one.path_length, atol=1e-12)
    assert one.time == pytest.approx(2.0) and many.time == pytest.approx(2.0)


def test_a_step_spanning_several_noise_periods_integrates_each_piece():
    w = World([EPUCK_BODY], [[0, 0, 0]], noise=ActuationNoise(relative=0.1, seed=5))
    ref = World([EPUCK_BODY], [[0, 0, 0]], noise=ActuationNoise(relative=0.1, seed=5))
    w.set_command(0, 0.05, 0.1)
    ref.set_command(0, 0.05, 0.1)
    w.step(0.35)  # three and a half periods in one call
    for dt in (0.1, 0.1, 0.1, 0.05):
        ref.step(dt)
    np.testing.assert_allclose(w.poses, ref.poses, atol=1e-12)
    assert w.last_substeps == 35


def test_stopped_robot_does_not_creep_even_with_absolute_noise():
    poses = [[0, 0, 0], [1, 0, 0]]
    w = World([EPUCK_BODY, HOLO], poses, noise=ActuationNoise(relative=0.1, absolute=0.01, seed=2))
    w.set_command(0, 0.1, 0.1)
    w.set_command(1, 0.1, 0.0)
    w.step(0.1)
    w.stop(0)
    w.stop(1)
    before = w.poses
    run(w, 1.0)
    assert np.array_equal(w.poses, before)
    assert np.array_equal(w.commands, np.zeros((2, 2)))
    assert list(w.commands_applied) == [1, 1]
    assert np.array_equal(w.velocities, np.zeros((2, 2)))


# ------------------------------------------------------------------ contacts


def test_robots_crossing_within_one_control_period_are_detected_by_substeps():
    # they swap places in one 0.1 s step: at the start and at the end they are 0.2 m apart
    poses = [[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0]]
    coarse = World([FAST_HOLO, FAST_HOLO], poses, substep=0.1, noise=ActuationNoise(relative=0.0))
    fine = World([FAST_HOLO, FAST_HOLO], poses, noise=ActuationNoise(relative=0.0))
    for w in (coarse, fine):
        w.set_command(0, 2.0, 0.0)
        w.set_command(1, -2.0, 0.0)
        started = w.step(0.1)
        np.testing.assert_allclose(w.poses[:, 0], [0.1, -0.1], atol=1e-12)
    assert coarse.contacts == []  # one substep per control period sees nothing
    assert len(started) == 1 and fine.contacts == started
    c = started[0]
    assert (c.kind, c.i, c.j) == ("robot", 0, 1)
    assert c.t_start == pytest.approx(0.03)  # centres 0.08 apart at t = 0.03
    assert c.t_end == pytest.approx(0.08)  # 0.12 apart at t = 0.08, first substep out of contact
    assert c.max_depth == pytest.approx(0.09)  # they met centre on centre at t = 0.05
    assert fine.min_clearance == pytest.approx(-0.09)


def test_contact_event_starts_ends_and_records_its_depth_without_pushing():
    w = World([HOLO, HOLO], [[0.0, 0.0, 0.0], [0.205, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.1, 0.0)
    w.set_command(1, -0.1, 0.0)
    assert run(w, 0.5) == []
    started = w.step(0.1)  # centres closer than 0.09 from t > 0.575
    assert len(started) == 1
    c = started[0]
    assert (c.kind, c.i, c.j, c.t_end) == ("robot", 0, 1, None)
    assert c.t_start == pytest.approx(0.58)
    assert w.step(0.1) == []  # ongoing: not reported again
    assert w.active_contacts == [c]
    # not pushed apart: they went on as commanded
    assert w.poses[1, 0] - w.poses[0, 0] == pytest.approx(0.205 - 0.14)
    w.set_command(0, -0.1, 0.0)
    w.set_command(1, 0.1, 0.0)
    run(w, 0.3)
    assert c.t_end == pytest.approx(0.83)  # 0.065 + 0.2 (t - 0.7) >= 0.09 from t = 0.825
    assert c.max_depth == pytest.approx(0.025)
    assert w.contacts == [c] and w.active_contacts == []
    assert w.min_clearance == pytest.approx(-0.025)


def test_contacts_with_different_radii_use_both_radii():
    small = Body("holonomic", radius=0.01, v_max=0.13)
    w = World([HOLO, small], [[0, 0, 0], [0.054, 0, 0]])  # 0.054 < 0.045 + 0.01
    assert [(c.kind, c.i, c.j) for c in w.contacts] == [("robot", 0, 1)]
    assert w.contacts[0].max_depth == pytest.approx(0.001)
    assert w.min_clearance == pytest.approx(-0.001)


def test_robots_starting_overlapped_are_recorded_at_t0():
    w = World([HOLO, HOLO, HOLO], [[0, 0, 0], [0.05, 0, 0], [1, 0, 0]])
    assert [(c.kind, c.i, c.j, c.t_start, c.t_end) for c in w.contacts] == [("robot", 0, 1, 0.0, None)]
    assert w.contacts[0].max_depth == pytest.approx(0.04)


def test_wall_contact():
    w = World([HOLO], [[0.5, 0.1025, 0.0]], arena=(0.0, 0.0, 1.0, 1.0), noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.0, -0.1)
    started = run(w, 1.0)  # y < 0.045 from t > 0.575
    assert len(started) == 1
    c = started[0]
    assert (c.kind, c.i, c.j, c.t_end) == ("wall", 0, -1, None)
    assert c.t_start == pytest.approx(0.58)
    assert c.max_depth == pytest.approx(0.045 - 0.0025)  # centre 2.5 mm from the wall at t = 1.0
    run(w, 0.5)  # leaves the arena: still one ongoing event, deeper than a radius
    assert c.max_depth == pytest.approx(0.045 + 0.0475) and len(w.contacts) == 1


def test_robot_starting_outside_the_arena_is_a_wall_contact():
    w = World([HOLO, HOLO], [[2.0, 2.0, 0.0], [0.5, 0.5, 0.0]], arena=(0.0, 0.0, 1.0, 1.0))
    assert [(c.kind, c.i, c.j) for c in w.contacts] == [("wall", 0, -1)]
    assert w.contacts[0].max_depth == pytest.approx(0.045 + math.sqrt(2))


def test_obstacle_contact_records_the_obstacle_index_and_depth():
    far = [(5.0, 5.0), (6.0, 5.0), (6.0, 6.0)]
    square = [(0.4, 0.4), (0.6, 0.4), (0.6, 0.6), (0.4, 0.6)]
    w = World([HOLO], [[0.2025, 0.5, 0.0]], obstacles=[far, square], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.1, 0.0)
    started = run(w, 1.6)  # x > 0.355 from t > 1.525
    assert [(c.kind, c.i, c.j) for c in started] == [("obstacle", 0, 1)]
    assert started[0].t_start == pytest.approx(1.53)
    assert started[0].max_depth == pytest.approx(0.045 - (0.4 - 0.3625))
    run(w, 1.0)  # centre at x = 0.4625, inside: depth = r + distance to the boundary
    assert started[0].max_depth == pytest.approx(0.045 + 0.0625)
    w.set_command(0, -0.1, 0.0)
    run(w, 1.5)  # back to x = 0.3125: out of contact once x <= 0.355, at t = 2.6 + 1.075
    assert started[0].t_end == pytest.approx(3.68)
    assert w.active_contacts == []


def test_no_contact_when_robots_are_apart():
    n = 100
    g = np.stack(np.meshgrid(np.arange(10), np.arange(10)), -1).reshape(-1, 2) * 0.3
    poses = np.column_stack([g, np.zeros(n)])
    w = World([EPUCK_BODY] * n, poses, arena=(-1, -1, 10, 10), noise=ActuationNoise(relative=0.0))
    for i in range(n):
        w.set_command(i, 0.1, 0.1)  # all in parallel along +x
    assert run(w, 2.0) == []
    assert w.contacts == []
    assert w.min_clearance == pytest.approx(0.3 - 0.09)
    assert w.step_min_clearance() == pytest.approx(0.3 - 0.09)


# ------------------------------------------------------------------ clearance


def test_min_clearance_tracks_the_closest_approach_and_the_last_step():
    w = World([HOLO, HOLO], [[0.0, 0.0, 0.0], [1.0, 0.1, 0.0]], noise=ActuationNoise(relative=0.0))
    assert w.min_clearance == pytest.approx(math.hypot(1.0, 0.1) - 0.09)
    w.set_command(1, -0.1, 0.0)
    run(w, 10.0)  # passes at (0, 0.1) at t = 10
    assert w.min_clearance == pytest.approx(0.1 - 0.09)
    w.set_command(1, 0.0, 0.1)
    w.step(0.1)
    assert w.step_min_clearance() == pytest.approx(0.1 - 0.09)  # the step's start counts
    w.step(0.1)
    assert w.step_min_clearance() == pytest.approx(0.11 - 0.09)
    assert w.min_clearance == pytest.approx(0.01)


def test_step_clearance_is_exact_after_the_closest_pair_is_pulled_apart():
    # robots 0 and 1 are the closest pair; 2 and 3 are next; then 1 is carried 50 m away
    poses = [[0, 0, 0], [0.1, 0, 0], [5, 5, 0], [5.3, 5, 0], [9, 9, 0]]
    w = World([HOLO] * 5, poses, noise=ActuationNoise(relative=0.0))
    w.step(0.1)
    assert w.step_min_clearance() == pytest.approx(0.01)
    w.teleport(1, (50.0, 50.0, 0.0))
    w.step(0.1)
    assert w.step_min_clearance() == pytest.approx(0.21)
    w.step(0.1)
    assert w.step_min_clearance() == pytest.approx(0.21)
    assert w.min_clearance == pytest.approx(0.01)


def test_single_robot_has_infinite_clearance():
    w = World([HOLO], [[0, 0, 0]])
    w.step(0.1)
    assert w.min_clearance == math.inf and w.step_min_clearance() == math.inf


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31), n=st.integers(2, 40), spread=st.floats(0.2, 3.0))
def test_clearance_and_contacts_match_brute_force(seed, n, spread):
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.01, 0.08, n)
    bodies = [Body("holonomic" if k % 2 else "diffdrive", float(rd), 0.5) for k, rd in enumerate(radii)]
    poses = np.column_stack([rng.uniform(0, spread, (n, 2)), rng.uniform(-3, 3, n)])
    w = World(bodies, poses, substep=0.1, noise=ActuationNoise(seed=seed))  # one substep per step: check at step ends
    sum_r = radii[:, None] + radii[None, :]
    iu = np.triu_indices(n, 1)

    def brute():
        d = squareform(pdist(w.poses[:, :2])) - sum_r
        return d[iu].min(), {(int(a), int(b)) for a, b in zip(*iu) if d[a, b] < 0}

    best, overlapping = brute()
    now = best
    assert w.step_min_clearance() == pytest.approx(best, abs=1e-12)
    assert {(c.i, c.j) for c in w.active_contacts} == overlapping
    for _ in range(8):
        for i in range(n):
            w.set_command(i, *rng.uniform(-0.5, 0.5, 2))
        w.step(0.1)
        before = now
        now, overlapping = brute()
        best = min(best, now)
        assert w.step_min_clearance() == pytest.approx(min(before, now), abs=1e-12)  # start and end
        assert {(c.i, c.j) for c in w.active_contacts} == overlapping
    assert w.min_clearance == pytest.approx(best, abs=1e-12)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31), n=st.integers(2, 30), spread=st.floats(0.2, 2.0))
def test_clearance_over_substeps_matches_brute_force_on_every_substep(seed, n, spread):
    # without noise, one step of 0.1 s in 10 substeps is the same motion as 10 steps of 0.01 s
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.01, 0.06, n)
    bodies = [Body("holonomic" if k % 2 else "diffdrive", float(rd), 1.0) for k, rd in enumerate(radii)]
    poses = np.column_stack([rng.uniform(0, spread, (n, 2)), rng.uniform(-3, 3, n)])
    coarse = World(bodies, poses, noise=ActuationNoise(relative=0.0))
    fine = World(bodies, poses, noise=ActuationNoise(relative=0.0))
    sum_r = (radii[:, None] + radii[None, :])[np.triu_indices(n, 1)]
    for _ in range(5):
        cmds = rng.uniform(-1.0, 1.0, (n, 2))
        for i in range(n):
            coarse.set_command(i, *cmds[i])
            fine.set_command(i, *cmds[i])
        coarse.step(0.1)
        states = [fine.poses[:, :2]]
        for _ in range(10):
            fine.step(0.01)
            states.append(fine.poses[:, :2])
        np.testing.assert_allclose(coarse.poses[:, :2], fine.poses[:, :2], atol=1e-12)
        dtheta = coarse.poses[:, 2] - fine.poses[:, 2]
        np.testing.assert_allclose(np.sin(dtheta), 0.0, atol=1e-12)
        brute = min(float((pdist(p) - sum_r).min()) for p in states)
        assert coarse.step_min_clearance() == pytest.approx(brute, abs=1e-12)
    assert coarse.min_clearance == pytest.approx(fine.min_clearance, abs=1e-12)
    key = lambda c: (c.kind, c.i, c.j, round(c.t_start, 9), None if c.t_end is None else round(c.t_end, 9))
    assert [key(c) for c in coarse.contacts] == [key(c) for c in fine.contacts]


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31), n=st.integers(6, 25))
def test_contacts_checked_later_are_the_contacts_checked_at_once(seed, n):
    """step(check=False), then check() (or any read of contacts or clearance, or the next step),
    with teleports between: the same events, depths and clearances as checking every step."""
    rng = np.random.default_rng(seed)
    bodies = [Body("holonomic" if k % 2 else "diffdrive", 0.05, 1.0) for k in range(n)]
    poses = np.column_stack([rng.uniform(0, 0.4, (n, 2)), rng.uniform(-3, 3, n)])  # crowded: contacts
    now, later = (World(bodies, poses, arena=(-0.1, -0.1, 0.5, 0.5), noise=ActuationNoise(seed=seed)) for _ in range(2))
    started_now, started_later = [], []
    for k in range(12):
        cmds = rng.uniform(-1.0, 1.0, (n, 2))
        now.set_commands(cmds)
        later.set_commands(cmds)
        started_now += now.step(0.1)
        started_later += later.step(0.1, check=False)
        if k % 3 == 0:
            pose = (*rng.uniform(0, 0.4, 2), 0.0)
            now.teleport(k % n, pose)
            later.teleport(k % n, pose)
        if k % 2:  # (reading the clearance first would check the step too, and return nothing)
            started_later += later.check()
            assert later.step_min_clearance() == now.step_min_clearance()
    started_later += later.check()
    np.testing.assert_array_equal(later.poses, now.poses)
    assert later.min_clearance == now.min_clearance
    event = lambda c: (c.kind, c.i, c.j, c.t_start, c.t_end, c.max_depth)
    assert [event(c) for c in later.contacts] == [event(c) for c in now.contacts]
    assert sorted(map(event, started_later), key=str) == sorted(map(event, started_now), key=str) and started_now


# ------------------------------------------------------------------ perturbations


def test_teleport_moves_without_path_and_zeroes_velocity():
    w = World([EPUCK_BODY], [[0.0, 0.0, 0.0]], noise=ActuationNoise(relative=0.0))
    w.set_command(0, 0.1, 0.1)
    w.step(0.5)
    w.teleport(0, (2.0, 3.0, 4.0))
    np.testing.assert_allclose(w.poses[0], [2.0, 3.0, 4.0 - 2 * math.pi])
    assert np.array_equal(w.velocities[0], [0.0, 0.0])
    assert w.path_length[0] == pytest.approx(0.05)
    np.testing.assert_allclose(w.commands[0], [0.1, 0.1])  # the command is kept
    w.step(0.1)
    assert w.poses[0, 0] < 2.0  # drives on along its new heading (4 rad)


def test_teleport_into_and_out_of_contact_is_recorded_at_the_teleport_time():
    w = World([HOLO, HOLO], [[0, 0, 0], [1, 0, 0]], noise=ActuationNoise(relative=0.0))
    w.step(0.3)
    w.teleport(1, (0.05, 0.0, 0.0))
    started = w.step(0.1)
    assert [(c.kind, c.i, c.j, c.t_start) for c in started] == [("robot", 0, 1, pytest.approx(0.3))]
    w.step(0.1)
    w.teleport(1, (1.0, 0.0, 0.0))
    w.step(0.1)
    assert started[0].t_end == pytest.approx(0.5)
    assert started[0].max_depth == pytest.approx(0.04)


# ------------------------------------------------------------------ construction and validation


def test_from_params_uses_the_paper_defaults():
    w = World.from_params(EPUCK, np.zeros((3, 3)) + [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert w.bodies[0] == Body("diffdrive", 0.045, 0.13, 0.0525, 4.96)
    mixed = World.from_params([EPUCK, RobotParams(kinematics="holonomic")], [[0, 0, 0], [1, 0, 0]])
    assert [b.kinematics for b in mixed.bodies] == ["diffdrive", "holonomic"]


def test_state_arrays_are_copies():
    w = World([HOLO], [[0, 0, 0]])
    w.poses[0, 0] = 5.0
    w.path_length[0] = 5.0
    assert w.poses[0, 0] == 0.0 and w.path_length[0] == 0.0


@pytest.mark.parametrize(
    "make",
    [
        lambda: Body("tank", 0.045, 0.13),
        lambda: Body("diffdrive", 0.0, 0.13),
        lambda: Body("diffdrive", 0.045, float("nan")),
        lambda: Body("diffdrive", 0.045, 0.13, wheel_base=-1.0),
        lambda: World([], np.zeros((0, 3))),
        lambda: World([HOLO], np.zeros((2, 3))),
        lambda: World([HOLO], np.zeros((1, 2))),
        lambda: World([HOLO], [[0.0, float("nan"), 0.0]]),
        lambda: World([HOLO], [[0, 0, 0]], arena=(1, 0, 0, 1)),
        lambda: World([HOLO], [[0, 0, 0]], arena=(0, 0, 1)),
        lambda: World([HOLO], [[0, 0, 0]], obstacles=[[(0, 0), (1, 1)]]),
        lambda: World([HOLO], [[0, 0, 0]], obstacles=[[(0, 0), (1, 1), (1, 0), (0, 1)]]),  # bow tie
        lambda: World([HOLO], [[0, 0, 0]], noise=ActuationNoise(relative=-0.1)),
        lambda: World([HOLO], [[0, 0, 0]], substep=0.0),
        lambda: World([HOLO], [[0, 0, 0]], noise=ActuationNoise(seed=-1)),
        lambda: World([HOLO], [[0, 0, 0]]).set_command(1, 0.0, 0.0),
        lambda: World([HOLO], [[0, 0, 0]]).set_command(0, float("inf"), 0.0),
        lambda: World([HOLO], [[0, 0, 0]]).set_commands(np.zeros((2, 2))),
        lambda: World([HOLO], [[0, 0, 0]]).set_commands([[0.0, float("nan")]]),
        lambda: World([HOLO], [[0, 0, 0]]).stop(-1),
        lambda: World([HOLO], [[0, 0, 0]]).teleport(0, (0.0, float("nan"), 0.0)),
        lambda: World([HOLO], [[0, 0, 0]]).step(0.0),
        lambda: World([HOLO], [[0, 0, 0]]).step(float("nan")),
    ],
)
def test_invalid_inputs_raise_value_error(make):
    with pytest.raises(ValueError):
        make()
