"""How a central run ends, as a distributed run of the same scene ends: at the duration (its last tick the poses
after the last step, beginning no image), or at a stop signal (what was recorded written, marked incomplete)."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.central.engine import Stop, run_central


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
