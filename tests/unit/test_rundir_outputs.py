"""Run-directory writers: MCAP log, metrics, video and plots, atomic RunDir."""

from __future__ import annotations

import datetime as dt
import json
import math
import re
import threading

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from sim.outputs import metrics, render
from sim.outputs.foxglove import QUANTUM, SceneUpdate, scene_update
from sim.outputs.mcaplog import McapLog, mcap_channels, read_mcap
from sim.outputs.render import (
    STAMP_ABOVE,
    Recording,
    _draw,
    _drawn_ahead,
    _painter,
    _View,
    frame_indices,
    write_plots,
    write_video,
)
from sim.outputs.rundir import RunDir, default_run_path, dumps_json, json_safe, write_json
from tests.conftest import METRIC_KEYS, run_pixelswarm
from tests.support.outputs import contact_events, log_json, render_frame, write_npz

POSE_SCHEMA = {
    "type": "object",
    "properties": {
        "id": {"type": "integer"},
        "pose": {"type": "array", "items": {"type": ["number", "null"]}},
        "stamp": {"type": "number"},
    },
    "required": ["id", "pose"],
}
STATUS_SCHEMA = {"type": "object", "properties": {"ok": {"type": "boolean"}, "note": {"type": "string"}}}


# ------------------------------------------------------------------------------------------------
# MCAP
# ------------------------------------------------------------------------------------------------


def test_mcap_round_trip(tmp_path):
    path = tmp_path / "log.mcap"
    with McapLog(path) as log:
        pose_ch = log.add_channel("swarm/robot/0/pose", "pixelswarm.Pose", POSE_SCHEMA)
        assert log.add_channel("swarm/robot/0/pose", "pixelswarm.Pose", POSE_SCHEMA) == pose_ch
        with pytest.raises(ValueError):
            log.add_channel("swarm/robot/0/pose", "pixelswarm.Pose", STATUS_SCHEMA)
        pose1_ch = log.add_channel("swarm/robot/1/pose", "pixelswarm.Pose", POSE_SCHEMA)
        status_ch = log.add_channel("swarm/status", "pixelswarm.Status", STATUS_SCHEMA)
        log.add_channel("swarm/empty", "pixelswarm.Status", STATUS_SCHEMA)
        assert len({pose_ch, pose1_ch, status_ch}) == 3
        # written out of log-time order on purpose
        log_json(
            log,
            pose_ch,
            2_000_000_000,
            {"id": np.int64(0), "pose": np.array([1.0, np.nan, 0.5]), "stamp": np.float32(2.0)},
        )
        log_json(log, pose_ch, 1_000_000_000, {"id": 0, "pose": [0.0, 0.0, np.inf], "stamp": 1.0})
        log_json(log, pose1_ch, 1_500_000_000, {"id": 1, "pose": np.arange(3, dtype=np.float32)})
        log.write_bytes(status_ch, 1_200_000_000, b'{"ok":true,"note":"raw"}')
        log_json(log, status_ch, 1_300_000_000, {"ok": np.bool_(False), "note": "x", "extra": {1: (np.nan,)}})
        log.add_metadata("run", {"scene": "circle", "seed": 7})
        assert log.message_count == 5
    assert log.closed
    log.close()  # idempotent
    with pytest.raises(ValueError):
        log_json(log, pose_ch, 3, {"id": 0, "pose": []})

    msgs = read_mcap(path)
    # Foxglove's writer puts a channel in the file with its first message: one never used is not there
    assert set(msgs) == {"swarm/robot/0/pose", "swarm/robot/1/pose", "swarm/status"}
    p0 = msgs["swarm/robot/0/pose"]
    assert [m["stamp"] for m in p0] == [1.0, 2.0]  # log-time order
    assert p0[0]["pose"] == [0.0, 0.0, None]  # inf -> null
    assert p0[1] == {"id": 0, "pose": [1.0, None, 0.5], "stamp": 2.0}  # NaN -> null
    assert msgs["swarm/robot/1/pose"][0]["pose"] == [0.0, 1.0, 2.0]
    assert msgs["swarm/status"] == [{"ok": True, "note": "raw"}, {"ok": False, "note": "x", "extra": {"1": [None]}}]

    ch = mcap_channels(path)
    for topic in msgs:
        assert ch[topic]["message_encoding"] == "json"
        assert ch[topic]["schema_encoding"] == "jsonschema"
    assert ch["swarm/robot/0/pose"]["schema_name"] == "pixelswarm.Pose"
    assert ch["swarm/robot/0/pose"]["schema"] == POSE_SCHEMA
    assert ch["swarm/status"]["schema"] == STATUS_SCHEMA
    assert ch["swarm/robot/0/pose"]["message_count"] == 2

    # Raw reader view: identical schemas are stored once; publish time is log time, sequence numbers
    # count each channel's messages in the order written.
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert len(summary.schemas) == 2
        assert summary.statistics.message_count == 5
        recs = [
            (c.topic, m.log_time, m.publish_time, m.sequence)
            for _s, c, m in reader.iter_messages(topics=["swarm/robot/0/pose"])
        ]
        meta = list(reader.iter_metadata())
    assert recs == [
        ("swarm/robot/0/pose", 1_000_000_000, 1_000_000_000, 2),
        ("swarm/robot/0/pose", 2_000_000_000, 2_000_000_000, 1),
    ]
    assert meta[0].name == "run" and meta[0].metadata == {"scene": "circle", "seed": "7"}


def test_mcap_cut_anywhere_reads_a_prefix(tmp_path):
    """A run whose writer died leaves a log cut at any byte: it reads up to there, never raises."""
    path = tmp_path / "log.mcap"
    with McapLog(path, compression=None) as log:
        ch = log.add_channel("swarm/robot/0/pose", "pixelswarm.Pose", POSE_SCHEMA)
        for k in range(40):
            log_json(log, ch, (k + 1) * 100_000_000, {"id": 0, "pose": [k * 0.1, 0.0, 0.0], "stamp": k * 0.1})
    whole = path.read_bytes()
    full = read_mcap(path)["swarm/robot/0/pose"]
    cut = tmp_path / "cut.mcap"
    for end in range(len(whole)):  # a cut inside a record's length field raised struct.error once
        cut.write_bytes(whole[:end])
        got = read_mcap(cut).get("swarm/robot/0/pose", [])
        assert got == full[: len(got)]


def test_mcap_scene_update(tmp_path):
    path = tmp_path / "scene.mcap"
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, math.pi / 2], [np.nan, np.nan, np.nan]])
    with McapLog(path, compression="lz4") as log:
        cid = log.add_foxglove_channel("/display", SceneUpdate)
        log.write_bytes(
            cid,
            1_500_000_000,
            scene_update(
                1_500_000_000, pose, [0.1, 0.2, 0.1], np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
            ),
        )
    (msg,) = read_mcap(path)["/display"]
    assert mcap_channels(path)["/display"]["schema_name"] == "foxglove.SceneUpdate"
    ents = msg["entities"]
    assert [e["id"] for e in ents] == ["robot/0", "robot/1"]  # NaN pose skipped
    assert ents[0]["timestamp"] == {"sec": 1, "nsec": 500_000_000}
    cyl = ents[1]["cylinders"][0]
    assert cyl["size"]["x"] == pytest.approx(0.4, abs=QUANTUM)  # lengths to 1/16384 m
    assert cyl["color"] == {"r": 0.0, "g": 1.0, "b": 0.0, "a": 1.0}
    assert cyl["pose"]["orientation"]["z"] == pytest.approx(math.sin(math.pi / 4), abs=1e-4)


# ------------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------------


def _approach(T=101, r=(0.1, 0.2), d0=1.0, v=0.01):
    """Two robots on the x axis moving towards each other: centre distance 2*(d0 - v*k)."""
    t = np.arange(T) * 0.1
    half = d0 - v * np.arange(T)
    pose = np.zeros((T, 2, 3))
    pose[:, 0, 0] = -half
    pose[:, 1, 0] = half
    pose[:, 1, 2] = math.pi
    return t, pose, np.array(r)


def test_clearance_two_robots_approaching():
    t, pose, r = _approach(T=31)  # distance 2.0 -> 1.4
    c = metrics.clearance_over_time(pose, r)
    np.testing.assert_allclose(c, 2 * (1.0 - 0.01 * np.arange(31)) - 0.3, atol=1e-12)
    assert c.min() == pytest.approx(1.4 - 0.3)
    # Overlapping: distance goes 2.0 -> 0.0
    t, pose, r = _approach(T=101)
    c = metrics.clearance_over_time(pose, r)
    assert c.min() == pytest.approx(-0.3)
    assert (c < 0).sum() == int(np.sum(2 * (1 - 0.01 * np.arange(101)) < 0.3 - 1e-12))
    # One robot: no pairs
    assert np.all(np.isinf(metrics.clearance_over_time(pose[:, :1], r[:1])))


def test_clearance_matches_brute_force_many_robots():
    rng = np.random.default_rng(3)
    T, N = 5, 300
    pose = np.zeros((T, N, 3))
    pose[:, :, :2] = rng.uniform(0, 10, (T, N, 2))
    pose[2, 5] = np.nan  # a missing robot is ignored
    for radius in (np.full(N, 0.1), rng.uniform(0.05, 0.4, N)):
        c = metrics.clearance_over_time(pose, radius)
        for k in range(T):
            ok = np.isfinite(pose[k, :, 0])
            xy, rr = pose[k, ok, :2], radius[ok]
            d = np.sqrt(((xy[:, None] - xy[None]) ** 2).sum(-1)) - rr[:, None] - rr[None]
            np.fill_diagonal(d, np.inf)
            assert c[k] == pytest.approx(d.min(), abs=1e-12)


def test_contact_events():
    T = 60
    pose = np.zeros((T, 3, 3))
    pose[:, 2, :2] = 50.0  # far away
    gap = np.full(T, 1.0)
    gap[10:15] = 0.1  # first contact
    gap[30:40] = 0.15  # second contact
    pose[:, 1, 0] = gap
    assert contact_events(pose, np.array([0.1, 0.1, 0.1])) == 2
    assert contact_events(pose[:, :1], np.array([0.1])) == 0


def test_path_lengths():
    T = 5
    pose = np.zeros((T, 3, 3))
    pose[:, 0, :2] = [[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]  # unit square: 4
    pose[:, 1, 0] = np.arange(T) * 0.5  # 2.0
    pose[:, 2, :2] = [[0, 0], [3, 4], [np.nan, np.nan], [3, 4], [3, 4]]  # 5, gap skipped
    np.testing.assert_allclose(metrics.path_lengths(pose), [4.0, 2.0, 5.0])
    assert metrics.path_lengths(pose[:1]).tolist() == [0.0, 0.0, 0.0]


def test_time_to_converge():
    T, N = 50, 3
    t = np.arange(T) * 0.2
    goal = np.full((T, N, 2), np.nan)
    goal[:, 0] = [1.0, 0.0]
    goal[:, 1] = [0.0, 1.0]
    # robot 2 never has a goal and wanders: ignored
    pose = np.zeros((T, N, 3))
    pose[:, 2, 0] = np.linspace(0, 9, T)
    pose[:, 0, 0] = np.clip(np.arange(T) / 20, 0, 1)  # reaches (1,0) at k = 20
    pose[:, 1, 1] = np.clip(np.arange(T) / 30, 0, 1)  # reaches (0,1) at k = 30
    tol = 0.01
    # robot 1 within 0.01 from k = 30 (1 - k/30 <= 0.01 -> k >= 29.7)
    assert metrics.time_to_converge(t, pose, goal, tol) == pytest.approx(t[30])
    # leaving the goal at the end: not converged
    p2 = pose.copy()
    p2[-1, 0, 0] = 0.5
    assert metrics.time_to_converge(t, p2, goal, tol) is None
    # a brief excursion postpones convergence
    p3 = pose.copy()
    p3[40, 0, 0] = 0.8
    assert metrics.time_to_converge(t, p3, goal, tol) == pytest.approx(t[41])
    # a new goal late in the run (robot 0's, 0.5 m back from k = 44): convergence waits for it
    g2 = goal.copy()
    g2[44:, 0] = [0.5, 0.0]
    assert metrics.time_to_converge(t, pose, g2, tol) is None  # robot 0 stays at its old goal
    p4 = pose.copy()
    p4[44:, 0, 0] = [0.8, 0.6, 0.5, 0.5, 0.5, 0.5]  # drives to the new one, there at k = 46
    assert metrics.time_to_converge(t, p4, g2, tol) == pytest.approx(t[46])
    # no goals at all
    assert metrics.time_to_converge(t, pose, np.full((T, N, 2), np.nan), tol) is None
    # every goal gone at the end (robots that stand, waiting for a goal set): nothing is reached
    g3 = goal.copy()
    g3[-3:] = np.nan
    assert metrics.time_to_converge(t, pose, g3, tol) is None


def test_summarise_and_json(tmp_path):
    t, pose, r = _approach(T=101)
    goal = np.full((101, 2, 2), np.nan)
    m = metrics.summarise(
        metrics.TrueRecord(t, pose, r, goal, tolerance=0.05),
        wall_s=5.0,
        contacts=1,
        traffic=metrics.Traffic({"pose": 2020, "plan": 202}, {"pose": 202000}, missed_ticks=3),
        scene="head-on",
        seed=np.int64(4),
    )
    assert set(METRIC_KEYS) <= set(m)
    assert m["robots"] == 2
    assert m["duration_s"] == pytest.approx(10.0)
    assert m["realtime_factor"] == pytest.approx(2.0)
    assert m["min_clearance_m"] == pytest.approx(-0.3)
    assert m["max_overlap_m"] == pytest.approx(0.3)
    assert m["converged"] is False and m["time_to_converge_s"] is None
    np.testing.assert_allclose(m["path_length_m"], [1.0, 1.0])
    assert m["messages_per_robot_s"] == {"pose": pytest.approx(101.0), "plan": pytest.approx(10.1)}
    assert m["bytes_per_robot_s"] == {"pose": pytest.approx(10100.0)}
    assert m["scene"] == "head-on"
    with pytest.raises(ValueError):
        metrics.summarise(metrics.TrueRecord(t, pose, r), wall_s=1.0, contacts=0, robots=5)

    # converged run, one robot (no pairs -> min clearance inf -> null in JSON)
    T = 11
    p1 = np.zeros((T, 1, 3))
    p1[:, 0, 0] = np.minimum(np.arange(T) * 0.2, 1.0)
    g1 = np.zeros((T, 1, 2))
    g1[:, 0, 0] = 1.0
    m1 = metrics.summarise(metrics.TrueRecord(np.arange(T) + 100.0, p1, [0.1], g1, 1e-9), wall_s=0.0, contacts=0)
    assert m1["converged"] is True and m1["time_to_converge_s"] == pytest.approx(5.0)
    assert m1["realtime_factor"] is None
    out = write_json(tmp_path / "metrics.json", m1)
    loaded = json.loads(out.read_text())
    assert loaded["min_clearance_m"] is None
    assert loaded["path_length_m"] == [pytest.approx(1.0)]


# ------------------------------------------------------------------------------------------------
# Video and plots
# ------------------------------------------------------------------------------------------------

ARENA = (0.0, 0.0, 4.0, 3.0)
OBSTACLES = [[(1.8, 1.2), (2.2, 1.2), (2.2, 1.8), (1.8, 1.8)]]


def _behind(pose_i, r):
    """A point inside the disc, away from the heading tick."""
    x, y, th = pose_i
    return np.array([x - 0.5 * r * math.cos(th), y - 0.5 * r * math.sin(th)])


def _scene(T=25, N=3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * 0.1
    pose = np.zeros((T, N, 3))
    pose[:, :, 0] = np.linspace(0.5, 1.5, T)[:, None] + np.arange(N)[None] * 1.0
    pose[:, :, 1] = 0.6
    pose[:, :, 2] = rng.uniform(-np.pi, np.pi, N)
    color = np.zeros((T, N, 3), np.uint8)
    color[:, 0] = (255, 0, 0)  # red (RGB)
    color[:, 1] = (0, 255, 0)
    color[:, 2] = (0, 0, 0)  # LED off: still drawn with a rim
    goal = np.broadcast_to(pose[-1, :, :2] + [0.0, 1.5], (T, N, 2)).copy()
    return t, pose, np.full(N, 0.15), color, goal


def test_render_frame():
    t, pose, r, color, goal = _scene()
    img = render_frame(t[0], pose[0], r, color[0], ARENA, OBSTACLES, goal[0], size_px=400)
    assert img.dtype == np.uint8 and img.ndim == 3
    h, w = img.shape[:2]
    assert max(h, w) in (400, 401, 402) and h % 2 == 0 and w % 2 == 0
    view = _View(ARENA, 400)
    c, rr = np.round(view.px(_behind(pose[0, 0], r[0]))).astype(int)
    assert tuple(int(v) for v in img[rr, c]) == (0, 0, 255)  # red robot, BGR
    oc, orow = np.round(view.px([2.0, 1.5])).astype(int)
    b, g, rch = (int(v) for v in img[orow, oc])
    assert b == g == rch and 60 < b < 200  # grey obstacle
    corner = img[h // 2, w - 3]  # margin: dark background
    assert int(corner.max()) < 40


def test_write_video_frames(tmp_path):
    t, pose, r, color, goal = _scene(T=25)
    path = tmp_path / "display.mp4"
    n = write_video(path, Recording(t, pose, r, ARENA, OBSTACLES, goal, color), fps=10, size_px=320)
    assert n == 25
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    cap.release()
    assert len(frames) == 25
    view = _View(ARENA, 320)
    assert frames[0].shape == (view.height, view.width, 3)
    # the red robot is visible (lossy codec: loose check) and the background is dark
    for k in (0, 24):
        c, rr = np.round(view.px(_behind(pose[k, 0], r[0]))).astype(int)
        b, g, red = (int(v) for v in frames[k][rr, c])
        assert red > 150 and g < 100 and b < 100
    assert frames[0][5:15, view.width - 15 : view.width - 5].mean() < 40

    # subsampling: real-time frames at 5 fps, and capped
    assert len(frame_indices(t, fps=5)) == 13
    assert len(frame_indices(t, fps=10, speed=None, max_frames=10)) == 10
    short = Recording(t, pose, r, ARENA, color=color[0])
    n2 = write_video(tmp_path / "short.mp4", short, fps=10, size_px=160, speed=None, max_frames=7)
    cap = cv2.VideoCapture(str(tmp_path / "short.mp4"))
    count = 0
    while cap.read()[0]:
        count += 1
    cap.release()
    assert n2 == count == 7


@pytest.mark.parametrize("robots", [3, STAMP_ABOVE + 1], ids=["discs", "stamps"])
def test_a_video_frame_is_the_swarm_drawn_whole_though_its_goal_rings_are_drawn_once(robots):
    """The video's frames reuse the goals' rings while goals and colours stand still: every frame has the
    pixels of the whole frame drawn anew, as the goals move on and the colours change."""
    t, pose, r, color, goal = _scene(T=12, N=robots)
    goal[6:] += 0.3  # the next image's goals
    color[9:, 0] = (0, 0, 255)  # a robot's LED turns blue
    rec = Recording(t, pose, r, ARENA, OBSTACLES, goal, color).checked()
    view = _View(ARENA, 320)
    draw = _painter(rec, view)
    for k in [0, 1, 5, 6, 7, 9, 11, 3]:  # on, and back to goals drawn before
        whole = _draw(view.background(OBSTACLES), view, t[k], rec.pose[k], rec.radius, color[k], goal[k])
        assert np.array_equal(draw(k), whole), k


def test_frames_drawn_ahead_of_the_encoder_come_in_order_each_told_once():
    """The next frame is drawn on a thread while the encoder takes the last: the same frames, in order."""
    drawn, told = [], []

    def draw(k):
        drawn.append(k)
        return np.full((2, 2, 3), k, np.uint8)

    frames = list(_drawn_ahead(draw, [4, 0, 7, 7, 2], lambda done, total: told.append((done, total))))
    assert [int(f[0, 0, 0]) for f in frames] == drawn == [4, 0, 7, 7, 2]
    assert told == [(1, 5), (2, 5), (3, 5), (4, 5), (5, 5)]


def test_a_frame_that_cannot_be_drawn_fails_the_video_and_leaves_no_file_or_thread(tmp_path, monkeypatch):
    t, pose, r, color, goal = _scene(T=25)
    draw, calls = render._draw, []

    def failing(*args):
        calls.append(1)
        if len(calls) == 10:
            raise RuntimeError("no ink")
        return draw(*args)

    monkeypatch.setattr(render, "_draw", failing)
    path = tmp_path / "display.mp4"
    with pytest.raises(RuntimeError, match="no ink"):
        write_video(path, Recording(t, pose, r, ARENA, goal=goal, color=color), size_px=160)
    assert len(calls) == 10 and not path.exists()
    assert not [th for th in threading.enumerate() if th.name.startswith("video-frames")]


def test_write_plots(tmp_path):
    t, pose, r, color, goal = _scene(T=40, N=4)
    clr = metrics.clearance_over_time(pose, r)
    paths = write_plots(tmp_path / "plots", Recording(t, pose, r, ARENA, OBSTACLES, goal, color), clr)
    assert set(paths) == {"clearance", "trajectories"}
    for name in ("clearance.png", "trajectories.png"):
        p = tmp_path / "plots" / name
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    # one robot: clearance all inf still plots
    write_plots(tmp_path / "one", Recording(t, pose[:, :1], r[:1], ARENA), np.full(len(t), np.inf))
    assert (tmp_path / "one" / "clearance.png").stat().st_size > 0


# ------------------------------------------------------------------------------------------------
# Run directory
# ------------------------------------------------------------------------------------------------


def test_rundir_abort_leaves_nothing(tmp_path):
    final = tmp_path / "runs" / "r1"
    rd = RunDir(final)
    assert rd.path == final.with_name("r1.partial") and rd.path.is_dir()
    write_json(rd / "metrics.json", {"x": 1})
    rd.abort()
    assert list((tmp_path / "runs").iterdir()) == []
    rd.abort()  # idempotent
    with pytest.raises(RuntimeError):
        rd.commit()

    with pytest.raises(ZeroDivisionError):
        with RunDir(tmp_path / "runs" / "r2") as rd2:
            write_json(rd2 / "metrics.json", {"x": 1})
            raise ZeroDivisionError
    assert list((tmp_path / "runs").iterdir()) == []


def test_rundir_commit_leaves_only_final(tmp_path):
    root = tmp_path / "runs"
    final = default_run_path("circle", root=root)
    with RunDir(final) as rd:
        write_json(rd / "metrics.json", {"v": np.float64(np.nan), "n": np.int32(3), "a": np.arange(2)})
        write_npz(rd / "trajectory.npz", t=np.arange(3.0), pose=np.zeros((3, 2, 3)))
        assert not final.exists()
    assert rd.state == "committed" and rd.path == final
    assert sorted(p.name for p in root.iterdir()) == [final.name]
    assert sorted(p.name for p in final.iterdir()) == ["metrics.json", "trajectory.npz"]
    assert json.loads((final / "metrics.json").read_text()) == {"v": None, "n": 3, "a": [0, 1]}
    with np.load(final / "trajectory.npz") as z:
        assert z["pose"].shape == (3, 2, 3) and z["t"].tolist() == [0.0, 1.0, 2.0]
    with pytest.raises(FileExistsError):
        RunDir(final)
    # explicit commit
    rd2 = RunDir(root / "explicit")
    (rd2 / "a.txt").write_text("a")
    assert rd2.commit() == root / "explicit"
    assert (root / "explicit" / "a.txt").read_text() == "a"
    assert not (root / "explicit.partial").exists()


def test_default_run_path_unique(tmp_path):
    now = dt.datetime(2025, 1, 31, 14, 25, 1, tzinfo=dt.UTC)
    a = default_run_path("circle", root=tmp_path, now=now)
    b = default_run_path("circle", root=tmp_path, now=now)
    assert a.parent == tmp_path and a.name == "20250131T142501Z-circle"
    assert a != b and b.name == "20250131T142501Z-circle-2"
    c = default_run_path("my scene/2", root=tmp_path)
    assert re.fullmatch(r"\d{8}T\d{6}Z-my-scene-2", c.name)
    (tmp_path / "20250131T142501Z-x.partial").mkdir()  # a run in progress elsewhere
    assert default_run_path("x", root=tmp_path, now=now).name == "20250131T142501Z-x-2"


def test_json_safe():
    obj = {
        "a": np.float32(1.5),
        "b": [np.nan, -np.inf, 2],
        "c": np.array([[1, 2]], np.int16),
        "d": (np.bool_(True), None),
        3: "k",
        "e": np.array([np.nan, 1.0]),
    }
    assert json_safe(obj) == {
        "a": 1.5,
        "b": [None, None, 2],
        "c": [[1, 2]],
        "d": [True, None],
        "3": "k",
        "e": [None, 1.0],
    }
    assert "NaN" not in dumps_json({"x": float("nan")})
    with pytest.raises(TypeError):
        json_safe(object())


@pytest.mark.parametrize("flags, drawn", [((), {"clearance.png", "trajectories.png"}), (("--no-plots",), set())])
def test_no_plots_leaves_the_plots_out_and_everything_else_in(tmp_path, flags, drawn):
    out = tmp_path / "run"
    args = ("run", "circle", "--robots", "2", "--duration", "0.5", "--engine", "central", "--no-video", "-q")
    result = run_pixelswarm(*args, *flags, "--out", str(out), timeout=120)
    assert result.returncode == 0, result.stderr
    names = {p.name for p in out.iterdir()}
    assert {"metrics.json", "trajectory.npz", "scene.json"} <= names
    assert {n for n in names if n.endswith(".png")} == drawn
