"""Goal generation end to end: goals inside the foreground, colours, resizing (paper 4.4), goal-set
families (5.1.2) and the goal-set file."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from coordinator import shapes
from coordinator.goals import GoalError, GoalOptions, GoalSet, generate_goals, prepare_image
from coordinator.goals.image import to_lab
from coordinator.goals.resize import from_arena
from tests.support import shape_truth
from tests.support.goal_sets import goal_set_from_json

SIZE = 160


def _pixels(gs: GoalSet, shape=(SIZE, SIZE)) -> np.ndarray:
    return from_arena(gs.goals, shape, gs.arena)


def _in_own_region(gs: GoalSet, labels: np.ndarray) -> np.ndarray:
    px = np.floor(_pixels(gs, labels.shape)).astype(int)
    ok = (px[:, 0] >= 0) & (px[:, 0] < labels.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < labels.shape[0])
    ok[ok] = labels[px[ok, 1], px[ok, 0]] == gs.regions[ok]
    return ok


@pytest.mark.parametrize("name", ["disk", "disk_and_line", "line", "L", "T", "ring", "two_squares"])
@pytest.mark.parametrize("method", ["cvt", "kmeans"])
def test_exactly_n_goals_each_inside_its_own_region(name, method):
    prep = prepare_image(shapes.draw(name, SIZE))
    truth = shape_truth.shape_mask(name, SIZE)
    for n, seed in ((14, 0), (60, 1)):
        gs = generate_goals(shapes.draw(name, SIZE), n, GoalOptions(method=method, seed=seed))
        assert len(gs) == n and gs.colors.shape == (n, 3) and gs.regions.shape == (n,)
        assert _in_own_region(gs, prep.seg.labels).all()
        px = np.floor(_pixels(gs)).astype(int)
        assert truth[px[:, 1], px[:, 0]].all()


def test_no_goal_in_the_hole_of_a_ring():
    half_pixel = 0.71 / SIZE  # the ring's radii are 0.36 and 0.2 of the side
    for n in (6, 14, 40):
        gs = generate_goals(shapes.draw("ring", SIZE), n, GoalOptions(seed=n))
        r = np.hypot(*(_pixels(gs) / SIZE - 0.5).T)
        assert np.all(r >= 0.2 - half_pixel) and np.all(r <= 0.36 + half_pixel)


def test_deterministic_for_a_seed():
    img = shapes.draw("disk_and_line", SIZE)
    a, b = generate_goals(img, 30, GoalOptions(seed=7)), generate_goals(img, 30, GoalOptions(seed=7))
    assert np.array_equal(a.goals, b.goals) and np.array_equal(a.colors, b.colors)
    assert a.cost_history == b.cost_history
    assert not np.array_equal(a.goals, generate_goals(img, 30, GoalOptions(seed=8)).goals)


@pytest.mark.parametrize("name,n", [("disk", 60), ("L", 60), ("T", 80), ("ring", 70), ("disk_and_line", 90)])
def test_spacing_is_uniform_within_each_region(name, n):
    gs = generate_goals(shapes.draw(name, 200), n, GoalOptions(seed=3))
    for rid in np.unique(gs.regions):
        pts = gs.goals[gs.regions == rid]
        if len(pts) < 50:
            continue
        d, _ = cKDTree(pts).query(pts, k=2)
        assert d[:, 1].min() / np.median(d[:, 1]) >= 0.6


def _delta_e(colors: np.ndarray, rgb) -> np.ndarray:
    return np.linalg.norm(to_lab(colors, precise=True) - to_lab(np.array([rgb], np.uint8), precise=True), axis=-1)


@pytest.mark.parametrize("antialias", [False, True])
def test_goal_colours_are_their_region_colours(antialias):
    img = shapes.draw("two_squares", SIZE, antialias=antialias)
    gs = generate_goals(img, 20, GoalOptions(seed=0))
    red, blue = shape_truth.part_masks("two_squares", SIZE)
    px = np.floor(_pixels(gs)).astype(int)
    on_red = red[px[:, 1], px[:, 0]]
    assert on_red.sum() == 10 and (~on_red).sum() == 10  # equal areas, separate goals
    assert len(np.unique(gs.regions[on_red])) == 1 and len(np.unique(gs.regions[~on_red])) == 1
    assert gs.regions[on_red][0] != gs.regions[~on_red][0]
    assert _delta_e(gs.colors[on_red], shapes.RED).max() < 2.0
    assert _delta_e(gs.colors[~on_red], shapes.BLUE).max() < 2.0


def test_goal_colour_is_the_mean_of_its_cell_in_lab():
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    img[40:120, 20:140] = (200, 60, 60)
    img[40:120, 20:140:2] = (180, 50, 50)  # fine stripes average to one colour
    gs = generate_goals(img, 6, GoalOptions(seed=0))
    mean = to_lab(img[40:120, 20:140].reshape(-1, 3), precise=True).mean(axis=0)
    assert np.linalg.norm(to_lab(gs.colors, precise=True) - mean, axis=1).max() < 1.5


def test_transparent_png_works(tmp_path):
    rgba = shapes.draw("T", SIZE, alpha=True)
    rgba[..., :3] = 0  # black everywhere: only alpha tells shape from background
    rgba[rgba[..., 3] > 0, :3] = shapes.BLUE
    cv2.imwrite(str(tmp_path / "t.png"), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    gs = generate_goals(tmp_path / "t.png", 25, GoalOptions(seed=0))
    px = np.floor(_pixels(gs)).astype(int)
    assert shape_truth.shape_mask("T", SIZE)[px[:, 1], px[:, 0]].all()
    assert gs.params["background"]["source"] == "alpha"


def test_photo_like_image_gives_goals_only_on_the_subject():
    img, subject = shape_truth.photo_like(SIZE, seed=1)
    gs = generate_goals(img, 60, GoalOptions(seed=0))
    px = np.floor(_pixels(gs)).astype(int)
    assert subject[px[:, 1], px[:, 0]].all()
    assert len(gs.params["regions"]) <= 3  # the body (one region despite its shading) and the leaf


def test_arena_scaling_and_feasibility():
    img = shapes.draw("disk", SIZE)
    gs = generate_goals(img, 30, GoalOptions(arena=2.0, seed=0))
    assert np.abs(gs.goals).max() <= 1.0 and gs.arena == 2.0
    assert gs.min_spacing() >= 2 * 0.045
    auto = generate_goals(img, 30, GoalOptions(seed=0))  # the conservative 2 K_r
    assert auto.min_spacing() >= 4 * 0.045 and auto.min_spacing() < 4 * 0.045 * 1.1
    assert np.allclose(auto.goals / auto.arena, gs.goals / gs.arena)


def test_too_small_an_arena_names_the_smallest_that_fits():
    img = shapes.draw("disk", SIZE)
    with pytest.raises(GoalError) as err:
        generate_goals(img, 200, GoalOptions(arena=1.0, seed=0))
    msg = str(err.value)
    assert "\n" not in msg and "at least" in msg and "robots" in msg
    smallest = float(msg.split("at least ")[1].split(" m")[0])
    gs = generate_goals(img, 200, GoalOptions(arena=smallest, seed=0))
    assert gs.min_spacing() >= 2 * 0.045
    fewer = int(msg.split("at most about ")[1].split(" ")[0])
    assert 0 < fewer < 200


def test_conservative_option_asks_for_twice_the_arena():
    img = shapes.draw("disk", SIZE)
    k_r = 2 * 0.045 / (generate_goals(img, 30, GoalOptions(arena=10.0, seed=0)).min_spacing() / 10.0)
    generate_goals(img, 30, GoalOptions(arena=1.5 * k_r, seed=0))
    with pytest.raises(GoalError, match="conservative"):
        generate_goals(img, 30, GoalOptions(arena=1.5 * k_r, seed=0, conservative=True))
    generate_goals(img, 30, GoalOptions(arena=2.01 * k_r, seed=0, conservative=True))


def test_artist_region_counts_and_fewer_robots_than_regions():
    img = shapes.draw("disk_and_line", SIZE)
    gs = generate_goals(img, 14, GoalOptions(region_counts={0: 6, 1: 8}, seed=0))
    assert np.bincount(gs.regions).tolist() == [6, 8]
    one = generate_goals(shapes.draw("two_squares", SIZE), 1, GoalOptions(seed=0))
    assert one.regions.tolist() == [0] and any("no robot" in note for note in one.params["notes"])


@pytest.mark.parametrize(
    "bad",
    [
        {"n": 0},
        {"n": -3},
        {"n": 2.5},
        {"seed": -1},
        {"arena": -1.0},
        {"method": "voronoi"},
        {"robot_radius": 0.0},
        {"n": 10_000_000},  # more goals than pixels even in the picture scaled up to MAX_UPSCALED_SIDE
    ],
)
def test_bad_arguments_are_goal_errors(bad):
    args = {"n": 10, **bad}
    n = args.pop("n")
    with pytest.raises(GoalError):
        generate_goals(shapes.draw("disk", 64), n, GoalOptions(**args))


def test_goal_set_json_round_trip():
    gs = generate_goals(shapes.draw("disk_and_line", SIZE), 14, GoalOptions(seed=2, arena=2.5))
    data = gs.to_dict()
    for key in ("goals", "colors", "regions", "cost_history", "params"):
        assert key in data
    for key in ("n", "arena", "method", "seed", "robot_radius"):
        assert key in data["params"]
    back = goal_set_from_json(gs.to_json(indent=1))
    assert np.allclose(back.goals, gs.goals, atol=1e-6)
    assert np.array_equal(back.colors, gs.colors) and np.array_equal(back.regions, gs.regions)
    assert back.cost_history == gs.cost_history and back.params == gs.params


def test_a_picture_with_few_pixels_a_goal_is_scaled_up_and_keeps_its_regions():
    """--robots 10000 on a small picture: under MIN_PIXELS_PER_GOAL pixels a goal the picture's pixels
    are made k x k, and the goals stay in their regions of the picture as given."""
    img = shapes.draw("two_squares", 64)
    prep = prepare_image(img)
    gs = generate_goals(img, 2 * max(r.area for r in prep.seg.regions))  # more goals than pixels
    assert len(gs) == 2 * max(r.area for r in prep.seg.regions) and gs.params["image_size"] == [64, 64]
    assert any("scaled up" in note for note in gs.params["notes"])
    assert _in_own_region(gs, prep.seg.labels).all()
    assert not any("scaled up" in note for note in generate_goals(img, 14).params["notes"])
