"""`pixelswarm run --secure DIR`: a secured run of real processes on 127.0.0.1, and what it refuses.

The run's router enforces the access rules of a folder made by `pixelswarm certs`; every process joins
it as its role. A session holding robot 3's credentials joins the run too and forges a goal set for
every robot: the router drops it, so the robots still swap to their antipodes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from sim.cli.main import main
from tests.conftest import REPO, bus_when_listening, pixelswarm_cmd, run_pixelswarm
from transport.codec import Goals, Tick
from transport.keys import Keys
from transport.security import check_folder, client_config, make_certificates
from transport.session import free_port

ROBOTS = 6
KEYS = Keys("default")
FORGED_EPOCH = 1_000_000  # newer than any the coordinator sends
RUN_TIMEOUT_S = 240.0  # a bound for a hung run, not a speed target


def _rotated(xy: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return xy @ np.array([[c, s], [-s, c]])


def _circle_starts() -> np.ndarray:
    """The circle scene's start positions for ROBOTS robots (antipodal goals: the negatives)."""
    from coordinator.scene import load_scene

    return np.asarray(load_scene("circle", robots=ROBOTS).poses, float)[:, :2]


def _forge(folder: Path, endpoint: str, forged: np.ndarray, stop: threading.Event, report: dict) -> None:
    """Join the run as robot 3 and, once its clock ticks, publish a goal set for every robot."""
    settings = dataclasses.replace(client_config(folder, "robot-3", endpoint), connect_timeout_ms=1000)
    try:
        bus = bus_when_listening(settings, stop)
        if bus is None:
            return
        with bus:
            clock = bus.subscribe(KEYS.clock, Tick)
            goals = bus.subscribe(KEYS.all_of("goals"), Goals)
            message = Goals(FORGED_EPOCH, 1, forged.astype(np.float32), np.zeros((ROBOTS, 3), np.uint8))
            while not stop.wait(0.1):
                ticks = [msg.tick for _, msg in clock.drain()]
                report["genuine_goal_sets"] += len(goals.drain())
                if ticks:
                    report["last_tick"] = max(ticks)
                if report["genuine_goal_sets"] and report["last_tick"] is not None:
                    bus.publish(KEYS.goals(FORGED_EPOCH), message)
                    report["forged"] += 1
                    if report["first_forged_tick"] is None:
                        report["first_forged_tick"] = report["last_tick"]
    except Exception as err:  # reported to the test, which fails on it
        report["error"] = repr(err)


@pytest.mark.slow
@pytest.mark.serial
def test_a_secured_run_converges_and_a_robots_forged_goal_set_changes_no_goal(tmp_path, spawned):
    made = run_pixelswarm("certs", str(tmp_path / "certs"), "--robots", str(ROBOTS), timeout=60)
    assert made.returncode == 0, made.stderr
    folder = Path(made.stdout.strip())
    endpoint = f"tls/127.0.0.1:{free_port()}"
    out = tmp_path / "run"
    starts = _circle_starts()
    report: dict = {"genuine_goal_sets": 0, "last_tick": None, "forged": 0, "first_forged_tick": None}
    stop = threading.Event()
    forger = threading.Thread(target=_forge, args=(folder, endpoint, _rotated(starts, np.pi / 2), stop, report))
    # In real time the robots are on their way for seconds of wall time: the forger's TLS session opens
    # while they move (a lock-step run swaps them in less time than that session takes to open).
    args = ["run", "circle", "--robots", str(ROBOTS), "--secure", str(folder), "--clock", "realtime"]
    args += ["--no-video", "--no-plots", "--duration", "30", "--listen", endpoint, "--out", str(out), "-q"]
    run = subprocess.Popen(pixelswarm_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    spawned.append(run)
    forger.start()
    try:
        stdout, stderr = run.communicate(timeout=RUN_TIMEOUT_S)
    finally:
        stop.set()
        forger.join(timeout=10)
    assert not forger.is_alive()
    assert run.returncode == 0, stderr[-3000:]
    assert Path(stdout.strip()) == out

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["converged"] and metrics["contacts"] == 0, metrics
    # Robot 3's credentials got in and its forgeries went out while the robots were still on their way.
    assert "error" not in report, report
    assert report["forged"] > 0 and report["genuine_goal_sets"] > 0, report
    dt = float(json.loads((out / "scene.json").read_text())["robot"]["dt"])
    assert report["first_forged_tick"] * dt < metrics["time_to_converge_s"], report

    # Every goal any robot announced is its antipode, never the forged one.
    trajectory = np.load(out / "trajectory.npz")
    goals, antipodes = trajectory["goal"], -starts
    announced = np.isfinite(goals[..., 0])
    assert announced[-1].all()
    assert np.allclose(goals[announced], np.broadcast_to(antipodes, goals.shape)[announced], atol=1e-3)
    tolerance = metrics["convergence_tolerance_m"]
    assert np.all(np.hypot(*(trajectory["pose"][-1, :, :2] - antipodes).T) <= tolerance + 1e-9)


@pytest.fixture(scope="module")
def two_robots(tmp_path_factory) -> Path:
    return make_certificates(tmp_path_factory.mktemp("secure") / "certs", 2)


BAD_INPUTS = [
    (["--secure", "{tmp}/missing"], "is not a folder"),
    (["--secure", "{tmp}/empty"], "roles.json missing"),
    (["--secure", "{certs}"], "made for 2 robots and this run has 3"),
    (["--secure", "{certs}", "--robots", "2", "-k", "2"], "one robot per agent process"),
    (["--secure", "{certs}", "--robots", "2", "-e", "tls/127.0.0.1:{port}"], "cannot be used with -e"),
    (["--secure", "{certs}", "--robots", "2", "--agents-connect", "tls/127.0.0.1:{port}"], "--agents-connect"),
    (["--secure", "{certs}", "--robots", "2", "--listen", "tcp/127.0.0.1:{port}"], "TLS only"),
    (["--secure", "{certs}", "--robots", "2", "--display", "other"], "display 'default', not 'other'"),
    (["--secure", "{certs}", "--robots", "2", "--engine", "central"], "central engine has none"),
    (["--secure", "{certs}", "--robots", "2", "--zenoh-config", "{certs}/world.json5"], "--zenoh-config"),
]


@pytest.mark.parametrize("extra, message", BAD_INPUTS)
def test_bad_input_to_a_secured_run_is_one_line_and_exit_2(extra, message, two_robots, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    fill = {"tmp": str(tmp_path), "certs": str(two_robots), "port": str(free_port())}
    out = tmp_path / "run"
    code = main(
        [
            "run",
            "swap",
            "--robots",
            "3",
            "--no-video",
            "--no-plots",
            "--out",
            str(out),
            *[a.format(**fill) for a in extra],
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() and not out.with_name("run.partial").exists()


def test_a_folder_missing_a_robots_key_is_refused_before_anything_starts(tmp_path):
    folder = make_certificates(tmp_path / "certs", 2)
    key = folder / "robot-1-key.pem"
    key.unlink()
    out = tmp_path / "run"
    result = run_pixelswarm("run", "swap", "--robots", "2", "--secure", str(folder), "--out", str(out), timeout=60)
    assert result.returncode == 2, result.stderr
    assert f"cannot read {key}" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr and result.stdout == ""
    assert not out.exists() and not out.with_name("run.partial").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_an_unreadable_folder_is_refused(tmp_path):
    folder = make_certificates(tmp_path / "certs", 2)
    folder.chmod(0)
    try:
        with pytest.raises(ValueError, match="cannot read"):
            check_folder(folder, 2)
    finally:
        folder.chmod(0o700)
