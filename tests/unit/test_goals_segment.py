"""Goal generation: segmentation into regions R_i and robots per region N_i (paper 4.1, 4.2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator import shapes
from coordinator.goals import GoalError, prepare_image
from coordinator.goals.allocate import allocate_robots
from tests.support import shape_truth

SIZE = 128


def _regions(img, **kw):
    return prepare_image(img, **kw).seg


def test_touching_regions_of_different_colour_stay_apart():
    seg = _regions(shapes.draw("two_squares", SIZE))
    assert [r.color for r in seg.regions] == [shapes.RED, shapes.BLUE]
    red, blue = shape_truth.part_masks("two_squares", SIZE)
    assert np.array_equal(seg.labels == 0, red) and np.array_equal(seg.labels == 1, blue)


def test_same_colour_splits_by_connectivity_and_joins_when_touching():
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    img[10:40, 10:40] = shapes.RED
    img[80:110, 80:120] = shapes.RED
    seg = _regions(img)
    assert [r.area for r in seg.regions] == [1200, 900]  # two regions, largest first
    img[40:80, 30:90] = shapes.RED  # a bridge joins them
    assert len(_regions(img).regions) == 1


def test_antialiased_edges_do_not_become_regions():
    seg = _regions(shapes.draw("disk_and_line", SIZE, antialias=True))
    assert len(seg.regions) == 2
    assert any("merged" in note for note in seg.notes)
    disk, line = shape_truth.part_masks("disk_and_line", SIZE)
    assert (seg.labels[disk] == 0).mean() > 0.99 and (seg.labels[line] == 1).mean() > 0.99


def test_specks_are_dropped_with_a_note():
    img = shapes.draw("disk", SIZE)
    img[5:7, 5:7] = shapes.BLUE  # 4 pixels, far from the disk
    seg = _regions(img)
    assert len(seg.regions) == 1 and seg.labels[5, 5] == -1
    assert any("speck" in note for note in seg.notes)
    seg = _regions(img, min_area=2)  # a smaller speck size keeps it
    assert len(seg.regions) == 2


@pytest.mark.parametrize("min_area", [None, 50])
def test_an_image_of_specks_alone_has_no_foreground(min_area):
    """Every foreground part under the speck size: the one-line error of an empty image, naming the size
    (it was an OpenCV assertion traceback)."""
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    img[5:7, 5:7], img[60:64, 60:64] = shapes.BLUE, shapes.RED  # 4 and 16 pixels: specks under 50
    if min_area is None:
        img[60:64, 60:64] = 255  # the default size (16 pixels at 128 px) leaves the 4-pixel one alone
    with pytest.raises(GoalError) as err:
        prepare_image(img, min_area=min_area)
    assert (
        str(err.value)
        == f"no foreground in <array>: its only foreground is specks smaller than {min_area or 16} pixels"
    )


def test_shading_is_one_region_but_an_edge_between_colours_is_two():
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    ramp = np.linspace(1.0, 0.45, 80)[None, :, None]
    img[20:100, 20:100] = np.round(np.array([235.0, 120.0, 30.0]) * ramp)  # orange, lit from the left
    assert len(_regions(img).regions) == 1
    img[20:100, 60:100] = (240, 200, 40)  # a yellow half with a hard edge
    assert len(_regions(img).regions) == 2


def test_allocation_is_proportional_to_area_with_an_exact_total():
    counts, notes = allocate_robots([300, 100, 600], 10)
    assert counts.tolist() == [3, 1, 6] and notes == []
    counts, _ = allocate_robots([1, 1, 1], 10)  # 3.33 each: the remainder goes to the lowest id
    assert counts.tolist() == [4, 3, 3]


def test_a_region_whose_share_rounds_to_zero_still_gets_a_robot():
    counts, _ = allocate_robots([1000, 10], 20)  # quota 0.2 for the small region
    assert counts.tolist() == [19, 1]


def test_fewer_robots_than_regions_shows_the_largest():
    counts, notes = allocate_robots([50, 400, 100, 300], 2)
    assert counts.tolist() == [0, 1, 0, 1]
    assert "region(s) 0, 2 get no robot" in notes[0]


def test_artist_override():
    counts, _ = allocate_robots([4000, 1000], 14, {0: 6, 1: 8})
    assert counts.tolist() == [6, 8]
    counts, _ = allocate_robots([100, 100, 200], 10, {2: 2})  # the rest shared by area
    assert counts.tolist() == [4, 4, 2]
    for bad in ({0: 15}, {0: 3, 1: 4}, {5: 1}, {0: -1}):
        with pytest.raises(GoalError):
            allocate_robots([4000, 1000], 14, bad)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(1, 10_000), min_size=1, max_size=12), st.integers(1, 500))
def test_allocation_properties(areas, n):
    counts, _ = allocate_robots(areas, n)
    assert counts.sum() == n and (counts >= 0).all()
    a = np.asarray(areas, float)
    if n >= len(areas):
        assert (counts >= 1).all()
        quota = n * a / a.sum()
        if (quota >= 1).all():  # no region needed lifting: plain largest remainder
            assert np.all(np.abs(counts - quota) < 1)
    else:
        assert set(np.nonzero(counts)[0]) == set(np.lexsort((np.arange(len(a)), -a))[:n])
