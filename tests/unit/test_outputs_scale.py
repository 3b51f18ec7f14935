"""The run directory's outputs at 10,000 robots (issue 43): display.mp4's frames show every robot as a
disc at least 2 px across (its drawing time: bench_outputs --large); trajectory.npz is float32 at that scale and stores
robots at rest compactly; the clearance's quick path is exact."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from sim.outputs.metrics import clearance_at
from sim.outputs.render import MIN_DISC_PX, _View, render_frame, video_size
from sim.outputs.write import FLOAT32_FROM, write_trajectory

ARENA = (-39.88, -41.74, 39.88, 41.71)  # paper-sequence-10000's
RADIUS = 0.037  # the e-puck's


def grid_of(n: int, spacing: float = 0.8) -> np.ndarray:
    side = int(np.ceil(np.sqrt(n)))
    xy = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * spacing
    return np.column_stack([xy - xy.mean(axis=0), np.zeros(n)])


def test_the_video_of_10000_robots_is_large_enough_for_2_px_discs():
    size = video_size(ARENA, RADIUS)
    assert 2 * RADIUS * _View(ARENA, size).scale >= MIN_DISC_PX
    assert video_size((0, 0, 4, 3), RADIUS) == 720  # small arenas keep the default


@pytest.mark.timeout(60)
def test_a_frame_of_10000_robots_shows_each_as_a_disc_of_2_px_or_more():
    n = 10_000
    pose = grid_of(n)
    color = np.zeros((n, 3), np.uint8)
    color[:, 1] = 255
    color[4321] = (255, 0, 0)  # one robot to find: red among green
    size = video_size(ARENA, RADIUS)
    img = render_frame(0.0, pose, RADIUS, color, ARENA, goal=pose[:, :2], size_px=size)  # its speed: bench_outputs
    red = (img[..., 2] > 200) & (img[..., 1] < 60)  # BGR
    rows, cols = np.nonzero(red)
    assert len(rows) >= 4
    assert rows.max() - rows.min() + 1 >= 2 and cols.max() - cols.min() + 1 >= 2
    green = (img[..., 1] > 200) & (img[..., 2] < 60)
    assert green.sum() >= 4 * (n - 1)  # every other robot drawn too, none a single pixel


def test_trajectory_npz_is_float32_and_compact_at_scale_and_exact_below(tmp_path):
    ticks = 40
    for n in (FLOAT32_FROM - 1, FLOAT32_FROM):
        pose = np.repeat(grid_of(n)[None], ticks, axis=0) * 1.0001  # robots at rest
        arrays = {
            "t": np.arange(ticks) * 0.1,
            "pose": pose,
            "goal": pose[..., :2].copy(),
            "assignment": np.broadcast_to(np.arange(n), (ticks, n)).copy(),
        }
        path = write_trajectory(tmp_path / f"{n}.npz", arrays, np.full(n, RADIUS))
        with np.load(path) as z:
            assert z["pose"].shape == pose.shape and z["t"].dtype == np.float64
            if n < FLOAT32_FROM:
                assert z["pose"].dtype == np.float64 and np.array_equal(z["pose"], pose)
            else:
                assert z["pose"].dtype == np.float32 and np.array_equal(z["pose"], pose.astype(np.float32))
            np.testing.assert_array_equal(z["assignment"], arrays["assignment"])
        raw = sum(a.nbytes for a in arrays.values())
        assert path.stat().st_size < raw / 10  # a robot at rest is its first tick's bytes, repeated


@pytest.mark.parametrize("spread", [0.5, 3.0, 40.0])
@pytest.mark.parametrize("equal", [True, False])
def test_clearance_at_is_the_smallest_over_all_pairs(spread, equal):
    rng = np.random.default_rng(int(spread * 10) + equal)
    xy = rng.uniform(0, spread, (400, 2))
    radius = np.full(400, RADIUS) if equal else rng.uniform(0.02, 0.06, 400)
    i, j = np.triu_indices(400, 1)
    brute = pdist(xy) - radius[i] - radius[j]
    assert clearance_at(xy, radius) == pytest.approx(brute.min(), abs=1e-12)


# ------------------------------------------------------------------------------------------------
# Metrics in chunks of ticks: the same numbers to the bit as over the whole arrays at once
# ------------------------------------------------------------------------------------------------


def _whole_path_lengths(pose):
    step = np.sqrt((np.diff(pose[:, :, :2], axis=0) ** 2).sum(-1))
    return np.nansum(np.where(np.isfinite(step), step, np.nan), axis=0)


def _whole_time_to_converge(t, pose, goal, tolerance):
    has_goal = np.isfinite(goal).all(axis=2)
    if not has_goal.any():
        return None
    err = np.sqrt(((pose[:, :, :2] - goal) ** 2).sum(-1))
    ok = np.all(np.where(has_goal, err <= tolerance, True), axis=1)
    if not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    return float(t[0 if len(bad) == 0 else int(bad[-1]) + 1])


def _whole_step_metrics(t, pose, goal, step, tolerance, current, members):
    """step_metrics as it was, every (T, N) temporary at once: the reference."""
    err = np.sqrt(((pose[:, :, :2] - goal) ** 2).sum(-1))
    has_goal = np.isfinite(goal).all(axis=2) & members
    err = np.where(members, err, np.nan)
    within = np.where(has_goal, (err <= tolerance) & current, True).all(axis=1) & has_goal.any(axis=1)
    moved = np.sqrt((np.diff(pose[:, :, :2], axis=0) ** 2).sum(-1))
    out = []
    for k in sorted(set(step[step >= 0].tolist()), key=lambda s: int(np.argmax(step == s))):
        idx = np.flatnonzero(step == k)
        first, last = int(idx[0]), int(idx[-1])
        ok = idx[within[idx]]
        at_end = err[last][has_goal[last]]
        known = bool(len(at_end) and np.isfinite(at_end).any())
        out.append(
            {
                "index": int(k),
                "t_start": float(t[first]),
                "t_end": float(t[last]),
                "converged_at": float(t[ok[0]] - t[first]) if len(ok) else None,
                "max_goal_error_at_end": float(np.nanmax(at_end)) if known else None,
                "median_goal_error_at_end": float(np.nanmedian(at_end)) if known else None,
                "path_length_m": float(np.nansum(moved[idx[idx < len(moved)]])),
            }
        )
    return out


@pytest.mark.parametrize("chunk", [1, 7, 64, 1000, 1 << 22])
def test_the_metrics_in_chunks_of_ticks_are_those_of_the_whole_arrays_to_the_bit(monkeypatch, chunk):
    from sim.outputs import metrics

    monkeypatch.setattr(metrics, "CHUNK", chunk)
    rng = np.random.default_rng(chunk)
    T, N = 60, 37
    pose = np.cumsum(rng.normal(0, rng.uniform(1e-4, 1.0, (T, N, 1)), (T, N, 3)), axis=0)
    pose[rng.random((T, N)) < 0.02] = np.nan  # robots not there at some ticks
    goal = pose[-1, :, :2] + rng.normal(0, 0.01, (T, N, 2))
    goal[rng.random((T, N)) < 0.05] = np.nan
    t = np.arange(T) * 0.1
    step = np.repeat([0, 1, 2, 1, 3], [10, 15, 5, 20, 10])  # step 1 shown twice
    current, members = rng.random((T, N)) < 0.97, rng.random((T, N)) < 0.97
    np.testing.assert_array_equal(metrics.path_lengths(pose), _whole_path_lengths(pose))
    for tolerance in (0.005, 0.05, 1.0):
        assert metrics.time_to_converge(t, pose, goal, tolerance) == _whole_time_to_converge(t, pose, goal, tolerance)
        got = metrics.step_metrics(t, pose, goal, step, tolerance, current, members)
        assert got == _whole_step_metrics(t, pose, goal, step, tolerance, current, members)
    float32 = pose.astype(np.float32)  # trajectory.npz above FLOAT32_FROM: converted a chunk at a time
    np.testing.assert_array_equal(metrics.path_lengths(float32), _whole_path_lengths(float32.astype(float)))


def test_a_steps_path_length_in_pieces_is_numpys_pairwise_sum(monkeypatch):
    """A step of more elements than CHUNK is summed in halves as numpy halves it."""
    from sim.outputs import metrics

    rng = np.random.default_rng(3)
    values = rng.normal(0, 1, (997, 131)) * rng.uniform(0, 1e6, (997, 1))
    values[rng.random(values.shape) < 0.01] = np.nan
    rows = np.arange(len(values))
    for chunk in (128, 1000, 4096, 100_000):
        monkeypatch.setattr(metrics, "CHUNK", chunk)
        assert metrics._pairwise_nansum(rows, values.shape[1], lambda r: values[r]) == np.nansum(values)
