"""One robot controller in every engine (issue 21): with zero impairment, a lock-step run is the same
run whether every robot steps in one process (the central engine), each robot is its own process, or
K robots share an agent host. Same ticks, same positions at every tick, because every engine calls
the same robot policy (agent.core.policy) on the same information: the states of the tick before,
as the wire carries them."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import run_scene

ENGINES = {
    "central": ("--engine", "central"),
    "a process per robot": ("--engine", "distributed"),
    "agent hosts": ("--engine", "distributed", "-k", "5"),
}


@pytest.mark.slow
@pytest.mark.parametrize("scene, seed", [("swap", 1), ("circle", 2)])
def test_central_and_distributed_runs_of_one_seed_are_the_same_run(tmp_path, scene, seed):
    runs = {
        name: run_scene(
            tmp_path, scene, "--clock", "lockstep", "--seed", str(seed), *flags, name=name.replace(" ", "-")
        )
        for name, flags in ENGINES.items()
    }
    (m_central, central) = runs["central"]
    assert m_central["contacts"] == 0 and m_central["converged"]
    for name in ("a process per robot", "agent hosts"):
        metrics, traj = runs[name]
        assert metrics["missed_ticks"] == 0, name  # every agent answered every tick
        assert len(traj["t"]) == len(central["t"]), name
        np.testing.assert_array_equal(traj["t"], central["t"])
        gap = np.abs(traj["pose"][..., :2] - central["pose"][..., :2]).max()
        assert gap <= 1e-9, f"{name}: positions differ by {gap} m"
        np.testing.assert_allclose(traj["goal"][-1], central["goal"][-1], rtol=0, atol=1e-9)
        assert metrics["time_to_converge_s"] == pytest.approx(m_central["time_to_converge_s"], abs=1e-9)
