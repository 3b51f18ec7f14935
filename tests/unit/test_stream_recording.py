"""The central engine's recording streamed to disk (sim.outputs.stream; issue 43: peak RSS at most 4 GB at
10,000 robots): the files hold what the arrays in memory hold, tick chunk after tick chunk; trajectory.npz
written from them a block of robots at a time is the one written from the arrays; a run directory keeps
none of the raw files, and an aborted run leaves nothing behind."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.central.engine import run_central, simulate
from sim.outputs import stream
from sim.outputs.metrics import TrueRecord, summarise
from sim.outputs.rundir import PARTIAL_SUFFIX
from sim.outputs.stream import FLOAT32_FROM, ROWS, OnDisk, TickRecorder
from sim.outputs.write import ColumnMajor, write_trajectory


def ticks_of(n: int, ticks: int, seed: int = 0) -> list[tuple]:
    """Made-up ticks of ``n`` robots: (t, step, rows in ROWS' order), goals NaN for some robots."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(ticks):
        goal = rng.normal(0, 30, (n, 2))
        goal[rng.random(n) < 0.1] = np.nan
        rows = (
            rng.normal(0, 30, (n, 3)),
            rng.normal(0, 0.1, (n, 2)),
            rng.uniform(0, 255, (n, 3)),  # as the robots hold colours: floats, recorded as uint8
            goal,
            rng.integers(-1, n, n),
        )
        out.append((k * 0.1, k // 7, rows))
    return out


def recorded(n: int, ticks: list[tuple], directory=None, upto: int | None = None) -> dict:
    rec = TickRecorder(len(ticks), n, directory)
    for k, (t, step, rows) in enumerate(ticks[:upto]):
        rec.record(k, t, step, rows)
    return rec.arrays(len(ticks[:upto]))


@pytest.mark.parametrize("n", [7, FLOAT32_FROM])
def test_streamed_ticks_are_the_ticks_held_in_memory_float32_only_at_scale(tmp_path, monkeypatch, n):
    monkeypatch.setattr(stream, "CHUNK_BYTES", 3 * n * 70)  # three ticks a chunk: the last chunk part-full
    ticks = ticks_of(n, 11)
    held = recorded(n, ticks)
    streamed = recorded(n, ticks, tmp_path / "ticks", upto=10)  # a run that ends early (converged)
    assert list(streamed) == list(held) == ["t", *ROWS, "step"]
    for name, a in held.items():
        b = streamed[name]
        assert len(b) == 10 and b.shape == a[:10].shape
        if n >= FLOAT32_FROM and name in stream.PER_TICK:
            assert isinstance(b, OnDisk) and b.dtype == np.float32
            np.testing.assert_array_equal(np.asarray(b), a[:10].astype(np.float32))
        else:
            assert b.dtype == a.dtype
            np.testing.assert_array_equal(np.asarray(b), a[:10])
    pose = streamed["pose"]
    np.testing.assert_array_equal(pose[[2, 9], 3:5, :2], np.asarray(pose)[[2, 9], 3:5, :2])  # any piece
    assert sorted(p.name for p in (tmp_path / "ticks").iterdir()) == sorted(f"{name}.raw" for name in ROWS)


def test_a_recording_of_no_ticks_reads_as_empty_arrays(tmp_path):
    empty = recorded(5, [], tmp_path / "ticks")
    assert empty["pose"].shape == (0, 5, 3) and np.asarray(empty["pose"]).shape == (0, 5, 3)


@pytest.mark.parametrize("n", [9, FLOAT32_FROM])
def test_trajectory_npz_from_disk_is_the_one_from_memory(tmp_path, monkeypatch, n):
    monkeypatch.setattr(ColumnMajor, "BLOCK_BYTES", 5 * 8 * 13)  # blocks of a few robots, the last one short
    ticks = ticks_of(n, 13, seed=1)
    radius = np.full(n, 0.037)
    held = write_trajectory(tmp_path / "held.npz", recorded(n, ticks), radius)
    streamed = write_trajectory(tmp_path / "streamed.npz", recorded(n, ticks, tmp_path / "ticks"), radius)
    with np.load(held) as a, np.load(streamed) as b:
        assert sorted(a.files) == sorted(b.files)
        for name in a.files:
            assert a[name].dtype == b[name].dtype and a[name].shape == b[name].shape, name
            np.testing.assert_array_equal(a[name], b[name])
            assert a[name].flags.f_contiguous == b[name].flags.f_contiguous, name
    assert abs(held.stat().st_size - streamed.stat().st_size) <= 0.01 * held.stat().st_size


def test_metrics_from_disk_are_the_metrics_from_memory(tmp_path):
    n, ticks = 12, ticks_of(12, 30, seed=2)
    held, streamed = recorded(n, ticks), recorded(n, ticks, tmp_path / "ticks")

    def metrics(a):
        steps = None
        record = TrueRecord(a["t"], a["pose"], np.full(n, 0.037), a["goal"], 0.5, None, steps)
        return summarise(record, wall_s=1.0, contacts=0)

    assert json.dumps(metrics(held)) == json.dumps(metrics(streamed))


def test_a_central_run_directory_is_the_in_memory_run_and_keeps_no_raw_files(tmp_path):
    scene = load_scene("circle", robots=12, duration=3.0, seed=4)
    held = simulate(scene, progress=None)
    path = run_central(scene, tmp_path / "run", video=False, plots=True, progress=None)
    assert not (path / stream.SCRATCH).exists() and not list(tmp_path.glob(f"*{PARTIAL_SUFFIX}"))
    with np.load(path / "trajectory.npz") as z:
        for name, a in held.arrays.items():
            np.testing.assert_array_equal(z[name], a)


def test_an_aborted_central_run_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(stream, "CHUNK_BYTES", 5 * 12 * 70)  # five ticks a chunk
    pose = tmp_path / f"run{PARTIAL_SUFFIX}" / stream.SCRATCH / "pose.raw"

    class Breaks:  # a live view that fails mid-run, after chunks of ticks reached the files
        def tick(self, tick, *_):
            if tick == 20:
                # ticks 0-14 at least, in chunks of five (15-19 may still be on their way)
                assert pose.stat().st_size >= 15 * 12 * 3 * 8
                raise RuntimeError("view gone")

    scene = load_scene("circle", robots=12, duration=5.0, seed=4)
    with pytest.raises(RuntimeError, match="view gone"):
        run_central(scene, tmp_path / "run", video=False, plots=False, progress=None, view=Breaks())
    assert list(tmp_path.iterdir()) == []


def test_a_chunk_that_cannot_be_written_fails_the_recording(tmp_path, monkeypatch):
    """Chunks are written on a thread of their own: a write that failed (here a file gone from the
    disk) fails the recording at the next chunk or at its end, not a run with a hole in it."""
    monkeypatch.setattr(stream, "CHUNK_BYTES", 3 * 5 * 70)  # three ticks a chunk
    ticks = ticks_of(5, 10)
    rec = TickRecorder(len(ticks), 5, tmp_path / "ticks")
    (tmp_path / "ticks" / "pose.raw").unlink()
    with pytest.raises(FileNotFoundError):
        for k, (t, step, rows) in enumerate(ticks):
            rec.record(k, t, step, rows)
        rec.arrays(len(ticks))
    assert not (tmp_path / "ticks" / "pose.raw").exists()
