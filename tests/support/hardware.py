"""Runs on emulated hardware (test_hardware_run, test_pose_trust_hardware): a real-time circle scene, the
commands an emulated robot received, and `pixelswarm run --hardware` as its own process."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from sim.emulators.lab import Lab
from tests.conftest import REPO, pixelswarm_cmd

SCENE = """name = "hw-circle"
robots = {robots}
seed = 1
clock = "realtime"
duration = {duration}

[robot]
kinematics = "diffdrive"

[layout]
kind = "circle"
spacing = 0.25

[goals]
kind = "antipodal"
"""


def scene_file(tmp_path: Path, robots: int = 4, duration: float = 60.0) -> Path:
    path = tmp_path / "hw-circle.toml"
    path.write_text(SCENE.format(robots=robots, duration=duration))
    return path


def moving_commands(log: list) -> np.ndarray:
    rows = np.array(log, float).reshape(-1, 3)
    return rows[(rows[:, 1] != 0) | (rows[:, 2] != 0)]


def start_run(
    tmp_path: Path, scene: Path, hw: Path, endpoint: str, spawned: list, own_group: bool = False
) -> subprocess.Popen:
    """`pixelswarm run SCENE --hardware FILE` as its own process, a client of the router at ``endpoint``;
    ``own_group``: in a process group of its own, as a shell starts a command."""
    cmd = pixelswarm_cmd("run", str(scene), "--hardware", str(hw), "-e", endpoint)
    run = subprocess.Popen(
        [*cmd, "--out", str(tmp_path / "run"), "--no-video", "--no-plots", "-q"],
        cwd=REPO,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=own_group,
    )
    spawned.append(run)
    return run


def all_moving(lab: Lab, commands: int = 10) -> bool:
    return all(len(moving_commands(lab.emulator.log(r))) >= commands for r in range(lab.scene.robots))
