"""`make run` as a newcomer types it: a swarm of 20 robot processes and a complete run directory."""
from __future__ import annotations

import json
import shutil
import subprocess

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from .conftest import REPO

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


def test_make_run_writes_a_complete_run_directory(tmp_path):
    out = tmp_path / "run"
    result = subprocess.run(["make", "-s", "run", f"RUN_ARGS=--out {out}"], cwd=REPO, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == str(out)
    assert "[circle] 20 robots" in result.stderr  # progress output

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["robots"] == 20 and metrics["agent_processes"] == 20
    for key in ["duration_s", "wall_s", "realtime_factor", "min_clearance_m", "contacts", "max_overlap_m",
                "converged", "time_to_converge_s", "path_length_m", "messages_per_robot_s", "bytes_per_robot_s",
                "missed_ticks", "agents_crashed"]:
        assert key in metrics
    assert len(metrics["path_length_m"]) == 20

    traj = np.load(out / "trajectory.npz")
    T = len(traj["t"])
    assert T > 10
    assert traj["pose"].shape == (T, 20, 3) and traj["velocity"].shape == (T, 20, 2)
    assert traj["color"].shape == (T, 20, 3) and traj["color"].dtype == np.uint8
    assert traj["goal"].shape == (T, 20, 2) and traj["radius"].shape == (20,)

    with open(out / "log.mcap", "rb") as f:
        reader = make_reader(f)
        topics = {channel.topic for _, channel, _ in reader.iter_messages(topics=["/pose", "/state", "/cmd"])}
    assert topics == {"/pose", "/state", "/cmd"}

    video = cv2.VideoCapture(str(out / "display.mp4"))
    frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, frame = video.read()
    video.release()
    assert ok and frames >= T * 0.9 and frame.max() > 0
    for plot in ["clearance.png", "trajectories.png"]:
        assert (out / plot).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
