"""A scene's values are checked when it loads (docs/scenes.md): every number finite and in range, every key
one its table takes. A bad one is one line naming the table, the key and the value, exit code 2 with nothing
written; before, nan, inf, true, 2.5 neighbours or a typo passed and the run broke (or ignored them) mid-way."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.core.params import RobotParams
from coordinator.scene import SceneError, scene_from_dict
from sim.cli import main as cli

NAN, INF = math.nan, math.inf
GRID = {"kind": "grid", "spacing": 0.2}
FAIL = {"kind": "fail", "t": 1.0, "robot": 0}
SQUARE = [[1.0, 1.0], [1.5, 1.0], [1.5, 1.5], [1.0, 1.5]]


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("v_max", INF, "v_max must be a positive number, not inf"),
        ("v_max", NAN, "v_max must be a positive number, not nan"),
        ("v_max", True, "v_max must be a positive number, not True"),
        ("tau", -1.0, "tau must be a positive number, not -1.0"),
        ("max_neighbours", 2.5, "max_neighbours must be a positive whole number, not 2.5"),
        ("max_neighbours", True, "max_neighbours must be a positive whole number, not True"),
        ("deadlock_iterations", 0.5, "deadlock_iterations must be a positive whole number, not 0.5"),
        ("rounds_per_tick", -1, "rounds_per_tick must be a whole number >= 0, not -1"),
        ("deadlock_cost", INF, "deadlock_cost must be a number >= 0, not inf"),
    ],
)
def test_a_robot_parameter_must_be_a_finite_number_whole_where_it_counts(key, value, message):
    with pytest.raises(ValueError) as err:
        RobotParams.from_dict({key: value})
    assert str(err.value) == f"robot parameter {message}"


@pytest.mark.parametrize(
    "key, value", [("max_neighbours", np.int64(4)), ("v_max", 1), ("rounds_per_tick", 0), ("deadlock_cost", 0)]
)
def test_whole_numbers_and_zero_where_it_turns_a_feature_off_are_taken(key, value):
    assert getattr(RobotParams.from_dict({key: value}), key) == value


@pytest.mark.parametrize(
    "data, message",
    [
        ({"robots": 2**16 + 1}, "robots must be at most 65536 (robot ids are 16-bit on the bus), not 65537"),
        # non-finite or malformed geometry
        ({"layout": {**GRID, "heading": NAN}}, "layout heading must be a finite number of radians, not nan"),
        ({"layout": {**GRID, "heading": "up"}}, "layout heading must be a finite number of radians, not 'up'"),
        ({"layout": {"kind": "rows", "gap": INF}}, "layout gap must be a positive number of metres, not inf"),
        ({"layout": {"kind": "random", "size": [NAN, 1.0]}}, "layout size must be [width, height] (finite numbers)"),
        ({"layout": {"kind": "random", "size": [1.0]}}, "layout size must be [width, height] (finite numbers)"),
        ({"layout": {"kind": "random", "size": [-1.0, 1.0]}}, "layout size must be [width, height] in metres, above 0"),
        (
            {"layout": {"kind": "list", "poses": [[0, 0, 0], [0.5, NAN, 0], [1, 0, 0], [1.5, 0, 0]]}},
            "layout poses[1] must be [x, y, theta] (finite numbers), not [0.5, nan, 0]",
        ),
        ({"layout": {"kind": "list", "poses": [[0, 0, "a"]] * 4}}, "layout poses[0] must be [x, y, theta]"),
        ({"layout": {"kind": "list", "poses": [[0, 0, 0]]}}, "layout poses needs 4 [x, y, theta] rows, not 1"),
        ({"layout": {"kind": "file", "path": 3}}, 'layout of kind "file" needs path'),
        (
            {"goals": {"kind": "list", "positions": [[0, 0], [1, INF], [2, 2], [3, 3]]}},
            "goals positions[1] must be [x, y] (finite numbers), not [1, inf]",
        ),
        ({"noise": {"tracking_xy": NAN}}, "[noise] tracking_xy must be a number >= 0, not nan"),
        ({"noise": {"actuation": True}}, "[noise] actuation must be a number >= 0, not True"),
        (
            {"obstacles": [{"vertices": [[1, 1], [2, NAN], [2, 2]]}]},
            "obstacles[0] vertices[1] must be [x, y] (finite numbers), not [2, nan]",
        ),
        (
            {"obstacles": [{"vertices": [[1, 1], [2, 2], [3, 3]]}]},
            "obstacles[0] vertices must outline a simple polygon (it has no area)",
        ),
        ({"obstacles": [{"vertices": [[1, 1], [1, 1], [2, 2]]}]}, "simple polygon (a vertex repeats)"),
        ({"obstacles": [{"vertices": [[1, 1], [2, 2], [2, 1], [1, 2.5]]}]}, "simple polygon (self-intersection)"),
        ({"obstacles": [{"vertices": [[1, 1], [2, 2]]}]}, "obstacles[0] vertices needs 3 [x, y] rows, not 2"),
        ({"obstacles": "square"}, "obstacles must be [[obstacles]] tables"),
        (
            {"events": [{"kind": "teleport", "t": 1.0, "robot": 0, "pose": [NAN, 0.0, 0.0]}]},
            "events[0] (teleport) pose must be [x, y, theta] (finite numbers), not [nan, 0.0, 0.0]",
        ),
        (
            {"events": [{"kind": "tracker-glitch", "t": 1.0, "robot": 0, "offset": [True, 0.0]}]},
            "events[0] (tracker-glitch) offset must be [dx, dy] (finite numbers), not [True, 0.0]",
        ),
        ({"events": [{**FAIL, "t": INF}]}, "events[0] (fail) t must be a positive number of seconds, not inf"),
        ({"events": [{**FAIL, "robot": True}]}, "events[0] (fail): robot must be a robot index in 0..3, not True"),
        (
            {"events": [{"kind": "tracker-outage", "t": 1.0, "duration": NAN}]},
            "events[0] (tracker-outage) duration must be a positive number of seconds, not nan",
        ),
        (
            {"scripted": [{"robot": 3, "waypoints": [[0.0, 0.0, 0.0], [NAN, 1.0, 1.0]]}]},
            "scripted[0] waypoints[1] must be [t, x, y] (finite numbers), not [nan, 1.0, 1.0]",
        ),
        (
            {"scripted": [{"robot": 3, "waypoints": [[1.0, 0.0, 0.0], [1.0, 1.0, 1.0]]}]},
            "scripted[0] waypoints must be [[t, x, y], ...] with increasing t, not [1.0, 1.0]",
        ),
        ({"pursuers": [{"robot": 2, "target": True}]}, "pursuers[0]: target must be a robot index in 0..3, not True"),
        (
            {"goals": {"kind": "image", "shape": "disk", "arena": NAN}},
            "goals arena must be a positive number of metres",
        ),
        # [layout] cols: a whole number >= 1 (0 was a ZeroDivisionError)
        ({"layout": {**GRID, "cols": 0}}, "layout cols must be a whole number >= 1, not 0"),
        ({"layout": {**GRID, "cols": -2}}, "layout cols must be a whole number >= 1, not -2"),
        ({"layout": {**GRID, "cols": 1.5}}, "layout cols must be a whole number >= 1, not 1.5"),
        # a key the table (or its kind) does not take: a typo
        (
            {"layout": {**GRID, "spacng": 0.3}},
            'layout of kind "grid": unknown key(s) spacng (allowed: kind, spacing, cols',
        ),
        ({"layout": {"kind": "circle", "cols": 2}}, 'layout of kind "circle": unknown key(s) cols'),
        # beyond 4096 m, 32-bit floats on the bus place a robot no closer than half a millimetre (a run of
        # robots 10^30 m out hung; 10^200 m out was SciPy's overflow message)
        (
            {"layout": {"kind": "list", "poses": [[1e30, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0, 0]]}},
            "the arena reaches 1e+30 m from the origin, beyond 4096 m, where the bus's 32-bit floats no longer place "
            "a robot to the millimetre; place the robots, goals and obstacles nearer (0, 0)",
        ),
        ({"arena": {"size": [8200.0, 2.0]}}, "the arena reaches 4100 m from the origin, beyond 4096 m"),
        # beyond the arena a teleported or scripted robot drove into the wall (a contact), and a lock-step
        # world waited every tick for the command of a robot whose pose its agent did not believe
        (
            {"events": [{"kind": "teleport", "t": 1.0, "robot": 1, "pose": [3.0, 0.0, 0.0]}]},
            "events[0] (teleport) pose (3, 0) puts the robot outside the 0.76 x 0.76 m arena [-0.38, -0.38] to "
            "[0.38, 0.38]; move it inside or enlarge [arena] size",
        ),
        (
            {"scripted": [{"robot": 3, "waypoints": [[0.0, 0.0, 0.0], [5.0, 0.0, -2.0]]}]},
            "scripted robot 3's waypoint (0, -2) puts the robot outside",
        ),
        (
            {"goals": {"kind": "list", "positions": [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [0.0, -5000.0]]}},
            "the arena reaches 5000.28 m from the origin",
        ),
        ({"goals": {"kind": "antipodal", "postions": []}}, 'goals of kind "antipodal": unknown key(s) postions'),
        ({"arena": {"size": [3.0, 3.0], "sise": 1}}, "arena: unknown key(s) sise (allowed: size)"),
        ({"end": {"converge_hol": 2.0}}, "[end]: unknown key(s) converge_hol (allowed: converge_hold)"),
        ({"noise": {"trackingxy": 0.1}}, "[noise]: unknown key(s) trackingxy (allowed: tracking_xy"),
        ({"events": [{**FAIL, "tt": 2.0}]}, 'events[0] of kind "fail": unknown key(s) tt (allowed: kind, t, robot)'),
        ({"events": [{**FAIL, "kind": "explode"}]}, "events[0] kind must be one of teleport, fail"),
        ({"obstacles": [{"vertices": SQUARE, "height": 1}]}, "obstacles[0]: unknown key(s) height (allowed: vertices)"),
        (
            {"scripted": [{"robot": 3, "waypoints": [[0, 0, 0], [1, 1, 1]], "speed": 1}]},
            "scripted[0]: unknown key(s) speed (allowed: robot, waypoints)",
        ),
        (
            {"pursuers": [{"robot": 2, "target": 3, "speed": 1}]},
            "pursuers[0]: unknown key(s) speed (allowed: robot, target)",
        ),
    ],
)
def test_a_bad_scene_value_or_key_is_one_line_naming_it(data, message):
    with pytest.raises(SceneError) as err:
        scene_from_dict({"robots": 4, "layout": GRID, **data}, "s.toml")
    assert str(err.value).startswith("s.toml: ") and message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_an_arena_within_4096_m_of_the_origin_loads():
    """The largest arena whose every position the bus's 32-bit floats hold to a quarter millimetre."""
    poses = [[4090.0, 0.0, 0.0], [4090.0, 1.0, 0.0], [-4090.0, 0.0, 0.0], [0.0, -4090.0, 0.0]]
    assert scene_from_dict({"robots": 4, "layout": {"kind": "list", "poses": poses}}, "s.toml").robots == 4
    assert scene_from_dict({"robots": 4, "layout": GRID, "arena": {"size": [8192.0, 8192.0]}}, "s.toml").robots == 4


def test_the_keys_a_scene_takes_still_load():
    """One of every kind of table, with every key it takes."""
    scene = scene_from_dict(
        {
            "robots": 4,
            "layout": {"kind": "grid", "spacing": 0.2, "cols": 2, "heading": -1.0},
            "goals": {"kind": "list", "positions": [[0, 0.5], [0.5, 0.5], [0, -0.5], [0.5, -0.5]]},
            "arena": {"size": [4.0, 4.0]},
            "obstacles": [{"vertices": SQUARE[::-1]}],
            "events": [
                {"kind": "teleport", "t": 1.0, "robot": 0, "pose": [0.0, 1.0, 0.0]},
                FAIL,
                {"kind": "tracker-outage", "t": 2.0, "duration": 0.5},
                {"kind": "tracker-glitch", "t": 3.0, "robot": 1, "offset": [0.1, 0.0]},
            ],
            "scripted": [{"robot": 3, "waypoints": [[0.0, 0.1, -0.1], [2.0, 1.0, -1.0]]}],
            "pursuers": [{"robot": 2, "target": 3}],
            "noise": {"tracking_xy": 0.0, "tracking_theta_deg": 1, "actuation": 0.01},
            "end": {"converge_hold": 0},
        },
        "s.toml",
    )
    assert scene.poses[:, 2].tolist() == [-1.0] * 4 and scene.obstacles[0] == [tuple(v) for v in SQUARE]


@pytest.mark.parametrize(
    "toml, message",
    [
        ("[robot]\nv_max = inf\n", "robot parameter v_max must be a positive number, not inf"),
        ("[robot]\nmax_neighbours = 2.5\n", "robot parameter max_neighbours must be a positive whole number, not 2.5"),
        ('[layout]\nkind = "grid"\nheading = nan\n', "layout heading must be a finite number of radians, not nan"),
        ("[layout]\ncols = 0\n", "layout cols must be a whole number >= 1, not 0"),
        ('[layout]\nkind = "grid"\nspacng = 0.3\n', 'layout of kind "grid": unknown key(s) spacng'),
        ("[[obstacles]]\nvertices = [[1, 1], [2, 2], [3, 3]]\n", "obstacles[0] vertices must outline a simple polygon"),
        ('[layout]\nkind = "list"\nposes = [[0, 0, 0], [1, 0, 0], [1e30, 0, 0]]\n', "reaches 1e+30 m from the origin"),
        # 1e300 ticks: the run never ended
        (
            "[robot]\ndt = 1e-300\n",
            "1 s at a control period dt of 1e-300 s is 1e+300 ticks, more than the bus can number",
        ),
    ],
)
def test_pixelswarm_run_refuses_a_bad_scene_value_in_one_line_and_writes_nothing(tmp_path, capsys, toml, message):
    """Exit 2 before any process starts (these ran, then failed with exit 3 and a partial run directory)."""
    scene, out = tmp_path / "bad.toml", tmp_path / "run"
    scene.write_text('robots = 3\n[goals]\nkind = "antipodal"\n' + toml)
    assert cli.main(["run", str(scene), "--duration", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists() and not out.with_name("run.partial").exists()


def test_pixelswarm_run_of_an_image_of_specks_alone_says_it_has_no_foreground(tmp_path, capsys):
    import cv2

    image, out = tmp_path / "specks.png", tmp_path / "run"
    pixels = np.full((64, 64, 3), 255, np.uint8)
    pixels[10:12, 10:12] = 0
    cv2.imwrite(str(image), pixels)
    assert cli.main(["run", str(image), "--duration", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no foreground in" in err and "specks smaller than 16 pixels" in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_a_layout_file_is_read_beside_its_scene_from_any_directory(tmp_path, monkeypatch):
    """As a scene's images are: a run started elsewhere found no file (it was read from the working directory)."""
    from coordinator.scene import parse_scene

    folder = tmp_path / "show"
    folder.mkdir()
    (folder / "start.csv").write_text("0,0,0\n0.5,0,1.5\n1,0,3\n")
    scene = folder / "scene.toml"
    scene.write_text('robots = 3\n[layout]\nkind = "file"\npath = "start.csv"\n[goals]\nkind = "stay"\n')
    monkeypatch.chdir(tmp_path)
    poses = parse_scene(str(scene)).poses
    np.testing.assert_allclose(poses, [[0, 0, 0], [0.5, 0, 1.5], [1, 0, 3]])
