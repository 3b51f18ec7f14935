"""Runs on emulated hardware (test_hardware_run, test_pose_trust_hardware): a real-time crossing scene, the
commands an emulated robot received, and `pixelswarm run --hardware` as its own process."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from sim.emulators.lab import Lab
from sim.processes import start_session
from tests.conftest import REPO, pixelswarm_cmd

SCENE = """name = "hw-crossing"
robots = {robots}
seed = 1
clock = "realtime"
duration = {duration}

[robot]
kinematics = "diffdrive"

[layout]
kind = "list"
poses = {poses}

[goals]
kind = "list"
positions = {goals}
"""
# Two pairs of robots swap places across the centre, each pair on lanes 16 cm apart, one pair across
# the other: every robot meets two others. (Four robots on a circle swapping with the robot opposite
# all meet in the centre, and creep round each other there for seconds.)
POSES = [(0.3, 0.08, 3.14159), (-0.3, -0.08, 0.0), (0.08, -0.3, 1.5708), (-0.08, 0.3, -1.5708)]
GOALS = np.array([(-0.3, 0.08), (0.3, -0.08), (0.08, 0.3), (-0.08, -0.3)])


def scene_file(tmp_path: Path, robots: int = 4, duration: float = 60.0) -> Path:
    """The crossing of up to four robots (the first ``robots`` of POSES and GOALS), in real time."""
    path = tmp_path / "hw-crossing.toml"
    poses, goals = [list(p) for p in POSES[:robots]], GOALS[:robots].tolist()
    path.write_text(SCENE.format(robots=robots, duration=duration, poses=poses, goals=goals))
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
    cmd += ["--out", str(tmp_path / "run"), "--no-video", "--no-plots", "-q"]
    run = (start_session if own_group else subprocess.Popen)(cmd, cwd=REPO, stderr=subprocess.PIPE, text=True)
    spawned.append(run)
    return run


def all_moving(lab: Lab, commands: int = 10) -> bool:
    return all(len(moving_commands(lab.emulator.log(r))) >= commands for r in range(lab.scene.robots))
