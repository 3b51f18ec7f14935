"""`pixelswarm view --connect ENDPOINT`: a viewer in another process watches a running swarm from its bus.

Real runs on 127.0.0.1 (free ports, no multicast scouting), real viewer processes writing .rrd files that
Rerun's own reader reads back. A viewer only subscribes: killing one mid-run leaves the run whole, and on
a secured bus the observer role it joins as can read the display but publish nothing (checked as the
security tests check a rogue robot: at the router, and in a run whose goal set an observer forges).
"""

from __future__ import annotations

import dataclasses
import json
import signal
import socket
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")

from coordinator.scene import load_scene  # noqa: E402
from sim.central.engine import simulate  # noqa: E402
from sim.cli.main import main  # noqa: E402
from tests.conftest import REPO, bus_when_listening, pixelswarm_cmd, run_pixelswarm, wait_for  # noqa: E402
from tests.support.recording import recorded_swarm  # noqa: E402
from transport.bus import Bus  # noqa: E402
from transport.codec import Goals, Tick, Truth  # noqa: E402
from transport.keys import Keys  # noqa: E402
from transport.security import AUTH_MODES, OBSERVER, client_config, make_certificates, router_config  # noqa: E402
from transport.session import free_port, listening, loopback_router, open_session  # noqa: E402

KEYS = Keys("default")
RUN_TIMEOUT_S = 240.0  # a bound for a hung run, not a speed target


def _start(args: list[str], spawned: list, log: Path) -> subprocess.Popen:
    """A pixelswarm process of the test's, its stderr in ``log``."""
    with log.open("w") as err:
        proc = subprocess.Popen(pixelswarm_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=err, text=True)
    spawned.append(proc)
    return proc


def _viewer(endpoint: str, rrd: Path, spawned: list, *extra: str) -> subprocess.Popen:
    return _start(
        ["view", "--connect", endpoint, "--save", str(rrd), "--timeout", "180", *extra],
        spawned,
        rrd.with_suffix(".err"),
    )


def _await_router(port: int, run: subprocess.Popen) -> None:
    assert wait_for(lambda: listening(port) or run.poll() is not None, 120, 0.02), "the run's router never listened"
    assert run.poll() is None, "the run ended before its router listened"


def _await_waiting(viewer: subprocess.Popen, err: Path) -> None:
    """The viewer has subscribed (it says so): from now on it misses no tick."""
    assert wait_for(lambda: "waiting for a run" in err.read_text() or viewer.poll() is not None, 60, 0.02)
    assert viewer.poll() is None, err.read_text()[-2000:]


def _seen_as_run(rrd: Path, out: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """What a viewer recorded, checked against the run's trajectory.npz tick by tick: every robot's
    position and colour as the run wrote them, up to the run's last recorded tick (the world may tick
    once more after the end, which the viewer shows and the run does not keep), and every robot moved
    while the viewer watched."""
    recorded = recorded_swarm(rrd)
    trajectory = np.load(out / "trajectory.npz")
    dt = float(json.loads((out / "scene.json").read_text())["robot"]["dt"])
    row = {int(k): i for i, k in enumerate(np.round(trajectory["t"] / dt))}
    assert max(row) in recorded and len(recorded) >= 10, sorted(recorded)
    for tick, (xy, rgb) in recorded.items():
        if tick > max(row):
            continue
        np.testing.assert_allclose(xy, trajectory["pose"][row[tick], :, :2], rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(rgb, trajectory["color"][row[tick]])
    first, last = recorded[min(recorded)][0], recorded[max(row)][0]
    assert np.all(np.hypot(*(last - first).T) > 0.05), (first, last)  # every robot moved
    return recorded


@pytest.mark.slow
@pytest.mark.timeout(360)
def test_a_viewer_from_another_process_sees_every_robot_move_and_its_exit_leaves_the_run_whole(tmp_path, spawned):
    """Two viewers join a lock-step run on its router: one is killed (SIGKILL) once it has seen a tick,
    the other watches to the end. The run is whole and the same as without them (the central engine's
    run of the seed); the second viewer's recording is the run. The viewers wait at the router before
    the run starts: a lock-step run of four robots is over in a second or two."""
    router = loopback_router()
    out = tmp_path / "run"
    endpoint = router.listen[0]
    # a deadline no loaded machine reaches: no tick is missed, so the run is the central engine's to the bit
    args = [
        "run",
        "swap",
        "--robots",
        "4",
        "-k",
        "2",
        "--clock",
        "lockstep",
        "--seed",
        "1",
        "--duration",
        "12",
        "--deadline",
        "60",
    ]
    with open_session(router):  # the router the viewers and the run join
        watcher, quitter = (
            _viewer(endpoint, tmp_path / "a.rrd", spawned),
            _viewer(endpoint, tmp_path / "b.rrd", spawned),
        )
        _await_waiting(watcher, tmp_path / "a.err")
        _await_waiting(quitter, tmp_path / "b.err")
        run = _start(
            [*args, "--no-video", "--no-plots", "-q", "-e", endpoint, "--out", str(out)], spawned, tmp_path / "run.err"
        )
        assert wait_for(
            lambda: "watching 4 robots" in (tmp_path / "b.err").read_text() or quitter.poll() is not None, 180, 0.02
        )
        assert "watching 4 robots" in (tmp_path / "b.err").read_text(), (tmp_path / "b.err").read_text()[-2000:]
        quitter.send_signal(signal.SIGKILL)  # the harshest exit: no goodbye to the router
        quitter.wait(timeout=30)
        stdout, _ = run.communicate(timeout=RUN_TIMEOUT_S)
        assert run.returncode == 0, (tmp_path / "run.err").read_text()[-3000:]
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["complete"] and metrics["converged"] and metrics["missed_ticks"] == 0, metrics
        # undisturbed: the lock-step run is, to the bit, the central engine's run of the seed (no auction in swap)
        central = simulate(load_scene("swap", robots=4, seed=1, clock="lockstep", duration=12), progress=None).arrays
        trajectory = np.load(out / "trajectory.npz")
        np.testing.assert_array_equal(trajectory["t"], central["t"])
        assert np.abs(trajectory["pose"][..., :2] - central["pose"][..., :2]).max() <= 1e-9
        viewed, _ = watcher.communicate(timeout=60)
        assert watcher.returncode == 0, (tmp_path / "a.err").read_text()[-3000:]
        assert viewed.strip() == str(tmp_path / "a.rrd")
        _seen_as_run(tmp_path / "a.rrd", out)
        assert "the run ended" in (tmp_path / "a.err").read_text()


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    return make_certificates(tmp_path_factory.mktemp("observer") / "certs", 4)


@pytest.mark.parametrize("auth", AUTH_MODES)
def test_the_observer_reads_the_display_and_publishes_nothing(certs, auth):
    """At a router with the access rules: the observer hears the world's truth and a robot's state, and
    nothing it puts (a goal set, a command, a state, poses, the clock, truth, an event) or declares alive
    reaches the recorder, the world, the coordinator or the robots."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = open_session(router_config(certs, endpoint, auth=auth))

    def bus(role: str) -> Bus:
        return Bus(client_config(certs, role, endpoint, auth=auth))

    try:
        with bus(OBSERVER) as observer, bus("recorder") as recorder, bus("world") as world, bus("robot-1") as robot:
            everything = recorder.subscribe_raw(KEYS.everything)
            robots_hear = robot.subscribe_raw(KEYS.all_of("goals"))
            commands = world.subscribe_raw(KEYS.all_of("cmd"))
            alive = recorder.watch_alive()
            truth = observer.subscribe(KEYS.truth, Truth)
            states = observer.subscribe_raw(KEYS.all_of("state"))
            heard: dict[str, set] = {"recorder": set(), "world": set(), "robot": set(), "alive": set()}

            def listen() -> dict[str, set]:
                heard["recorder"] |= {(key, payload) for key, payload, _ in everything.drain()}
                heard["world"] |= {(key, payload) for key, payload, _ in commands.drain()}
                heard["robot"] |= {(key, payload) for key, payload, _ in robots_hear.drain()}
                heard["alive"] |= {f"{role}/{ident}" for role, ident, _, _, _ in alive.drain()}
                return heard

            pose, velocity, rgb, applied = (
                np.zeros((2, 3)),
                np.zeros((2, 2)),
                np.zeros((2, 3), np.uint8),
                np.ones(2, np.uint32),
            )
            message = Truth(1, 0.1, 0.2, 2, pose, velocity, rgb, applied)

            def reads() -> bool:  # the observer reads what the display needs, once both subscriptions are routed
                world.publish(KEYS.truth, message)
                robot.put(KEYS.state((0, 0), 1), b"own")
                return truth.get(timeout=0.05) is not None and bool(states.drain())

            assert wait_for(reads, 10.0, 0.02)
            forged = [KEYS.goals(9), KEYS.cmd(1), KEYS.states(1), KEYS.state((0, 0), 1), KEYS.poses, KEYS.pose(1)]
            forged += [KEYS.clock, KEYS.truth, KEYS.contact, KEYS.event]
            for key in forged:
                observer.put(key, b"forged")
            observer.declare_alive("agent", 1)
            observer.declare_alive("world", 0)
            # The observer's subscription comes after its forgeries on the same link: once the router routes
            # to it, it has handled them; the coordinator's goal set after that reaches the recorder after
            # any forgery the router let through.
            late = observer.subscribe_raw(KEYS.event)
            assert wait_for(lambda: world.put(KEYS.event, b"probe") or bool(late.drain()), 10.0, 0.02)
            with bus("coordinator") as coordinator:
                assert wait_for(
                    lambda: (
                        coordinator.put(KEYS.goals(1), b"goal set") or (KEYS.goals(1), b"goal set") in listen()["robot"]
                    ),
                    10.0,
                    0.02,
                )
            assert wait_for(lambda: (KEYS.goals(1), b"goal set") in listen()["recorder"], 10.0, 0.02)
            got = listen()
            reached = {key for key, payload in got["recorder"] | got["world"] | got["robot"] if payload == b"forged"}
            assert not reached, reached
            assert not {"agent/1", "world/0"} & got["alive"], got["alive"]
    finally:
        router.close()


def _forge(folder: Path, endpoint: str, role: str, forged: np.ndarray, stop: threading.Event, report: dict) -> None:
    """Join the secured run as ``role`` and, once its clock ticks and a goal set of the coordinator's came,
    publish a goal set for every robot under the next epoch, as the coordinator would, all along."""
    settings = dataclasses.replace(client_config(folder, role, endpoint), connect_timeout_ms=1000)
    try:
        bus = bus_when_listening(settings, stop)
        if bus is None:
            return
        with bus:
            clock = bus.subscribe(KEYS.clock, Tick)
            goals = bus.subscribe(KEYS.all_of("goals"), Goals)
            own = lambda g: g.positions.shape == forged.shape and np.allclose(g.positions, forged, atol=1e-3)
            newest = 0
            while not stop.wait(0.1):
                ticks = [msg.tick for _, msg in clock.drain()]
                genuine = [msg for _, msg in goals.drain() if not own(msg)]
                report["genuine_goal_sets"] += len(genuine)
                newest = max([newest, *(g.epoch for g in genuine)])
                if ticks:
                    report["last_tick"] = max(ticks)
                if report["genuine_goal_sets"] and report["last_tick"] is not None:
                    # the next epoch, each robot's own goal: what a receiver takes from the coordinator
                    message = Goals(newest + 1, 1, forged.astype(np.float32), np.zeros((len(forged), 3), np.uint8))
                    bus.publish(KEYS.goals(newest + 1), message)
                    report["forged"] += 1
                    if report["first_forged_tick"] is None:
                        report["first_forged_tick"] = report["last_tick"]
    except Exception as err:  # reported to the test, which fails on it
        report["error"] = repr(err)


@pytest.mark.slow
@pytest.mark.wall_clock
@pytest.mark.timeout(360)
def test_a_secured_run_refuses_a_robots_and_the_observers_forged_goal_sets_while_a_viewer_watches(tmp_path, spawned):
    """`pixelswarm run --secure DIR` converges, every robot on its antipode, while two sessions forge a goal
    set for every robot all along: one with robot 3's credentials (a rogue robot), one with the observer's
    (the role a viewer joins as). The router drops both: no robot ever announces a forged goal. Meanwhile
    `pixelswarm view --connect tls/... --secure DIR` sees every robot move as the run recorded it."""
    robots = 6
    made = run_pixelswarm("certs", str(tmp_path / "certs"), "--robots", str(robots), timeout=60)
    assert made.returncode == 0, made.stderr
    folder = Path(made.stdout.strip())
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    out = tmp_path / "run"
    # In real time the robots move for seconds of wall time: the viewer and the forgers, which join only
    # once the run's router listens (and open TLS sessions), see them on their way (a lock-step run is
    # over in about as long as those sessions take to open).
    args = ["run", "circle", "--robots", str(robots), "--secure", str(folder), "--clock", "realtime"]
    args += ["--no-video", "--no-plots", "-q", "--duration", "30", "--listen", endpoint, "--out", str(out)]
    starts = np.asarray(load_scene("circle", robots=robots).poses, float)[:, :2]
    quarter = np.array([[0.0, 1.0], [-1.0, 0.0]])  # the starts turned a quarter: goals no robot has
    forgeries = {"robot-3": starts @ quarter, OBSERVER: starts}
    reports = {
        role: {"genuine_goal_sets": 0, "last_tick": None, "forged": 0, "first_forged_tick": None} for role in forgeries
    }
    stop = threading.Event()
    forgers = [
        threading.Thread(target=_forge, args=(folder, endpoint, role, forged, stop, reports[role]))
        for role, forged in forgeries.items()
    ]
    run = _start(args, spawned, tmp_path / "run.err")
    for forger in forgers:
        forger.start()
    try:
        _await_router(port, run)
        viewer = _viewer(endpoint, tmp_path / "view.rrd", spawned, "--secure", str(folder))
        stdout, _ = run.communicate(timeout=RUN_TIMEOUT_S)
    finally:
        stop.set()
        for forger in forgers:
            forger.join(timeout=10)
    assert not any(forger.is_alive() for forger in forgers)
    assert run.returncode == 0, (tmp_path / "run.err").read_text()[-3000:]
    assert Path(stdout.strip()) == out
    viewer.communicate(timeout=60)
    assert viewer.returncode == 0, (tmp_path / "view.err").read_text()[-3000:]
    _seen_as_run(tmp_path / "view.rrd", out)

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["converged"] and metrics["contacts"] == 0, metrics
    # Both got in, heard the coordinator's goal sets and forged theirs while the robots were on their way
    dt = float(json.loads((out / "scene.json").read_text())["robot"]["dt"])
    for report in reports.values():
        assert "error" not in report and report["forged"] > 0 and report["genuine_goal_sets"] > 0, reports
        assert report["first_forged_tick"] * dt < metrics["time_to_converge_s"], reports
    # Every goal any robot announced is its antipode, never a forged one, and every robot reached it
    trajectory = np.load(out / "trajectory.npz")
    goals, antipodes = trajectory["goal"], -starts
    announced = np.isfinite(goals[..., 0])
    assert announced[-1].all()
    assert np.allclose(goals[announced], np.broadcast_to(antipodes, goals.shape)[announced], atol=1e-3)
    tolerance = metrics["convergence_tolerance_m"]
    assert np.all(np.hypot(*(trajectory["pose"][-1, :, :2] - antipodes).T) <= tolerance + 1e-9)


def test_bad_input_to_view_connect_is_one_line_and_exit_2(tmp_path, capsys, certs):
    old = tmp_path / "old"
    make_certificates(old, 2)
    for name in ("observer.json5", "observer.pem", "observer-key.pem"):
        (old / name).unlink()  # a folder made before the role existed
    cases = [
        (["view"], "give a RUN_DIR to replay, or --connect ENDPOINT"),
        (["view", "--connect", "banana"], "is not an endpoint"),
        (["view", "--connect", "tcp/127.0.0.1:7447", str(tmp_path)], "not both"),
        (["view", "--connect", "tls/127.0.0.1:7447", "--secure", str(old)], "made before the role existed"),
        (["view", "--connect", "tls/127.0.0.1:7447", "--secure", str(certs), "--display", "other"], "not 'other'"),
        (["view", "--connect", "tcp/127.0.0.1:7447", "--display", "a b"], "display name"),
        (["view", str(tmp_path), "--secure", str(certs)], "go with --connect"),
        (["view", "--connect", "tcp/127.0.0.1:7447", "--save", str(tmp_path / "no" / "v.rrd")], "no directory"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]


def test_no_router_at_the_endpoint_is_one_line_and_exit_2(tmp_path):
    # A port bound here and never listened on refuses connections, and no other test's router can
    # take it meanwhile (a port free_port found free once served another test's run).
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{held.getsockname()[1]}"
        result = run_pixelswarm("view", "--connect", endpoint, "--save", str(tmp_path / "v.rrd"), timeout=60)
    assert result.returncode == 2 and "pixelswarm view: error:" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not (tmp_path / "v.rrd").exists()
