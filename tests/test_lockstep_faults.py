"""Injected loss and delay in lock-step count in ticks, drawn per message: two runs of one seed with
faults are the same run, however fast the machine steps (a study's condition is reproducible)."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import run_scene

FAULTS = "state:drop=0.2,delay=0.1,jitter=0.02"


@pytest.mark.slow
def test_two_lockstep_runs_with_lost_and_delayed_states_are_the_same_run(tmp_path):
    """In agent hosts of two, beside whatever else the machine runs: an agent waits for its
    neighbours' states to arrive, then the fault plan decides, by the message, what it hears."""
    args = ("--robots", "10", "--clock", "lockstep", "--seed", "3", "--faults", FAULTS, "-k", "2")
    first_metrics, first = run_scene(tmp_path, "circle", *args, name="first")
    second_metrics, second = run_scene(tmp_path, "circle", *args, name="second")
    assert first_metrics["dropped_messages"].get("fault", 0) > 0  # the loss really happened
    assert first_metrics["contacts"] == 0 and first_metrics["converged"]
    assert len(first["t"]) == len(second["t"])
    assert np.array_equal(first["pose"], second["pose"])
