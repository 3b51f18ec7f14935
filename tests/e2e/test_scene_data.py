"""Scenes are data (issue 21): a run makes its goal sets once and saves them in the run directory with
the resolved scene; the world and the coordinator read them from there, the world without the image
pipeline."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from coordinator.resolved import GOAL_SETS_FILE, SCENE_FILE, load_resolved, save_resolved, stored_counts
from coordinator.scene import SceneError, load_scene, scene_from_dict, scene_goal_set
from sim.central.engine import run_central
from tests.conftest import REPO, run_scene

# A small image scene of every kind the loader makes goal sets for: [[steps]] with region counts and a
# moving step, a scripted mover and a pursuer (fewer robot pixels than robots), and a drawn animation.
STEPS = {
    "name": "two-steps",
    "robots": 6,
    "seed": 3,
    "layout": {"kind": "grid", "spacing": 0.2},
    "steps": [
        {"shape": "disk_and_line", "region_counts": {"0": 4, "1": 2}, "hold": 4.0},
        {"shape": "ring", "hold": 3.0, "motion": {"angular_velocity": 0.1, "velocity": [0.01, 0.0]}},
    ],
    "scripted": [{"robot": 5, "waypoints": [[0.0, 0.4, 0.4], [5.0, 0.4, -0.4]]}],
    "events": [{"t": 1.0, "kind": "teleport", "robot": 2, "pose": [0.1, 0.1, 0.0]}],
    "noise": {"tracking_xy": 0.001},
}
ANIMATION = {
    "name": "triangle",
    "robots": 5,
    "animation": {"keyframes": "triangle", "frame_time": 4.0, "first_hold": 8.0, "size": 96},
    "layout": {"kind": "grid", "spacing": 0.2},
}
IMAGE_CODE = ("cv2", "sklearn", "coordinator.goals.pipeline", "coordinator.goals.image", "coordinator.keyframes")


def _same_goal_sets(a, b, counts) -> None:
    for k in range(len(a.steps)):
        for n in counts:
            (ga, ca), (gb, cb) = scene_goal_set(a, k, n), scene_goal_set(b, k, n)
            np.testing.assert_array_equal(ga, gb, err_msg=f"step {k}, {n} robots")
            np.testing.assert_array_equal(ca, cb, err_msg=f"step {k}, {n} robots")


@pytest.mark.parametrize("table", [STEPS, ANIMATION], ids=["steps", "animation"])
def test_a_resolved_scene_round_trips_to_the_same_scene_and_goal_sets(tmp_path, table):
    scene = scene_from_dict(table, source=str(tmp_path / "scene.toml"))
    save_resolved(scene, tmp_path)
    again = load_resolved(tmp_path)
    assert again.arena == scene.arena
    assert again.steps == scene.steps and again.step_starts == scene.step_starts
    assert again.events == scene.events and again.pursuers == scene.pursuers and again.noise == scene.noise
    assert again.scripted.keys() == scene.scripted.keys()
    for r in scene.scripted:
        np.testing.assert_array_equal(again.scripted[r], scene.scripted[r])
    np.testing.assert_array_equal(again.poses, scene.poses)
    np.testing.assert_array_equal(again.goal_positions, scene.goal_positions)
    assert again.image_goals is not None and scene.image_goals is not None
    assert again.image_goals.arena == scene.image_goals.arena  # K_r
    _same_goal_sets(scene, again, stored_counts(scene))
    with pytest.raises(ValueError):
        again.goal_set[0, 0] = 1.0  # shared by every caller: read-only, as the pipeline's own


def test_the_run_directory_holds_the_goal_sets_and_the_arena(tmp_path):
    scene = scene_from_dict(STEPS, source=str(tmp_path / "scene.toml"))
    assert stored_counts(scene) == [5, 6]  # the robot pixels, and every robot (the arena holds those)
    save_resolved(scene, tmp_path)
    record = json.loads((tmp_path / SCENE_FILE).read_text())
    assert tuple(record["arena"]) == scene.arena
    assert record["image_goals"]["arena"] == scene.image_goals.arena
    with np.load(tmp_path / GOAL_SETS_FILE) as npz:
        assert float(npz["arena"]) == scene.image_goals.arena
        for k in range(len(scene.steps)):
            goals, colors = scene_goal_set(scene, k, 5)
            np.testing.assert_array_equal(npz[f"goals_{k}_5"], goals)
            np.testing.assert_array_equal(npz[f"colors_{k}_5"], colors)


def test_a_count_the_run_did_not_save_comes_from_the_pipeline_in_the_same_arena(tmp_path):
    """Robots lost mid-run (paper 5.1.2): the coordinator makes that count's goal set, in K_r."""
    toml = tmp_path / "scene.toml"
    toml.write_text(
        'robots = 6\nseed = 3\n[layout]\nkind = "grid"\nspacing = 0.2\n[[steps]]\nshape = "disk"\nhold = 4.0\n'
    )
    scene = load_scene(str(toml))
    save_resolved(scene, tmp_path)
    again = load_resolved(tmp_path)
    assert again.image_goals.counts == [6]
    _same_goal_sets(scene, again, [4])
    assert again.image_goals.counts == [4, 6]


def test_the_world_reads_the_run_directory_without_the_image_pipeline(tmp_path):
    """A fresh world process: its module, the resolved scene and the simulated bodies, and not one
    module of the image pipeline (OpenCV, the CVT, the keyframes)."""
    scene = scene_from_dict(ANIMATION, source=str(tmp_path / "scene.toml"))
    save_resolved(scene, tmp_path)
    code = (
        "import json, sys\n"
        "import sim.node.world\n"
        "from coordinator.resolved import load_resolved\n"
        "from sim.bodies.tracker import world_of\n"
        f"scene = load_resolved({str(tmp_path)!r})\n"
        "params, world = world_of(scene)\n"
        f"print(json.dumps([scene.arena, [m for m in {IMAGE_CODE!r} if m in sys.modules]]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    arena, loaded = json.loads(out.stdout)
    assert tuple(arena) == scene.arena
    assert loaded == []


def test_the_coordinator_of_a_run_without_images_starts_without_scipy_or_the_image_pipeline(tmp_path):
    """A fresh coordinator process of a scene whose goals are no image's (the circle's antipodes): its
    module, the resolved scene and the goal set it serves, and neither SciPy nor the image pipeline,
    which every run's coordinator loaded at its start before."""
    save_resolved(load_scene("circle", robots=4, seed=1), tmp_path)
    code = (
        "import json, sys\n"
        "from coordinator import service\n"
        "from coordinator.resolved import load_resolved\n"
        "from tests.support.fake_bus import Bus\n"
        f"[(key, goals)] = service.Coordinator(Bus(), load_resolved({str(tmp_path)!r}))._answer()\n"
        f"print(json.dumps([m for m in ('scipy', 'coordinator.keyframes', *{IMAGE_CODE!r}) if m in sys.modules]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout) == []


@pytest.mark.parametrize("module", ["sim.node.world", "coordinator.service"])
def test_a_child_given_no_resolved_scene_says_so_in_one_line(tmp_path, module):
    (tmp_path / SCENE_FILE).write_text('{"name": "x"}')
    out = subprocess.run(
        [sys.executable, "-m", module, "--run-dir", str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "not a resolved scene" in out.stderr and "Traceback" not in out.stderr
    with pytest.raises(SceneError, match="cannot read"):
        load_resolved(tmp_path / "missing")


def test_a_central_run_directory_holds_its_resolved_scene(tmp_path):
    scene = scene_from_dict({**STEPS, "duration": 0.5}, source=str(tmp_path / "scene.toml"))
    run = run_central(scene, tmp_path / "run", video=False, progress=None)
    again = load_resolved(run)
    assert again.arena == scene.arena and again.duration == 0.5
    _same_goal_sets(scene, again, stored_counts(scene))


@pytest.mark.slow
def test_a_distributed_image_run_shows_the_goal_sets_it_saved(tmp_path):
    """The launcher saves the goal sets once; the coordinator publishes them from the run directory,
    and the world keeps to the arena saved there."""
    toml = (
        'robots = 4\nseed = 2\nduration = 3.0\n[robot]\nkinematics = "holonomic"\n'
        '[layout]\nkind = "grid"\nspacing = 0.2\n[[steps]]\nshape = "disk"\nhold = 3.0\n'
    )
    metrics, traj = run_scene(tmp_path, toml, "--clock", "lockstep", name="run")
    assert metrics["complete"] and metrics["converged"]
    scene = load_scene(str(tmp_path / "run.toml"))
    saved = load_resolved(tmp_path / "run")
    assert saved.arena == scene.arena
    _same_goal_sets(scene, saved, [4])
    goals, colors = scene_goal_set(scene, 0, 4)
    np.testing.assert_allclose(traj["goal_sets"][0], goals, atol=1e-6)  # float32 on the wire
    np.testing.assert_array_equal(traj["goal_set_colors"][0], colors)
