"""The run directory's outputs at 10,000 robots (issue 43): display.mp4's frames show every robot as a
disc at least 2 px across (its drawing time: bench_outputs --large); trajectory.npz is float32 at that scale and stores
robots at rest compactly; the clearance's quick path is exact."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from sim.outputs.metrics import clearance_at
from sim.outputs.render import MIN_DISC_PX, _View, video_size
from sim.outputs.write import FLOAT32_FROM, write_trajectory
from tests.support.outputs import render_frame

ARENA = (-39.88, -41.74, 39.88, 41.71)  # paper-sequence-10000's
RADIUS = 0.037  # below the e-puck's 0.045 m: a smaller robot still shows as a disc


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


def _metrics_of(metrics, chunk, arrays):
    """path_lengths, time_to_converge and step_metrics at three tolerances, in chunks of ``chunk``."""
    t, pose, goal, step, current, members = arrays
    metrics.CHUNK = chunk
    out = [metrics.path_lengths(pose).tolist(), metrics.path_lengths(pose.astype(np.float32)).tolist()]
    for tolerance in (0.005, 0.05, 1.0):
        out.append(metrics.time_to_converge(t, pose, goal, tolerance))
        out.append(metrics.step_metrics(t, pose, goal, step, tolerance, current, members))
    return out


@pytest.mark.parametrize("chunk", [1, 7, 64, 1000])
def test_the_metrics_in_chunks_of_ticks_are_those_of_the_whole_arrays_to_the_bit(monkeypatch, chunk):
    """Against one chunk of every tick (each function's own results are checked by hand elsewhere:
    test_rundir_outputs, test_scene_steps)."""
    from sim.outputs import metrics

    monkeypatch.setattr(metrics, "CHUNK", metrics.CHUNK)
    rng = np.random.default_rng(chunk)
    T, N = 60, 37
    pose = np.cumsum(rng.normal(0, rng.uniform(1e-4, 1.0, (T, N, 1)), (T, N, 3)), axis=0)
    pose[rng.random((T, N)) < 0.02] = np.nan  # robots not there at some ticks
    goal = pose[-1, :, :2] + rng.normal(0, 0.01, (T, N, 2))
    goal[rng.random((T, N)) < 0.05] = np.nan
    step = np.repeat([0, 1, 2, 1, 3], [10, 15, 5, 20, 10])  # step 1 shown twice
    arrays = (np.arange(T) * 0.1, pose, goal, step, rng.random((T, N)) < 0.97, rng.random((T, N)) < 0.97)
    whole = _metrics_of(metrics, T * N * 10, arrays)
    assert _metrics_of(metrics, chunk, arrays) == whole


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
