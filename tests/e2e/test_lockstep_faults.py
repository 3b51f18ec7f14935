"""Injected loss and delay in lock-step count in ticks, drawn per message: two runs of one seed with
faults are the same run, however fast the machine steps (a study's condition is reproducible)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import start_run

FAULTS = "state:drop=0.2,delay=0.1,jitter=0.02"


def two_runs_at_once(spawned: list, tmp_path, *args: str) -> tuple[dict, dict, dict]:
    """The first run's metrics and both runs' trajectories of the circle with ``args``, the two runs
    at once, each beside the other (a run waits on its messages more than it computes). Only the
    trajectories are compared: the world steps on after the recorded end until it hears of it, and
    counts those ticks too."""
    runs = {name: start_run(spawned, "circle", tmp_path / name, *args) for name in ("first", "second")}
    for proc in runs.values():
        _, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, stderr[-3000:]
    metrics = json.loads((tmp_path / "first" / "metrics.json").read_text())
    first, second = (dict(np.load(tmp_path / name / "trajectory.npz")) for name in runs)
    return metrics, first, second


@pytest.mark.slow
def test_two_lockstep_runs_with_lost_and_delayed_states_are_the_same_run(tmp_path, spawned):
    """In agent hosts of two, beside whatever else the machine runs: an agent waits for its
    neighbours' states to arrive, then the fault plan decides, by the message, what it hears."""
    args = ("--robots", "10", "--clock", "lockstep", "--seed", "3", "--faults", FAULTS, "-k", "2")
    first_metrics, first, second = two_runs_at_once(spawned, tmp_path, *args)
    assert first_metrics["dropped_messages"].get("fault", 0) > 0  # the loss really happened
    assert first_metrics["contacts"] == 0 and first_metrics["converged"]
    assert len(first["t"]) == len(second["t"])
    assert np.array_equal(first["pose"], second["pose"])


@pytest.mark.slow
def test_two_lockstep_runs_with_most_commands_lost_are_the_same_run(tmp_path, spawned):
    """Robots go half a second without a command here, and the body node sends their bodies standing
    beside their agents' states of the same ticks; neighbours take the body's whichever comes first
    (agent.neighbour_table), or the two runs part (they did, seeds 3 and 4, before they did)."""
    args = ("--robots", "8", "--clock", "lockstep", "--seed", "3", "--faults", "cmd:drop=0.6", "--duration", "8")
    metrics, first, second = two_runs_at_once(spawned, tmp_path, *args)
    assert metrics["contacts"] == 0 and metrics["missed_ticks"] > 0
    assert len(first["t"]) == len(second["t"])
    assert np.array_equal(first["pose"], second["pose"])


@pytest.mark.slow
def test_two_lockstep_runs_with_lost_commands_are_the_same_run(tmp_path, spawned):
    """The world draws a command's fate from the command itself, and does not wait out its deadline
    for one that came and was lost (a robot without its command stands for the tick)."""
    args = ("--robots", "8", "--clock", "lockstep", "--seed", "3", "--faults", "cmd:drop=0.2", "--duration", "20")
    metrics, first, second = two_runs_at_once(spawned, tmp_path, *args)
    assert metrics["dropped_messages"].get("fault", 0) > 0 and metrics["missed_ticks"] > 0
    assert metrics["contacts"] == 0 and metrics["converged"]
    assert len(first["t"]) == len(second["t"])
    assert np.array_equal(first["pose"], second["pose"])
