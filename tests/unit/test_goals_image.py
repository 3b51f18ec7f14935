"""Goal generation, input side: image files, alpha, background subtraction (paper 4.1)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from coordinator import shapes
from coordinator.goals import GoalError, GoalOptions, generate_goals
from coordinator.goals.image import foreground_mask, load_image, parse_color
from tests.support import shape_truth

SIZE = 96


def _write(path, rgb_or_rgba: np.ndarray) -> None:
    code = cv2.COLOR_RGBA2BGRA if rgb_or_rgba.shape[-1] == 4 else cv2.COLOR_RGB2BGR
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb_or_rgba, code))


@pytest.mark.parametrize("ext", ["png", "bmp", "tif", "jpg"])
def test_formats_load_as_rgb(tmp_path, ext):
    img = shapes.draw("disk_and_line", SIZE)
    _write(tmp_path / f"a.{ext}", img)
    rgb, alpha = load_image(tmp_path / f"a.{ext}")
    assert rgb.shape == img.shape and rgb.dtype == np.uint8 and alpha is None
    err = np.abs(rgb.astype(int) - img.astype(int))
    if ext == "jpg":
        assert np.median(err) <= 2  # lossy, but the channels are in RGB order
        assert np.abs(rgb[SIZE // 2, int(0.37 * SIZE)].astype(int) - shapes.RED).max() < 20
    else:
        assert err.max() == 0


def test_gray_and_16_bit_images_load(tmp_path):
    gray = (shape_truth.shape_mask("disk", SIZE) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), 255 - gray)
    rgb, _ = load_image(tmp_path / "g.png")
    assert rgb.shape == (SIZE, SIZE, 3) and (rgb[SIZE // 2, SIZE // 2] == 0).all()
    deep = (shapes.draw("disk", SIZE).astype(np.uint16) * 257)[:, :, ::-1]
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    rgb, _ = load_image(tmp_path / "d.png")
    assert tuple(rgb[SIZE // 2, SIZE // 2]) == shapes.RED


def test_transparent_pixels_are_background_whatever_their_colour(tmp_path):
    rgba = shapes.draw("L", SIZE, alpha=True)
    rgba[..., :3] = shapes.RED  # the RGB alone shows no shape at all
    _write(tmp_path / "t.png", rgba)
    rgb, alpha = load_image(tmp_path / "t.png")
    fg = foreground_mask(rgb, alpha)
    assert fg.source == "alpha"
    assert np.array_equal(fg.mask, shape_truth.shape_mask("L", SIZE))


def test_explicit_background_keeps_transparent_pixels_out():
    rgba = shapes.draw("disk", SIZE, alpha=True)
    rgba[rgba[..., 3] == 0, :3] = 0  # black under the transparent pixels
    rgba[40:56, 40:56, :3] = 255  # an opaque white patch inside the disk
    fg = foreground_mask(rgba[..., :3], rgba[..., 3], background="white")
    expected = shape_truth.shape_mask("disk", SIZE)
    expected[40:56, 40:56] = False
    assert np.array_equal(fg.mask, expected)


def test_opaque_alpha_falls_back_to_the_border_colour():
    rgba = np.dstack([shapes.draw("disk", SIZE), np.full((SIZE, SIZE), 255, np.uint8)])
    fg = foreground_mask(rgba[..., :3], rgba[..., 3])
    assert fg.source == "border"
    assert np.array_equal(fg.mask, shape_truth.shape_mask("disk", SIZE))


@pytest.mark.parametrize("bg", [(255, 255, 255), (0, 0, 0), (40, 160, 60)])
def test_dominant_border_colour_is_background(bg):
    img = shapes.draw("T", SIZE, background=bg)
    fg = foreground_mask(img)
    assert np.array_equal(fg.mask, shape_truth.shape_mask("T", SIZE))
    assert np.abs(np.array(fg.background) - bg).max() <= 2


def test_explicit_background_colour_wins_over_the_border():
    g = (np.arange(SIZE) + 0.5) / SIZE
    y, x = np.meshgrid(g, g, indexing="ij")
    big = (x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.62**2  # a disk that covers most of the border
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    img[big] = shapes.RED
    assert np.array_equal(foreground_mask(img).mask, ~big)  # the border's red looks like background
    assert np.array_equal(foreground_mask(img, background="white").mask, big)
    assert np.array_equal(foreground_mask(img, background="#ffffff").mask, big)


def test_uneven_noisy_background_leaves_only_the_subject():
    img, subject = shape_truth.photo_like(160, seed=3)
    mask = foreground_mask(img).mask
    near = cv2.dilate(subject.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert not (mask & ~near).any()  # nothing away from the subject
    assert (mask & subject).sum() >= 0.95 * subject.sum()


def test_parse_color():
    assert parse_color("#ff8000") == (255, 128, 0)
    assert parse_color("10, 20,30") == (10, 20, 30)
    assert parse_color("White") == (255, 255, 255)
    for bad in ("#ff80", "1,2", "300,0,0", "nope"):
        with pytest.raises(GoalError):
            parse_color(bad)


def test_unreadable_inputs_give_one_line_errors(tmp_path):
    (tmp_path / "text.png").write_text("not an image")
    good = tmp_path / "good.png"
    _write(good, shapes.draw("disk", SIZE))
    (tmp_path / "cut.png").write_bytes(good.read_bytes()[:60])
    cases = {
        tmp_path / "missing.png": "no such file",
        tmp_path: "directory",
        tmp_path / "text.png": "not a PNG",
        tmp_path / "cut.png": "damaged",
    }
    for path, words in cases.items():
        with pytest.raises(GoalError) as err:
            load_image(path)
        assert words in str(err.value) and "\n" not in str(err.value)


def test_image_without_foreground_is_an_error():
    with pytest.raises(GoalError, match="no foreground"):
        generate_goals(np.full((64, 64, 3), 200, np.uint8), 5)
    with pytest.raises(GoalError, match="transparent"):
        generate_goals(np.zeros((64, 64, 4), np.uint8), 5)


def test_aspect_ratio_is_kept_and_y_points_up():
    wide = np.full((80, 160, 3), 255, np.uint8)
    wide[8:24, 8:24] = shapes.BLUE  # a square in the top-left corner
    wide[60:76, 136:152] = shapes.RED  # and one in the bottom-right corner
    gs = generate_goals(wide, 8, GoalOptions(arena=2.0, robot_radius=0.01))
    blue = gs.regions == [r["id"] for r in gs.params["regions"] if r["color"] == list(shapes.BLUE)][0]
    # the longer side (160 px) spans the arena (2 m): 1 px = 1/80 m, the image centred on the origin,
    # so columns 8-24 are x in [-0.9, -0.7] and rows 8-24 are y in [0.2, 0.4]
    bx, by = gs.goals[blue].T
    rx, ry = gs.goals[~blue].T
    assert np.all((bx > -0.9) & (bx < -0.7) & (by > 0.2) & (by < 0.4))
    assert np.all((rx > 0.7) & (rx < 0.9) & (ry > -0.45) & (ry < -0.25))
