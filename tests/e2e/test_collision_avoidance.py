"""Collision avoidance in the distributed runtime (issue 3): agents over zenoh, tracking noise on,
contacts and clearance measured by the recorder from the world's TRUE poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import run_pixelswarm
from tests.support.engines import engine_run


def run_scene(tmp_path: Path, toml: str, *extra: str, name: str = "run") -> tuple[dict, dict]:
    scene = tmp_path / f"{name}.toml"
    scene.write_text(toml)
    out = tmp_path / name
    result = run_pixelswarm("run", str(scene), "--out", str(out), "--no-video", "--no-plots", "-q", *extra, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))


def scene(robots: int, kinematics: str, layout: str, goals: str, duration: float, seed: int = 2) -> str:
    return f"""
robots = {robots}
seed = {seed}
duration = {duration}
[robot]
kinematics = "{kinematics}"
[layout]
{layout}
[goals]
kind = "{goals}"
"""


CIRCLE = 'kind = "circle"\nspacing = 0.2'
ROWS = 'kind = "rows"\nspacing = 0.18\ngap = 0.8'


def assert_safe_and_arrived(m: dict, traj: dict) -> None:
    assert m["contacts"] == 0, m["contact_events"][:5]
    assert m["min_clearance_m"] > 0 and m["min_clearance_substep_m"] > 0
    assert m["converged"], "not every robot reached its goal"
    err = np.hypot(*(traj["pose"][-1, :, :2] - traj["goal"][-1]).T)
    assert np.all(err <= 0.01)


@pytest.mark.slow
@pytest.mark.parametrize(
    "layout, goals",
    [(CIRCLE, "antipodal"), pytest.param(ROWS, "swap", marks=pytest.mark.xdist_group("swap-seed-1"))],
    ids=["circle", "swap"],  # the swap's run is test_one_controller's: in its group
)
def test_fourteen_epucks(tmp_path, shared_runs, layout, goals):
    if goals == "swap":
        # the shipped swap scene is these 14 e-pucks in facing rows (scene(14, "diffdrive", ROWS, "swap",
        # 90) but for the seed): seed 1's run, a process per robot, is test_one_controller's, made once
        m, traj = engine_run(shared_runs, "swap", 1, "a process per robot")
        assert m["agent_processes"] == 14
    else:
        # two agent hosts of seven: a lock-step run is the same run with a process per robot
        # (test_one_controller.py), at a fraction of the CPU
        m, traj = run_scene(tmp_path, scene(14, "diffdrive", layout, goals, 90), "-k", "7")
        assert m["agent_processes"] == 2
    assert_safe_and_arrived(m, traj)


@pytest.mark.slow
@pytest.mark.parametrize("layout, goals", [(CIRCLE, "antipodal"), (ROWS, "swap")], ids=["circle", "swap"])
def test_fifty_holonomic(tmp_path, layout, goals):
    # 50 robots in two agent hosts (the same agent code; a lock-step run is the same run however it
    # is hosted, test_one_controller.py, and fewer hosts decode fewer of each other's frames)
    m, traj = run_scene(tmp_path, scene(50, "holonomic", layout, goals, 150), "--agents-per-process", "25")
    assert_safe_and_arrived(m, traj)


@pytest.mark.slow
@pytest.mark.parametrize(
    "kinematics, robots, k, faults, clock",
    [
        ("diffdrive", 14, "1", "state:drop=0.1,delay=0.05", "lockstep"),
        ("holonomic", 50, "5", "state:drop=0.1,delay=0.05", "lockstep"),
        # most neighbours stale, some never heard since their hellos: robots stand for them (3 contacts
        # with 70 % lost before they did; 4 with 90 % before the hellos counted as states)
        ("holonomic", 20, "5", "state:drop=0.9", "lockstep"),
        # real time, no hellos: neighbours never heard are seen where the tracker sees them (contacts
        # before they were)
        ("holonomic", 20, "1", "state:drop=0.99", "realtime"),
    ],
)
def test_loss_and_delay_on_states_cause_no_contact(tmp_path, kinematics, robots, k, faults, clock):
    # 25 s: past the crowd in the circle's centre, where the states lost and late matter
    flags = ("--faults", faults, "--agents-per-process", k, "--clock", clock)
    m, _ = run_scene(tmp_path, scene(robots, kinematics, CIRCLE, "antipodal", 25), *flags)
    assert m["dropped_messages"].get("fault", 0) > 0  # the faults really happened
    assert m["contacts"] == 0, m["contact_events"][:5]
    assert m["min_clearance_m"] > 0


HEAD_ON = scene(2, "diffdrive", 'kind = "list"\nposes = [[-0.5, 0.0, 0.0], [0.5, 0.0, 3.14159]]', "antipodal", 40)
CROSSING = scene(4, "diffdrive", 'kind = "circle"\nradius = 0.6', "antipodal", 40)
PASS_BETWEEN = """
robots = 3
seed = 2
duration = 40
[robot]
kinematics = "diffdrive"
[layout]
kind = "list"
poses = [[-0.6, 0.0, 0.0], [0.0, 0.115, 0.0], [0.0, -0.115, 0.0]]
[goals]
kind = "list"
positions = [[0.6, 0.0], [0.0, 0.115], [0.0, -0.115]]
"""


@pytest.mark.slow
@pytest.mark.parametrize("toml", [HEAD_ON, CROSSING, PASS_BETWEEN], ids=["head-on", "4-way", "pass-between"])
def test_symmetric_and_tight_cases_resolve_without_deadlock(tmp_path, toml):
    m, traj = run_scene(tmp_path, toml)
    assert_safe_and_arrived(m, traj)
    assert m["time_to_converge_s"] < 30


@pytest.mark.slow
def test_dynamic_obstacle_and_pursuer_through_a_formation(tmp_path):
    """Paper Fig. 19: an uncontrolled robot crosses a formation of 14, another pursues it."""
    from coordinator.scene import SCENE_DIR

    # two agent hosts: a lock-step run is the same run with a process per robot (test_one_controller.py)
    m, traj = run_scene(tmp_path, (SCENE_DIR / "dynamic.toml").read_text(), "-k", "8")
    assert m["contacts"] == 0, m["contact_events"][:5]
    assert m["min_clearance_m"] > 0
    pose = traj["pose"]
    assert pose[-1, 14, 0] > 1.1  # the obstacle crossed the whole formation
    assert np.hypot(*(pose[-1, 15, :2] - pose[-1, 14, :2])) < 0.4  # the pursuer caught up with it
