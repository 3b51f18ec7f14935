"""`pixelswarm run --engine central` writes what the distributed engine writes (docs/outputs.md), stops as it
stops on Ctrl-C or SIGTERM (docs/cli.md), and refuses the real-time clock it cannot keep."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from coordinator import shapes
from tests.conftest import REPO, assert_usage_error, run_scenes, start_run, wait_for

# metrics.json keys docs/outputs.md says only the distributed engine writes
DISTRIBUTED_ONLY = {"agents_per_process"}


@pytest.mark.slow
def test_central_and_distributed_runs_of_an_image_write_the_same_keys_and_agreements(tmp_path):
    image = tmp_path / "two.png"
    cv2.imwrite(str(image), shapes.draw("two_squares", 128)[:, :, ::-1])
    flags = (str(image), "--robots", "6", "--duration", "20")
    runs = run_scenes(tmp_path, {"central": (*flags, "--engine", "central"), "distributed": flags})
    (m_central, central), (m_distributed, distributed) = runs["central"], runs["distributed"]
    assert set(m_distributed) - set(m_central) <= DISTRIBUTED_ONLY and set(m_central) <= set(m_distributed)
    assert m_central["engine"] == "central" and m_central["complete"] and m_central["converged"]
    assert m_central["agent_processes"] == 0 and m_central["crashes"] == [] and m_central["dropped_messages"] == {}
    assert m_central["missed_ticks_by_robot"] == [0] * 6 and len(m_distributed["missed_ticks_by_robot"]) == 6
    assert m_central["stepping_wall_s"] > 0 and m_central["commands_applied"] == m_central["commands_sent"] > 0
    assert set(central) == set(distributed)
    # one seed, one run: the same goal sets, and each robot's goal from the same agreement of the same auction
    auction = ["goal_sets", "goal_set_robots", "goal_set_epoch", "agreements", "assignment_epoch", "assignment"]
    for name in [*auction, "assignment_instance", "agreement_positions", "agreement_penalties"]:
        np.testing.assert_array_equal(central[name], distributed[name], err_msg=name)


def test_docs_name_the_keys_only_the_distributed_engine_writes():
    text = (REPO / "docs" / "outputs.md").read_text()
    for key in DISTRIBUTED_ONLY:
        assert f"`{key}` (distributed engine only" in text, key


def assert_stopped(proc, out: Path, signum: int) -> None:
    """Exit 128 + signal, the run directory's path on stdout, one line on stderr, what was recorded written."""
    stdout, stderr = proc.communicate(timeout=120)
    name = signal.Signals(signum).name
    assert proc.returncode == 128 + signum, stderr
    assert stderr.strip() == f"pixelswarm run: stopped by {name}; what was recorded is in {out}, marked incomplete"
    assert stdout.strip() == str(out) and not out.with_name(out.name + ".partial").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] is False and metrics["end_reason"] == "interrupted" and metrics["samples"] >= 1
    assert (out / "INCOMPLETE").read_text().splitlines()[0] == "interrupted"
    assert len(np.load(out / "trajectory.npz")["t"]) == metrics["samples"]


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_writes_what_the_central_run_recorded_marked_incomplete(tmp_path, spawned, signum):
    out = tmp_path / "r"
    # a moving image never ends on convergence: the run goes on for an hour of display time (a minute of wall time)
    proc = start_run(spawned, "rotating-triangle", out, "--engine", "central", "--duration", "3600")
    assert wait_for(lambda: (out.with_name("r.partial") / ".ticks").exists() or proc.poll() is not None, 120)
    time.sleep(0.5)  # some ticks in (ended at once, the first tick would be written, as it is)
    assert proc.poll() is None
    proc.send_signal(signum)
    assert_stopped(proc, out, signum)


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ("--clock", "realtime"),
            "--clock realtime needs the distributed engine: the central engine has no wall clock",
        ),
        ((), 'clock = "realtime" needs the distributed engine'),
    ],
)
def test_the_central_engine_refuses_the_real_time_clock(tmp_path, args, message):
    scene = tmp_path / "scene.toml"
    scene.write_text(f'robots = 3\nduration = 5.0\nclock = "{"lockstep" if args else "realtime"}"\n')
    assert_usage_error(tmp_path, message, str(scene), "--engine", "central", *args)
