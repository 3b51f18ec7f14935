"""Image sequences in scenes ([[steps]], paper 7.2 / Fig. 12): parsing, the goal sets of every step
and robot count in one shared arena, the central engine playing them, and per-step metrics."""

from __future__ import annotations

import json
import math
import tomllib

import cv2
import numpy as np
import pytest

from coordinator import shapes
from coordinator.goals import GoalOptions, generate_goals
from coordinator.scene import SCENE_DIR, SceneError, load_scene, scene_from_dict, scene_goal_set
from coordinator.steps import scale_region_counts
from sim.central.engine import run_central
from sim.outputs.metrics import TrueRecord, step_metrics, summarise
from transport.codec import as_sent

# --dist loadgroup gives the module one xdist worker: its module fixture (the paper sequence, loaded and played) is made
# once, not once on each worker
pytestmark = pytest.mark.xdist_group("scene-steps")

BLUE_GOAL = 150  # blue channel above this: a goal on the blue part (the line of disk_and_line)


def two_steps(**extra):
    return {
        "robots": 14,
        "seed": 1,
        "layout": {"kind": "grid", "spacing": 0.2},
        "steps": [
            {"shape": "disk", "hold": 10.0},
            {"shape": "disk_and_line", "region_counts": {"0": 10, "1": 4}, "hold": 12.0},
        ],
        **extra,
    }


@pytest.fixture(scope="module")
def sequence():
    return load_scene("paper-sequence")


# --- parsing ------------------------------------------------------------------------------------
def test_paper_sequence_is_fig_12(sequence):
    assert sequence.robots == 14 and sequence.clock == "lockstep" and sequence.layout["kind"] == "grid"
    assert [s.shape for s in sequence.steps] == ["disk", "disk_and_line", "disk_and_line", "line", "L", "T"]
    assert [s.region_counts for s in sequence.steps[1:3]] == [{0: 10, 1: 4}, {0: 6, 1: 8}]
    assert sequence.duration == pytest.approx(sum(s.hold for s in sequence.steps))
    assert sequence.noise.tracking_xy > 0  # tracking noise on, as on the real testbed
    assert "description" in tomllib.loads((SCENE_DIR / "paper-sequence.toml").read_text())
    goals, colors = scene_goal_set(sequence, 0, 14)
    np.testing.assert_array_equal(sequence.goal_set, goals)
    np.testing.assert_array_equal(sequence.goal_colors, colors)
    assert np.isnan(sequence.goal_positions).all()


def test_step_windows_and_duration():
    scene = scene_from_dict(two_steps())
    assert scene.duration == 22.0 and scene.step_starts == [0.0, 10.0]
    assert [scene.step_at(t) for t in (0.0, 9.95, 10.0, 21.9, 50.0)] == [0, 0, 1, 1, 1]
    assert scene.steps[1].name == "disk_and_line" and scene.steps[1].hold == 12.0
    assert scene_from_dict(two_steps(duration=5.0)).duration == 5.0  # an explicit duration wins
    assert scene_from_dict(two_steps(), duration=7.0).duration == 7.0  # and so does the command line


def test_a_single_image_is_one_step_held_for_the_run():
    scene = scene_from_dict(
        {
            "robots": 8,
            "duration": 40.0,
            "layout": {"kind": "grid", "spacing": 0.2},
            "goals": {"kind": "image", "shape": "line"},
        }
    )
    assert len(scene.steps) == 1 and scene.steps[0].hold == 40.0 and scene.steps[0].shape == "line"
    assert scene.goal_set.shape == (8, 2) and scene.goal_colors.dtype == np.uint8
    np.testing.assert_array_equal(scene.goal_set, scene_goal_set(scene, 0, 8)[0])


def test_image_steps_are_read_relative_to_the_scene_file(tmp_path):
    cv2.imwrite(str(tmp_path / "pic.png"), shapes.draw("T", 128)[:, :, ::-1])
    path = tmp_path / "seq.toml"
    path.write_text(
        'robots = 6\n[layout]\nkind = "grid"\nspacing = 0.2\n'
        '[[steps]]\nimage = "pic.png"\nhold = 5.0\n[[steps]]\nshape = "disk"\nhold = 5.0\n'
    )
    scene = load_scene(str(path))
    assert scene.steps[0].name == "pic" and scene.steps[0].image == tmp_path / "pic.png"
    assert scene_goal_set(scene, 0, 6)[0].shape == (6, 2)


@pytest.mark.parametrize(
    "step, message",
    [
        ({"shape": "disk", "hold": 5.0, "colour": "red"}, "unknown key"),
        ({"shape": "disk", "hold": 0.0}, "hold must be a positive"),
        ({"shape": "disk", "hold": -3}, "hold must be a positive"),
        ({"shape": "disk"}, "hold must be a positive"),
        ({"hold": 5.0}, "exactly one of image"),
        ({"shape": "disk", "image": "a.png", "hold": 5.0}, "exactly one of image"),
        ({"shape": "hexagon", "hold": 5.0}, "shape must be one of"),
        ({"image": "/nonexistent/picture.png", "hold": 5.0}, "not found"),
        ({"shape": "disk_and_line", "region_counts": {"0": 20}, "hold": 5.0}, "more than N"),
        ({"shape": "disk_and_line", "region_counts": {"7": 2}, "hold": 5.0}, "regions 0..1"),
        ({"shape": "disk", "region_counts": {"0": "many"}, "hold": 5.0}, "whole numbers"),
        ({"shape": "disk", "method": "magic", "hold": 5.0}, "method must be"),
    ],
)
def test_bad_steps_say_what_is_wrong_in_one_line(step, message):
    data = {"robots": 6, "layout": {"kind": "grid", "spacing": 0.2}, "steps": [{"shape": "disk", "hold": 5.0}, step]}
    with pytest.raises(SceneError, match=message) as err:
        scene_from_dict(data)
    assert "\n" not in str(err.value) and "steps[1]" in str(err.value)


@pytest.mark.parametrize(
    "data, message",
    [
        ({"steps": [{"shape": "disk", "hold": 5.0}], "goals": {"kind": "image", "shape": "disk"}}, "not both"),
        ({"steps": []}, "one or more"),
        ({"steps": {"shape": "disk"}}, "one or more"),
        ({"goals": {"kind": "image"}}, "image"),
    ],
)
def test_bad_sequences_say_what_is_wrong(data, message):
    with pytest.raises(SceneError, match=message):
        scene_from_dict({"robots": 6, "layout": {"kind": "grid", "spacing": 0.2}, **data})


@pytest.mark.parametrize(
    "key, value",
    [("robot", "e-puck"), ("layout", "grid"), ("goals", "disk"), ("noise", 3), ("end", 1.0)]
    + [(key, value) for key in ("events", "scripted", "pursuers") for value in ("fail", ["fail"])],
)
def test_a_table_written_as_a_value_names_its_key(key, value):
    """`robot = "e-puck"` where [robot] belongs: one line that names the key, not a Python error."""
    with pytest.raises(SceneError, match=rf"^s.toml: {key} must be .*\[{key}\]") as err:
        scene_from_dict({"robots": 4, key: value}, "s.toml")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    "data, message",
    [
        ({"layout": {"kind": "circle", "spacing": "wide"}}, "layout spacing must be a positive number"),
        ({"layout": {"kind": "circle", "radius": -0.5}}, "layout radius must be a positive number"),
        ({"layout": {"kind": "blocks", "offset": [1]}}, "layout offset must be a positive number"),
        ({"end": {"converge_hold": "long"}}, "converge_hold must be a number of seconds >= 0"),
        ({"end": {"converge_hold": -1}}, "converge_hold must be a number of seconds >= 0"),
    ],
)
def test_a_bad_number_in_the_layout_or_the_end_names_its_key(data, message):
    with pytest.raises(SceneError, match=message) as err:
        scene_from_dict({"robots": 4, **data}, "s.toml")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("gap, overlapping", [(0.05, True), (0.0899, True), (0.09, False), (1.0, False)])
def test_robots_that_start_closer_than_a_diameter_are_refused_with_the_closest_gap(gap, overlapping):
    """Two robots (radius 0.045 m) placed ``gap`` apart among others far away: one line naming the
    closest centres, or accepted when they touch at most."""
    poses = [[0.0, 0.0, 0.0], [gap, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]
    data = {"robots": 4, "layout": {"kind": "list", "poses": poses}, "goals": {"kind": "antipodal"}}
    if not overlapping:
        assert scene_from_dict(data, "s.toml").robots == 4
        return
    with pytest.raises(
        SceneError, match=rf"robots start overlapping \(closest centres {gap:.3f} m, diameter 0.090 m\)"
    ):
        scene_from_dict(data, "s.toml")


# --- goal sets of a step for a robot count ------------------------------------------------------
@pytest.mark.parametrize(
    "counts, full, n, expected",
    [
        ({0: 10, 1: 4}, 14, 14, {0: 10, 1: 4}),
        ({0: 10, 1: 4}, 14, 13, {0: 9, 1: 4}),
        ({0: 10, 1: 4}, 14, 7, {0: 5, 1: 2}),
        ({0: 13, 1: 1}, 14, 5, {0: 4, 1: 1}),  # the small region keeps its robot
        ({0: 6, 1: 8}, 14, 2, {0: 1, 1: 1}),
        ({1: 4}, 14, 7, {1: 2}),  # the rest is the allocator's, for the regions not named
        (None, 14, 9, None),
    ],
)
def test_region_counts_scale_with_the_robots(counts, full, n, expected):
    assert scale_region_counts(counts, full, n) == expected


def test_goal_sets_for_fewer_robots_keep_the_artists_split(sequence):
    for n, disk, line in [(14, 10, 4), (13, 9, 4), (7, 5, 2), (2, 1, 1)]:
        goals, colors = scene_goal_set(sequence, 1, n)
        assert goals.shape == (n, 2) and colors.shape == (n, 3) and colors.dtype == np.uint8
        blue = int((colors[:, 2] > BLUE_GOAL).sum())
        assert (n - blue, blue) == (disk, line)


def test_robots_on_the_command_line_scale_the_artists_split():
    scene = load_scene("paper-sequence", robots=10)  # the file's region_counts are for 14 robots
    colors = scene_goal_set(scene, 1, 10)[1]
    assert int((colors[:, 2] > BLUE_GOAL).sum()) == 3  # 10 + 4 of 14 is 7 + 3 of 10


def test_goal_sets_are_deterministic_and_cached(sequence):
    again = load_scene("paper-sequence")
    for k in range(len(sequence.steps)):
        np.testing.assert_array_equal(scene_goal_set(sequence, k, 11)[0], scene_goal_set(again, k, 11)[0])
    first = scene_goal_set(sequence, 4, 12)
    assert scene_goal_set(sequence, 4, 12)[0] is first[0]
    assert not first[0].flags.writeable  # the cache is shared: nobody may change it


def test_every_step_and_count_shares_one_arena(sequence):
    k_r = sequence.image_goals.arena
    own = [
        generate_goals(
            shapes.draw(s.shape, 256), 14, GoalOptions(seed=sequence.seed, region_counts=s.region_counts)
        ).arena
        for s in sequence.steps
    ]
    assert k_r == pytest.approx(max(own))  # the largest conservative arena of the N-robot sets
    disk_radius = 150 / 512 * k_r  # coordinator.shapes: the disk's radius is 150/512 of the image
    for n in (14, 10, 6):
        goals = scene_goal_set(sequence, 0, n)[0]
        reach = np.hypot(*goals.T).max()
        assert 0.5 * disk_radius < reach < disk_radius  # the picture keeps its size with fewer robots
    for k in range(len(sequence.steps)):
        for n in (14, 9):
            goals = scene_goal_set(sequence, k, n)[0]
            assert np.abs(goals).max() <= k_r / 2  # inside the image square, centred on the origin
            d = np.hypot(*(goals[:, None] - goals[None]).transpose(2, 0, 1)) + np.eye(n)
            assert d.min() >= 2 * sequence.radius  # feasible (paper 4.4)
            lo, hi = np.array(sequence.arena[:2]), np.array(sequence.arena[2:])
            assert np.all(goals - sequence.radius >= lo) and np.all(goals + sequence.radius <= hi)


def test_goal_sets_only_for_existing_steps_and_counts(sequence):
    with pytest.raises(SceneError, match="step 6"):
        scene_goal_set(sequence, 6, 14)
    with pytest.raises(SceneError, match="1..14 robots"):
        scene_goal_set(sequence, 0, 15)
    with pytest.raises(SceneError, match="no image"):
        scene_goal_set(scene_from_dict({"robots": 3, "goals": {"kind": "antipodal"}}), 0, 3)


# --- the central engine plays the sequence ------------------------------------------------------
@pytest.fixture(scope="module")
def played(sequence, tmp_path_factory):
    out = run_central(sequence, tmp_path_factory.mktemp("seq") / "run", video=False, progress=None)
    return sequence, json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))


def test_every_image_of_fig_12_is_formed_before_its_hold_ends(played):
    scene, m, traj = played
    t, pose, goal, step = traj["t"], traj["pose"], traj["goal"], traj["step"]
    assert m["contacts"] == 0 and m["min_clearance_m"] > 0
    assert [s["index"] for s in m["steps"]] == list(range(6))
    for s, start in zip(m["steps"], scene.step_starts):
        assert s["t_start"] == pytest.approx(start)
        assert s["converged_at"] is not None and s["t_start"] + s["converged_at"] < s["t_end"]
        assert s["max_goal_error_at_end"] <= 0.01 and s["path_length_m"] > 0
        last = int(np.flatnonzero(step == s["index"])[-1])
        assert np.hypot(*(pose[last, :, :2] - goal[last]).T).max() <= 0.01  # checked on the trajectory too
    # the run may end on convergence, but only once the last image is up
    assert t[-1] > scene.step_starts[-1] and (m["end_reason"] == "duration" or step[-1] == 5)
    np.testing.assert_array_equal(step, [scene.step_at(x) for x in t])


def test_the_assignment_is_one_to_one_onto_the_shown_step(played):
    scene, _, traj = played
    for k, a, g in zip(traj["step"], traj["assignment"], traj["goal"]):
        assert sorted(a.tolist()) == list(range(scene.robots))
        # the goals as every robot decodes them from the goal set's message (float32 on the wire)
        np.testing.assert_array_equal(g, as_sent(scene_goal_set(scene, int(k), scene.robots)[0])[a])


def test_scenes_without_steps_record_step_zero(tmp_path):
    scene = scene_from_dict(
        {"robots": 2, "duration": 1.0, "layout": {"kind": "rows", "spacing": 0.2}, "goals": {"kind": "swap"}}
    )
    out = run_central(scene, tmp_path / "run", video=False, progress=None)
    traj = np.load(out / "trajectory.npz")
    assert traj["step"].tolist() == [0] * len(traj["t"])
    assert [s["index"] for s in json.loads((out / "metrics.json").read_text())["steps"]] == [0]


# --- per-step metrics from arrays ---------------------------------------------------------------
def test_step_metrics_from_arrays():
    t = np.arange(6) * 0.5
    x = np.array([[0.0, 0.3, 0.5, 0.5, 0.7, 1.0], [2.0, 2.0, 2.0, 2.0, 2.0, 2.0]]).T  # (T, N)
    pose = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=2)
    goal = np.zeros((6, 2, 2))
    goal[:3, :, 0] = [0.5, 2.0]
    goal[3:, :, 0] = [1.0, math.nan]  # robot 1 has no goal in step 1
    goal[3:, 1, 1] = math.nan
    rows = step_metrics(t, pose, goal, np.array([0, 0, 0, 1, 1, 1]), 0.01)
    assert rows[0] == pytest.approx(
        {
            "index": 0,
            "t_start": 0.0,
            "t_end": 1.0,
            "converged_at": 1.0,
            "max_goal_error_at_end": 0.0,
            "median_goal_error_at_end": 0.0,
            "path_length_m": 0.5,
        }
    )
    assert rows[1] == pytest.approx(
        {
            "index": 1,
            "t_start": 1.5,
            "t_end": 2.5,
            "converged_at": 1.0,
            "max_goal_error_at_end": 0.0,
            "median_goal_error_at_end": 0.0,
            "path_length_m": 0.5,
        }
    )
    never = step_metrics(t[:2], pose[:2], goal[:2], np.array([0, 0]), 0.01)
    assert never[0]["converged_at"] is None and never[0]["max_goal_error_at_end"] == pytest.approx(0.2)
    assert never[0]["median_goal_error_at_end"] == pytest.approx(0.1)  # robots 0.2 m and 0 m off
    plain = summarise(TrueRecord(t, pose, np.full(2, 0.045), goal), wall_s=1.0, contacts=0)
    assert "steps" not in plain  # runs without a step record keep their metrics as they were
