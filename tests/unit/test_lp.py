"""The 2-D linear program of ORCA (agent.core.control.linear_program): hand-worked cases, and
optimality against scipy's SLSQP."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from agent.core.control import linear_program

# Lines as (point, direction); the permissible side is on the left of the direction.
Y_GE_1 = ((0.0, 1.0), (1.0, 0.0))  # y >= 1
Y_LE_2 = ((0.0, 2.0), (-1.0, 0.0))  # y <= 2
Y_GE_2 = ((0.0, 2.0), (1.0, 0.0))  # y >= 2
Y_LE_1 = ((0.0, 1.0), (-1.0, 0.0))  # y <= 1
X_GE_1 = ((1.0, 0.0), (0.0, -1.0))  # x >= 1
Y_GE_3 = ((0.0, 3.0), (1.0, 0.0))  # y >= 3


def solve(lines, pref, radius=5.0, n_hard=0):
    table = np.array([[*p, *d] for p, d in lines], dtype=float).reshape(-1, 4)
    v, fb = linear_program(table, radius, np.array(pref, dtype=float), n_hard)
    return v, bool(fb)


def test_unconstrained_optimum_is_the_preferred_velocity_clipped_to_the_speed_disk():
    v, fb = solve([], (1.0, 2.0))
    assert np.allclose(v, (1.0, 2.0)) and not fb
    v, fb = solve([], (6.0, 8.0))
    assert np.allclose(v, (3.0, 4.0)) and not fb


def test_feasible_optimum_inside_and_on_the_boundary():
    v, fb = solve([Y_GE_1], (0.5, 3.0))
    assert np.array_equal(v, (0.5, 3.0)) and not fb
    v, fb = solve([Y_GE_1], (0.5, -3.0))
    assert np.allclose(v, (0.5, 1.0)) and not fb
    v, fb = solve([Y_GE_1, X_GE_1], (0.0, 0.0))  # vertex of two lines
    assert np.allclose(v, (1.0, 1.0)) and not fb


def test_parallel_lines_form_a_strip():
    assert np.allclose(solve([Y_GE_1, Y_LE_2], (0.0, 0.0))[0], (0.0, 1.0))
    assert np.allclose(solve([Y_GE_1, Y_LE_2], (3.0, 5.0))[0], (3.0, 2.0))
    assert np.allclose(solve([Y_GE_1, Y_GE_2], (0.0, 0.0))[0], (0.0, 2.0))  # same direction


def test_speed_limit_binds_along_a_line():
    # closest point of y >= 1 to (10, 0) inside the disk of radius 2: on the circle at y = 1
    v, fb = solve([Y_GE_1], (10.0, 0.0), radius=2.0)
    assert np.allclose(v, (np.sqrt(3.0), 1.0)) and not fb


def test_anti_parallel_infeasible_lines_split_the_violation():
    v, fb = solve([Y_GE_2, Y_LE_1], (0.0, 0.0))
    assert fb
    assert v[1] == pytest.approx(1.5)  # both violated by 0.5
    assert np.hypot(*v) <= 5.0 + 1e-12


def test_line_beyond_the_speed_disk_gets_as_close_as_possible():
    v, fb = solve([Y_GE_3], (0.0, 0.0), radius=2.0)
    assert fb and np.allclose(v, (0.0, 2.0))


def test_hard_lines_stay_satisfied_in_the_fallback():
    # x >= 1 hard (an obstacle line); the two robot lines conflict
    v, fb = solve([X_GE_1, Y_GE_2, Y_LE_1], (-3.0, 0.0), n_hard=1)
    assert fb and v[0] >= 1.0 - 1e-12 and v[1] == pytest.approx(1.5)
    # x >= 1 hard contradicting the speed disk: every line softened, still a velocity in the disk
    v, fb = solve([((4.0, 0.0), (0.0, -1.0)), Y_GE_1], (0.0, 0.0), radius=2.0, n_hard=1)
    assert fb and np.hypot(*v) <= 2.0 + 1e-12


def random_problem(rng, b, n_lines, spread=2.0):
    angle = rng.uniform(0, 2 * np.pi, (b, n_lines))
    direction = np.stack([np.cos(angle), np.sin(angle)], -1)
    point = rng.uniform(-spread, spread, (b, n_lines, 2))
    valid = rng.random((b, n_lines)) < 0.85
    pref = rng.uniform(-3, 3, (b, 2))
    radius = rng.uniform(0.5, 3.0, b)
    return point, direction, valid, radius, pref


def violation(point, direction, v):
    return direction[:, 0] * (point[:, 1] - v[1]) - direction[:, 1] * (point[:, 0] - v[0])


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 7))
def test_feasible_result_is_the_closest_point_of_the_feasible_set(seed, n_lines):
    rng = np.random.default_rng(seed)
    point, direction, valid, radius, pref = random_problem(rng, 1, n_lines, spread=1.0)
    p, d = point[0][valid[0]], direction[0][valid[0]]
    v, fb = linear_program(np.concatenate([p, d], axis=1), radius[0], pref[0])
    v, fb = v[None], np.array([fb])
    cons = [{"type": "ineq", "fun": lambda x: radius[0] ** 2 - x @ x}]
    cons += [
        {"type": "ineq", "fun": lambda x, k=k: -violation(p[k : k + 1], d[k : k + 1], x)[0]} for k in range(len(p))
    ]
    ref = minimize(
        lambda x: np.sum((x - pref[0]) ** 2),
        np.zeros(2),
        constraints=cons,
        method="SLSQP",
        options={"ftol": 1e-12, "maxiter": 500},
    )
    ref_ok = ref.success and np.all(violation(p, d, ref.x) <= 1e-7) and ref.x @ ref.x <= radius[0] ** 2 + 1e-7
    if not fb[0]:
        assert np.all(violation(p, d, v[0]) <= 1e-9)
        assert np.hypot(*v[0]) <= radius[0] + 1e-9
        if ref_ok:
            assert np.sum((v[0] - pref[0]) ** 2) <= ref.fun + 1e-6
    else:
        assert not ref_ok  # infeasible for us means infeasible for the reference


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 7), st.integers(0, 2))
def test_fallback_minimises_the_largest_violation_of_soft_lines(seed, n_lines, n_hard):
    rng = np.random.default_rng(seed)
    point, direction, valid, radius, pref = random_problem(rng, 1, n_lines, spread=3.0)
    valid[:] = True
    n_hard = min(n_hard, n_lines - 1)
    p, d = point[0], direction[0]
    v, _ = linear_program(np.concatenate([p, d], axis=1), radius[0], pref[0], n_hard)
    hard = violation(p[:n_hard], d[:n_hard], v)
    # reference: min delta s.t. soft violations <= delta, hard <= 0, |v| <= R
    cons = [{"type": "ineq", "fun": lambda x: radius[0] ** 2 - x[:2] @ x[:2]}]
    cons += [
        {"type": "ineq", "fun": lambda x, k=k: -violation(p[k : k + 1], d[k : k + 1], x[:2])[0]} for k in range(n_hard)
    ]
    cons += [
        {"type": "ineq", "fun": lambda x, k=k: x[2] - violation(p[k : k + 1], d[k : k + 1], x[:2])[0]}
        for k in range(n_hard, n_lines)
    ]
    best = np.inf
    for x0 in ([0.0, 0.0, 10.0], [*v, 10.0]):
        ref = minimize(
            lambda x: x[2], np.array(x0), constraints=cons, method="SLSQP", options={"ftol": 1e-12, "maxiter": 500}
        )
        x = ref.x
        if x[:2] @ x[:2] <= radius[0] ** 2 + 1e-7 and np.all(violation(p[:n_hard], d[:n_hard], x[:2]) <= 1e-7):
            best = min(best, max(0.0, np.max(violation(p[n_hard:], d[n_hard:], x[:2]))))
    if not np.isfinite(best):
        return  # hard lines infeasible: everything is soft, nothing to compare
    assert np.all(hard <= 1e-9)
    assert np.hypot(*v) <= radius[0] + 1e-9
    ours = max(0.0, np.max(violation(p[n_hard:], d[n_hard:], v)))
    assert ours <= best + 1e-6
