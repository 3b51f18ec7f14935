"""`make run` as a newcomer types it: a paper image (Fig. 12's disk) by 14 e-puck processes deciding
among themselves who goes where, and a complete run directory. `make run` shows the whole sequence
by default; the sequence end to end (every hold formed, agreements valid and optimal) is checked in
test_image_display_distributed.py, in agent hosts beside the central engine."""

from __future__ import annotations

import json
import shutil
import subprocess

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from tests.conftest import METRIC_KEYS, PAPER_E_PUCKS, REPO
from tests.support.assignment_quality import assert_agreements_valid
from tests.support.formation import assert_every_hold_formed

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


PAPER_DISK = (
    'name = "paper-disk"'
    + PAPER_E_PUCKS
    + """
[[steps]]
shape = "disk"
hold = 30.0
[end]
converge_hold = 3.0
"""
)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_make_run_writes_a_complete_run_directory(tmp_path):
    scene, out = tmp_path / "paper-disk.toml", tmp_path / "run"
    scene.write_text(PAPER_DISK)
    result = subprocess.run(
        ["make", "-s", "run", f"SCENE={scene}", f"RUN_ARGS=--out {out}"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == str(out)
    assert "[paper-disk] 14 robots" in result.stderr  # progress output

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["robots"] == 14 and metrics["agent_processes"] == 14
    assert set(METRIC_KEYS) <= set(metrics)
    assert len(metrics["path_length_m"]) == 14

    traj = np.load(out / "trajectory.npz")
    T = len(traj["t"])
    assert T > 10
    assert traj["pose"].shape == (T, 14, 3) and traj["velocity"].shape == (T, 14, 2)
    assert traj["color"].shape == (T, 14, 3) and traj["color"].dtype == np.uint8
    assert traj["goal"].shape == (T, 14, 2) and traj["radius"].shape == (14,)

    with open(out / "log.mcap", "rb") as f:
        reader = make_reader(f)
        topics = {
            channel.topic
            for _, channel, _ in reader.iter_messages(topics=["/pose", "/state", "/cmd", "/auction", "/goals"])
        }
    assert topics == {"/pose", "/state", "/cmd", "/auction", "/goals"}

    video = cv2.VideoCapture(str(out / "display.mp4"))
    frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, frame = video.read()
    video.release()
    assert ok and frames >= T * 0.9 and frame.max() > 0
    for plot in ["clearance.png", "trajectories.png"]:
        assert (out / plot).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    assert metrics["end_reason"] == "converged"
    assert_every_hold_formed(metrics)
    assert_agreements_valid(dict(traj))
    # the LEDs show the goals' colours: at the end every robot lights its agreed goal's colour
    last = len(traj["t"]) - 1
    row = list(traj["goal_set_epochs"]).index(int(traj["assignment_epoch"][last, 0]))
    goal = traj["assignment"][last]
    assert np.all(goal >= 0)
    assert np.array_equal(traj["color"][last], traj["goal_set_colors"][row][goal])
