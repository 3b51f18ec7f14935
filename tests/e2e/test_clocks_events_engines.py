"""The real-time clock, perturbation events, the central engine, and scene validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.scene import SceneError, load_scene, scene_from_dict, shipped_scenes
from tests.conftest import run_pixelswarm, run_scenes

SMALL = """
robots = 6
seed = 4
duration = {duration}
clock = "{clock}"
[robot]
kinematics = "diffdrive"
[layout]
kind = "circle"
spacing = 0.25
[goals]
kind = "antipodal"
{extra}
"""


def run(tmp_path, toml, *args, name="run"):
    path = tmp_path / f"{name}.toml"
    path.write_text(toml)
    out = tmp_path / name
    result = run_pixelswarm("run", str(path), "--out", str(out), "--no-video", "--no-plots", "-q", *args, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads((out / "metrics.json").read_text()), np.load(out / "trajectory.npz")


@pytest.mark.slow
@pytest.mark.wall_clock
def test_realtime_clock_follows_the_wall_clock(tmp_path):
    m, traj = run(tmp_path, SMALL.format(duration=5.0, clock="realtime", extra=""))
    assert len(traj["t"]) == 51 and traj["t"][-1] == pytest.approx(5.0)
    # 10 Hz as on hardware: the world never runs ahead of the wall clock
    assert m["stepping_wall_s"] >= 4.9
    assert m["commands_applied"] >= 6 * 40  # agents kept up (a few missed ticks are allowed)


@pytest.mark.slow
def test_a_robot_picked_up_by_hand_returns_to_its_goal(tmp_path):
    # moved at t = 16 s, after the swarm has arrived, to a free spot; the run ends 8 s after all hold
    extra = '[[events]]\nt = 16.0\nkind = "teleport"\nrobot = 2\npose = [0.0, 0.65, 0.0]\n[end]\nconverge_hold = 8.0'
    # two agent hosts: a lock-step run is the same run with a process per robot (test_one_controller.py)
    m, traj = run(tmp_path, SMALL.format(duration=60.0, clock="lockstep", extra=extra), "-k", "3")
    t, pose = traj["t"], traj["pose"]
    k = int(np.searchsorted(t, 16.0))
    assert np.allclose(pose[k, 2, :2], [0.0, 0.65])  # the event happened
    assert m["converged"] and m["contacts"] == 0
    assert m["time_to_converge_s"] > 16.0  # converged again after being moved


@pytest.mark.slow
def test_central_engine_matches_the_scene_and_is_safe(tmp_path):
    toml = SMALL.format(duration=60.0, clock="lockstep", extra="")
    # and the same scene distributed (in two agent hosts), run at the same time
    runs = run_scenes(tmp_path, {"run": (toml, "--engine", "central"), "distributed": (toml, "-k", "3")})
    (m, traj), (m2, traj2) = runs["run"], runs["distributed"]
    assert m["engine"] == "central" and m["contacts"] == 0 and m["converged"]
    assert traj["pose"].shape[1] == 6
    # same scene, distributed: same start, same goals, both arrive
    assert m2["engine"] == "distributed" and m2["converged"]
    np.testing.assert_allclose(traj["pose"][0], traj2["pose"][0])
    np.testing.assert_allclose(traj["goal"][-1], traj2["goal"][-1], atol=1e-6)


# Shipped scenes whose goal sets take seconds to make, loaded in full by another test that checks
# the same (robots, a pose each) and more: loaded once per `make test`, there
LOADED_ELSEWHERE = {
    "paper-sequence-1000": "tests/unit/test_large_scene.py",
    "paper-sequence-10000": "tests/unit/test_large_scene.py",
    "leaf-1000": "tests/unit/test_animation.py::test_the_shipped_animations_load",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", [name for name in shipped_scenes() if name not in LOADED_ELSEWHERE])
def test_shipped_scenes_load(name):
    scene = load_scene(name)
    assert scene.robots >= 1 and scene.poses.shape == (scene.robots, 3)


def test_the_scenes_loaded_elsewhere_are_shipped():
    assert set(LOADED_ELSEWHERE) <= set(shipped_scenes())


@pytest.mark.parametrize(
    "data, message",
    [
        ({"robots": 3, "layout": {"kind": "spiral"}}, "layout kind"),
        ({"robots": 3, "goals": {"kind": "everywhere"}}, "goals kind"),
        ({"robots": 3, "clock": "sundial"}, "clock must be"),
        ({"robots": 3, "events": [{"kind": "teleport", "robot": 9, "t": 1.0, "pose": [0, 0, 0]}]}, "robot must be"),
        ({"robots": 3, "scripted": [{"robot": 0, "waypoints": [[1, 0, 0]]}]}, "waypoints"),
        ({"robots": 3, "colour": "red"}, "unknown key"),
        ({"robots": 3, "deadline": 0}, "deadline must be"),
    ],
)
def test_invalid_scenes_say_what_is_wrong(data, message):
    with pytest.raises(SceneError, match=message):
        scene_from_dict(data)


def test_a_scene_sets_the_lock_step_deadline_and_the_command_line_checks_its_own(tmp_path, capsys):
    """A scene whose agents take longer than 2 s at an image change (1000 robots match the goal sets)
    names its own deadline; a bad --deadline is a one-line usage error that starts nothing."""
    from sim.cli.main import main

    assert load_scene("paper-sequence-1000").deadline == 8.0
    assert scene_from_dict({"robots": 3}).deadline == 2.0
    out = tmp_path / "run"
    assert main(["run", "circle", "--robots", "3", "--deadline", "-1", "--out", str(out)]) == 2
    assert "--deadline must be a positive number" in capsys.readouterr().err
    assert not out.exists() and not out.with_name("run.partial").exists()
