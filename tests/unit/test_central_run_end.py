"""How a central run ends, as a distributed run of the same scene ends: at the duration (its last tick the poses
after the last step, beginning no image), or at a stop signal (what was recorded written, marked incomplete)."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.central.engine import Agreements, Stop, run_central
from transport.codec import Goals


def test_a_duration_on_an_image_step_boundary_begins_no_image_in_its_last_tick(tmp_path):
    """paper-sequence's second image begins at 30 s: a 30 s run shows only the first, and has converged on it
    (the central engine once began the second in its last tick: a phantom step, and converged false)."""
    scene = load_scene("paper-sequence", duration=30.0)
    assert scene.step_starts[1] == 30.0
    out = run_central(scene, tmp_path / "run", video=False, plots=False, progress=None)
    metrics = json.loads((out / "metrics.json").read_text())
    traj = np.load(out / "trajectory.npz")
    assert traj["t"][-1] == 30.0 and set(traj["step"].tolist()) == {0}
    assert [s["index"] for s in metrics["steps"]] == [0] and metrics["steps"][0]["t_end"] == 30.0
    assert metrics["converged"] and metrics["end_reason"] == "duration" and metrics["complete"]


def test_a_stop_signal_ends_the_run_at_its_tick_written_marked_incomplete(tmp_path):
    """A signal already received when the run starts: its first tick is recorded and written, without the video."""
    scene = load_scene("swap", robots=4, seed=1, duration=30.0)
    stop, before = Stop(signal=signal.SIGTERM), signal.getsignal(signal.SIGTERM)
    out = run_central(scene, tmp_path / "run", video=True, plots=False, progress=None, stop=stop)
    assert stop.interrupted and out == tmp_path / "run"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] is False and metrics["end_reason"] == "interrupted" and metrics["samples"] == 1
    assert (out / "INCOMPLETE").read_text() == "interrupted\n"
    assert not (out / "display.mp4").exists() and (out / "trajectory.npz").exists()
    assert signal.getsignal(signal.SIGTERM) == before  # the handlers before the run are back


def test_a_second_stop_signal_abandons_the_writing():
    stop = Stop()
    stop.on_signal(signal.SIGINT, None)
    with pytest.raises(KeyboardInterrupt):  # run_central aborts its run directory: nothing is written
        stop.on_signal(signal.SIGINT, None)
    assert stop.signal == signal.SIGINT


def test_agreements_streamed_to_a_directory_are_those_held_in_memory_by_epoch_and_instance(tmp_path):
    """A run written to a directory streams its agreements' rows there: trajectory.npz gets the same arrays as
    when they are held, sorted by (epoch, instance), and a key agreed again in a row keeps its last rows."""
    made = [((1, 0), 0.1), ((1, 1), 0.2), ((1, 1), 0.3), ((2, 0), 0.4), ((1, 2), 0.5)]
    kept = {}
    for streamed in (False, True):
        agreements = Agreements(3, goal_sets={1: Goals(1, 1, np.zeros((2, 2)), robots=np.array([0, 2]))})
        if streamed:
            agreements.stream_to(tmp_path, len(made))
        for (epoch, instance), x in made:
            agreements.agree(epoch, instance, np.array([0, 2]), np.full((2, 2), x), np.array([x, 0.0]))
        arrays = agreements.arrays(np.zeros(4, np.int64))
        kept[streamed] = {k: np.asarray(v) for k, v in arrays.items() if k.startswith("agreement")}
    held = kept[False]
    assert held["agreements"].tolist() == [[1, 0], [1, 1], [1, 2], [2, 0]]
    assert held["agreement_positions"][:, 0, 0].tolist() == [0.1, 0.3, 0.5, 0.4]
    assert np.isnan(held["agreement_positions"][:, 1]).all() and held["agreement_penalties"][1, 0] == 0.3
    for name, value in held.items():
        np.testing.assert_array_equal(kept[True][name], value)
