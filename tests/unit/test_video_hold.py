"""display.mp4 holds the final picture for at least 3 s of video (sim.outputs.render.held_frames), whatever
ended the run: a picture's run ends about 1 s after it forms (converge_hold), too short to see."""

from __future__ import annotations

import json
import math

import av
import numpy as np
import pytest

from coordinator.scene import load_scene
from sim.outputs.render import HOLD_S, _View, frame_indices, held_frames
from tests.conftest import run_pixelswarm

FPS = 10


def test_the_frames_from_the_formed_picture_on_last_three_seconds():
    t = np.round(np.arange(0, 9.45, 0.1), 6)  # 9.4 s recorded, 95 samples
    plain = frame_indices(t, FPS)
    idx = held_frames(t, formed_at=8.4, fps=FPS)
    assert list(idx[: len(plain)]) == list(plain)  # real time up to the end, then the last frame again
    assert np.count_nonzero(t[idx] >= 8.4) == HOLD_S * FPS == 30
    assert set(idx[len(plain) :].tolist()) == {len(t) - 1}


def test_a_run_that_did_not_form_its_picture_ends_on_its_last_frame_for_three_seconds():
    t = np.arange(50) * 0.1
    idx = held_frames(t, formed_at=None, fps=FPS)
    assert len(idx) == 50 + 29 and np.count_nonzero(idx == 49) == 30


def test_a_picture_held_longer_than_that_gets_no_extra_frames():
    t = np.arange(100) * 0.1
    assert list(held_frames(t, formed_at=2.0, fps=FPS)) == list(frame_indices(t, FPS))


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_video_of_a_run_that_ends_on_convergence_holds_the_picture_three_seconds(tmp_path):
    """A real run, ended by convergence (converge_hold 1 s): from the first frame at or after the
    time it converged, at least 3 s of frames, all showing the formed picture."""
    out = tmp_path / "run"
    result = run_pixelswarm("run", "circle", "--engine", "central", "--robots", "6", "--no-plots", "--out", str(out))
    assert result.returncode == 0, result.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["end_reason"] == "converged" and metrics["duration_s"] - metrics["time_to_converge_s"] < 2
    with av.open(str(out / "display.mp4")) as container:
        stream = container.streams.video[0]
        assert stream.average_rate == FPS
        # int16 holds a pixel's difference from another: every frame of the run in memory at once, not 4x that
        frames = [f.to_ndarray(format="bgr24").astype(np.int16) for f in container.decode(stream)]
    # the writing said, as the distributed engine's: the run's end, then the video's frames as they came
    said = result.stderr.splitlines()
    assert "[circle] run ended (converged); writing run" in said
    assert f"[circle] display.mp4: {len(frames)} of {len(frames)} frames" in said
    formed = math.ceil(metrics["time_to_converge_s"] * FPS - 1e-6)  # frame k shows t = k / FPS
    after = frames[formed:]
    assert len(after) >= HOLD_S * FPS
    scene = load_scene("circle", robots=6)
    below = _View(scene.arena, 720).height // 20  # under the time label, which differs frame to frame
    moved = [int((np.abs(f[below:] - frames[-1][below:]).max(axis=-1) > 60).sum()) for f in frames]
    # pixels a robot covers in one frame and not in the last: the robots within tolerance of their
    # goals (goal_tolerance, 1 cm) still creep in, but far less than on their way
    assert max(moved[formed:]) < max(moved) / 4
