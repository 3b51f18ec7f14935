"""The live view in Rerun (sim.outputs.view, pixelswarm run --view, pixelswarm view): no window is opened here.
The logging path writes an .rrd file, read back with Rerun's own chunk reader; the web viewer is a real
Rerun server process on 127.0.0.1, asked for its page and stopped."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import psutil
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader  # noqa: E402

from sim.cli.main import main  # noqa: E402
from sim.outputs.view import SwarmView, replay  # noqa: E402
from tests.conftest import run_pixelswarm  # noqa: E402
from tests.support.outputs import url_serves  # noqa: E402
from tests.support.recording import recorded_swarm  # noqa: E402

ARENA = (-2.0, -1.5, 2.0, 1.5)


def _swarm(T: int, N: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    start = rng.uniform(-1.5, 1.5, (N, 2))
    step = rng.normal(0, 0.01, (T, N, 2)).cumsum(axis=0)
    pose = np.concatenate([start + step, rng.uniform(-np.pi, np.pi, (T, N, 1))], axis=2)
    color = rng.integers(0, 256, (T, N, 3)).astype(np.uint8)
    goal = np.broadcast_to(rng.uniform(-1.5, 1.5, (N, 2)), (T, N, 2)).copy()
    goal[:5, 0] = np.nan  # no goal set yet
    return {"t": np.arange(T) * 0.1, "pose": pose, "color": color, "goal": goal, "radius": np.full(N, 0.035)}


def test_a_swarm_logged_to_a_file_reads_back_tick_by_tick(tmp_path):
    """One batch a tick: every robot's position and colour at every tick, as Rerun reads them back."""
    s = _swarm(T=30, N=50, seed=3)
    path = tmp_path / "view.rrd"
    view = SwarmView("test", ARENA, [[(0.0, 0.0), (0.3, 0.0), (0.3, 0.3)]], s["radius"], robots=50, sink=path)
    for k in range(30):
        view.tick(k, s["t"][k], s["pose"][k], s["color"][k], s["goal"][k], missed=np.full(50, k))
    view.close()
    recorded = recorded_swarm(path)
    assert list(recorded) == list(range(30))
    for k, (xy, rgb) in recorded.items():
        np.testing.assert_allclose(xy, s["pose"][k, :, :2], rtol=1e-6, atol=1e-6)  # Rerun keeps float32
        np.testing.assert_array_equal(rgb, s["color"][k])
    entities = RrdReader(str(path)).store().summary()
    for entity in ("/arena", "/obstacles", "/swarm/heading", "/swarm/goals", "/swarm/trails", "/metrics/clearance"):
        assert entity in entities


def test_the_web_view_is_served_on_loopback_and_stops_with_the_view(tmp_path):
    view = SwarmView("test", ARENA, [], 0.035, robots=3, sink="web")
    try:
        assert view.url is not None and view.url.startswith("http://127.0.0.1:")
        assert url_serves(view.url)
        server = psutil.Process(view.process.pid)
        listening = [c.laddr.ip for c in server.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
        assert listening and set(listening) == {"127.0.0.1"}  # nothing on another interface
        view.tick(0, 0.0, np.zeros((3, 3)), np.zeros((3, 3), np.uint8), np.full((3, 2), np.nan))
    finally:
        view.close()
    assert not psutil.pid_exists(server.pid) or server.status() == psutil.STATUS_ZOMBIE


def test_a_bad_view_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["run", "circle", "--view", "banana", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "--view takes native, web or a FILE.rrd" in err, err
    assert not (tmp_path / "run").exists() and not (tmp_path / "run.partial").exists()
    assert main(["view", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "is not a run directory" in err and "Traceback" not in err


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_100_robot_run_viewed_live_is_its_trajectory(tmp_path):
    """`pixelswarm run --view FILE.rrd` on 100 robots: Rerun's own reader finds every robot's position and
    colour equal to trajectory.npz at every tick; `pixelswarm view RUN_DIR --save` replays it the same."""
    out, rrd = tmp_path / "run", tmp_path / "live.rrd"
    args = ("--engine", "central", "--duration", "6", "--no-video", "--no-plots", "-q", "--seed", "2")
    result = run_pixelswarm("run", "paper-sequence-100", *args, "--out", str(out), "--view", str(rrd))
    assert result.returncode == 0, result.stderr[-3000:]
    traj = np.load(out / "trajectory.npz")
    T, N = traj["pose"].shape[:2]
    assert N == 100
    for path in (rrd, _replayed(out, tmp_path)):
        recorded = recorded_swarm(path)
        assert len(recorded) == T
        for k, (xy, rgb) in zip(range(T), recorded.values()):
            np.testing.assert_allclose(xy, traj["pose"][k, :, :2], rtol=1e-6, atol=1e-6)
            np.testing.assert_array_equal(rgb, traj["color"][k])


def _replayed(out: Path, tmp_path: Path) -> Path:
    saved = tmp_path / "replay.rrd"
    result = run_pixelswarm("view", str(out), "--save", str(saved), timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == str(saved), result.stderr[-2000:]
    return saved


def test_replay_builds_the_recording_from_a_run_directory(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    s = _swarm(T=12, N=20, seed=8)
    np.savez(run / "trajectory.npz", **s)
    (run / "scene.json").write_text(json.dumps({"name": "demo", "arena": list(ARENA), "obstacles": []}))
    replay(run, tmp_path / "r.rrd").close()
    recorded = recorded_swarm(tmp_path / "r.rrd")
    assert len(recorded) == 12
    np.testing.assert_allclose(recorded[11][0], s["pose"][11, :, :2], rtol=1e-6, atol=1e-6)


def test_the_view_subcommand_is_in_the_help():
    shown = subprocess.run([sys.executable, "-m", "sim.cli", "view", "--help"], capture_output=True, text=True)
    assert shown.returncode == 0 and "--web" in shown.stdout and "--save" in shown.stdout


@pytest.mark.slow
@pytest.mark.timeout(200)
def test_a_distributed_run_is_viewed_from_the_recorder(tmp_path):
    """The distributed engine: the recorder (a bus subscriber, not the agents) logs the world's truth."""
    out, rrd = tmp_path / "run", tmp_path / "live.rrd"
    args = ("--robots", "4", "--duration", "3", "-k", "4", "--no-video", "--no-plots", "-q")
    result = run_pixelswarm("run", "swap", *args, "--out", str(out), "--view", str(rrd))
    assert result.returncode == 0, result.stderr[-3000:]
    traj = np.load(out / "trajectory.npz")
    recorded = recorded_swarm(rrd)
    assert len(recorded) == len(traj["t"])
    for k, (xy, rgb) in zip(range(len(traj["t"])), recorded.values()):
        np.testing.assert_allclose(xy, traj["pose"][k, :, :2], rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(rgb, traj["color"][k])


def _run_dir(path: Path) -> Path:
    """A small finished run's trajectory.npz and scene.json."""
    path.mkdir()
    np.savez(path / "trajectory.npz", **_swarm(T=6, N=4, seed=1))
    (path / "scene.json").write_text(json.dumps({"name": "demo", "arena": list(ARENA), "obstacles": []}))
    return path


def _spoil(run: Path, how: str) -> None:
    """A run directory whose files are there but do not read as a run's."""
    if how == "empty trajectory":
        (run / "trajectory.npz").write_bytes(b"")
    elif how == "trajectory without pose":
        np.savez(run / "trajectory.npz", t=np.zeros(3))
    elif how == "poses of two numbers":
        s = _swarm(T=6, N=4, seed=1)
        np.savez(run / "trajectory.npz", **(s | {"pose": s["pose"][..., :2]}))
    elif how == "scene not JSON":
        (run / "scene.json").write_text("garbage")
    elif how == "arena a number":
        (run / "scene.json").write_text('{"arena": 5}')


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--save", "{tmp}/missing/v.rrd"], "--save: no directory {tmp}/missing to write v.rrd in"),
        (["--save", "{tmp}"], "--save {tmp} is a directory"),
        (["--save", "{tmp}/v.rrd", "--web"], "--web serves the view, --save writes it to a file: choose one"),
        ([], "no display to open Rerun's window on"),
        (["--save", "/proc/v.rrd"], "cannot write /proc/v.rrd.partial"),
        (["--connect", "tcp/127.0.0.1:7447", "--save", "{tmp}"], "--save {tmp} is a directory"),
        (["--connect", "tcp/127.0.0.1:7447"], "no display to open Rerun's window on"),
    ],
)
def test_a_view_that_cannot_be_shown_or_saved_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, argv, said):
    """`pixelswarm view`: nothing written (RUN_DIR/view.rrd neither), and a viewer's window where no display is
    (it used to exit 0 having shown nothing) says what to use instead."""
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    run = _run_dir(tmp_path / "run")
    argv = [a.format(tmp=tmp_path) for a in argv]
    where = [] if "--connect" in argv else [str(run)]
    assert main(["view", *where, *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and said.format(tmp=tmp_path) in err and "Traceback" not in err, err
    if not argv:
        assert "use --web to serve the view, or --save FILE.rrd" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert sorted(p.name for p in run.iterdir()) == ["scene.json", "trajectory.npz"]


@pytest.mark.parametrize(
    ("how", "said"),
    [
        ("empty trajectory", "trajectory.npz is not a NumPy .npz archive"),
        ("trajectory without pose", "trajectory.npz has no pose, color, goal, radius"),
        ("poses of two numbers", "trajectory.npz: pose has shape (6, 4, 2), not (T, N, 3)"),
        ("scene not JSON", "scene.json does not read as a run's scene"),
        ("arena a number", "scene.json does not read as a run's scene"),
    ],
)
def test_a_run_directory_that_does_not_read_is_one_line_and_leaves_the_saved_file(tmp_path, capsys, how, said):
    run = _run_dir(tmp_path / "run")
    _spoil(run, how)
    saved = tmp_path / "v.rrd"
    saved.write_text("an earlier recording")
    assert main(["view", str(run), "--save", str(saved)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and said in err and "Traceback" not in err, err
    assert saved.read_text() == "an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "v.rrd"]


def test_a_saved_replay_takes_its_name_only_when_whole(tmp_path, capsys):
    run = _run_dir(tmp_path / "run")
    saved = tmp_path / "v.rrd"
    assert main(["view", str(run), "--save", str(saved)]) == 0
    assert capsys.readouterr().out.strip() == str(saved)
    assert len(recorded_swarm(saved)) == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "v.rrd"]


def test_a_live_view_into_a_file_that_cannot_be_made_is_one_line_and_no_run(tmp_path, capsys):
    """--view FILE.rrd in a folder there is but no file can be made in (rerun's error was a traceback)."""
    out = tmp_path / "r"
    code = main(["run", "circle", "--engine", "central", "--out", str(out), "--no-video", "--no-plots", "-q",
                 "--view", "/proc/v.rrd"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert "pixelswarm run: error: --view: cannot write /proc/v.rrd" in err
    assert not list(tmp_path.iterdir())


def test_a_live_view_in_a_window_without_a_display_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["run", "circle", "--engine", "central", "--out", str(tmp_path / "r"), "-q", "--view"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no display" in err and "use --view web or --view FILE.rrd" in err, err
    assert not list(tmp_path.iterdir())
