"""`--view web` in a browser: headless Chromium, driven by Playwright, opens the web viewer's address and
the screenshot shows the robots, upright (the arena's y up). Skipped where no Chromium or Playwright is
installed (Debian's `chromium`, `pip install playwright`); the browser reaches 127.0.0.1 only."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rerun")
pytest.importorskip("playwright.sync_api")

from bench.view_screenshot import chromium, screenshot  # noqa: E402
from sim.outputs.view import SwarmView  # noqa: E402

pytestmark = pytest.mark.skipif(chromium() is None, reason="no Chromium installed")

SIDE = 25  # robots along each bar of the L


def _red(image: np.ndarray) -> np.ndarray:
    """The red robots' pixels in the display (the left of the window, below the viewer's top bar)."""
    h, w = image.shape[:2]
    rgb = image.astype(int)
    red = (rgb[..., 0] > 180) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80)
    red[: int(0.06 * h)] = False
    red[:, int(0.7 * w) :] = False
    return red


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_web_view_shows_the_robots_upright_in_headless_chromium(tmp_path):
    """An L of red robots (a vertical bar on the left, a horizontal one at the bottom, y up) is drawn as an
    L, not upside down: most red pixels of the bottom fifth, few of the top fifth."""
    ys = np.linspace(-1.5, 1.5, SIDE)
    xy = np.concatenate(
        [np.column_stack([np.full(SIDE, -1.5), ys]), np.column_stack([ys[1:], np.full(SIDE - 1, -1.5)])]
    )
    n = len(xy)
    view = SwarmView("browser", (-2.0, -2.0, 2.0, 2.0), [], 0.07, robots=n, sink="web")
    try:
        pose = np.column_stack([xy, np.zeros(n)])
        red = np.tile(np.array([[230, 0, 0]], np.uint8), (n, 1))
        for k in range(10):
            view.tick(k, 0.1 * k, pose, red, np.full((n, 2), np.nan))
        view.flush()
        image = screenshot(view.url, lambda shot: _red(shot).sum() > 2000, tmp_path / "view.png")
    finally:
        view.close()
    rows = np.flatnonzero(_red(image).any(axis=1))
    top, bottom = rows.min(), rows.max()
    fifth = (bottom - top) // 5
    mask = _red(image)
    assert mask[bottom - fifth : bottom + 1].sum() > 3 * mask[top : top + fifth + 1].sum()  # the bar at the bottom
    cols = np.flatnonzero(mask.any(axis=0))
    left_bar = mask[:, cols.min() : cols.min() + (cols.max() - cols.min()) // 5].sum()
    right_part = mask[:, cols.max() - (cols.max() - cols.min()) // 5 : cols.max() + 1].sum()
    assert left_bar > 3 * right_part  # the bar on the left
