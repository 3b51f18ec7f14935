"""The History of the Universe (paper 7.5.2, Fig. 21), in its spirit: the shipped scene `history`, 50
Elisa-like robots on the paper's 2 m table show the big bang, the Earth orbiting the Sun with the Moon
orbiting the Earth, a zoom onto the Earth, a microbe and a fish in the sea, a dinosaur stretching its
neck and a human. Checked: every keyframe's goals fit the table with room between the robots, and the
central engine plays the first keyframes in time without contact (the whole show: README)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from agent.core.params import RobotParams
from coordinator import drawings
from coordinator.scene import load_scene, scene_goal_set
from sim.central.engine import run_central

# --dist loadgroup gives the module one xdist worker: its module fixture (the history scene's goal sets) is made
# once, not once on each worker
pytestmark = pytest.mark.xdist_group("history")

TABLE_RADIUS = 1.0  # m: the paper's circular table, 2 m across
MIN_SPACING = 0.06  # m between goals: a centimetre between two robots 5 cm across standing on them
EQ27_LAG = 0.04  # m: what eq. 27's held velocity leaves at the end of K_f dt (see below)


@pytest.fixture(scope="module")
def history():
    return load_scene("history")  # the goal sets of all 23 keyframes, seeded by the scene (seed 1)


def test_fifty_elisas_tell_the_story_in_three_to_five_minutes(history):
    params = RobotParams.from_dict(history.robot)
    assert history.robots == 50 and params.kinematics == "diffdrive"
    assert params.radius == 0.025 and params.v_max == 0.25  # the Elisa, limited as in the paper (7.5.1)
    assert len(history.steps) == 23 and 180.0 <= history.duration <= 300.0
    colours = [{tuple(int(v) for v in c) for c in scene_goal_set(history, k, 50)[1]} for k in range(23)]
    assert colours[0] == {drawings.BANG_FIRE, drawings.BANG_CORE}
    assert all(c == {drawings.SUN, drawings.EARTH, drawings.MOON} for c in colours[3:12])  # the orbit
    assert colours[13] == {drawings.EARTH, drawings.LAND}
    assert colours[16] == {drawings.SEA, drawings.MICROBE, drawings.FISH}
    assert colours[19] == {drawings.DINOSAUR} and colours[22] == {drawings.PERSON}


def test_every_keyframe_puts_fifty_goals_on_the_table_apart(history):
    xmin, ymin, xmax, ymax = history.arena
    r = history.radius
    for k in range(len(history.steps)):
        goals, colors = scene_goal_set(history, k, 50)
        assert goals.shape == (50, 2) and colors.shape == (50, 3) and np.isfinite(goals).all()
        assert np.all(np.hypot(*goals.T) + r <= TABLE_RADIUS), k  # on the table, so in the arena too
        assert np.all((goals - r > (xmin, ymin)) & (goals + r < (xmax, ymax))), k
        d, _ = cKDTree(goals).query(goals, k=2)
        assert d[:, 1].min() >= MIN_SPACING, (k, d[:, 1].min())
    # the Earth goes once round the Sun, in eighths (keyframes 3 to 11): the Earth's goals turn with it
    earth = [scene_goal_set(history, k, 50) for k in (3, 5, 7, 9, 11)]
    centres = [g[np.all(c == drawings.EARTH, axis=1)].mean(axis=0) for g, c in earth]
    angles = np.degrees(np.unwrap([np.arctan2(y, x) for x, y in centres]))
    np.testing.assert_allclose(np.diff(angles), 90.0, atol=5.0)


def test_the_central_engine_forms_the_big_bang_in_time_without_contact(history, tmp_path):
    """The first three keyframes (45 s of display): the fireball, formed from the table's rim in 25 s;
    the burst, 12 s; the burst held, 8 s. Eq. 27 brings the robots to a keyframe's goals as the next
    begins, within EQ27_LAG: the held velocity does not make up the time a differential-drive robot
    spends turning on the spot at the start, nor what ORCA's yielding costs on the way (paper 6.2;
    measured: at most 2.3 to 2.9 cm, under 1 cm on average). A held keyframe is formed within the goal
    tolerance, 1 cm, before it ends (measured: 4.9 to 5.2 s into its 8 s)."""
    scene = dataclasses.replace(history, duration=45.0)
    out = run_central(scene, tmp_path / "run", video=False, progress=None)
    m, traj = json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))
    assert m["contacts"] == 0, m["contact_events"][:5]
    t, pose, goal, step = traj["t"], traj["pose"][:, :, :2], traj["goal"], traj["step"]
    assert set(step[t < scene.duration - 1e-9].tolist()) == {0, 1, 2}  # the last tick begins keyframe 3
    lags = []
    for f in (0, 1):
        last = np.flatnonzero(step == f)[-1]  # the last tick before keyframe f + 1 begins
        error = np.hypot(*(pose[last] - goal[last]).T)
        lags.append(error.max())
        assert error.max() <= EQ27_LAG and error.mean() <= 0.015, (f, error.max(), error.mean())
    held = np.flatnonzero(step == 2)
    error = np.hypot(*(pose[held] - goal[held]).transpose(2, 0, 1))
    formed = np.flatnonzero((error <= RobotParams.from_dict(history.robot).goal_tolerance).all(axis=1))
    assert len(formed), f"the burst was not formed within 1 cm (at best {error.max(axis=1).min():.3f} m)"
    print(
        f"\nhistory: fireball and burst reached within {lags[0] * 100:.1f} and {lags[1] * 100:.1f} cm; the held "
        f"burst formed within 1 cm at t = {t[held[formed[0]]]:.1f} s; min clearance {m['min_clearance_m']:.4f} m"
    )
