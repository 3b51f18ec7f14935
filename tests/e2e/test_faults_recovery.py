"""Faults injected mid-show, each with its safe behaviour and recovery (docs/faults.md): real
`pixelswarm run` processes over zenoh on loopback, zero contacts in every run."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from mcap.exceptions import McapError

from sim.outputs.mcaplog import McapLog, read_mcap
from sim.outputs.ticklog import TICKS_FILE, TickLog, read_ticks
from tests.conftest import REPO, descendants, pixelswarm_cmd, reap, start_run, ticks_so_far, wait_for, write_disk
from tests.support.outputs import log_json
from transport.session import free_port

TOLERANCE = 0.01  # m: the show completes when every robot is this close to its goal at the end


def flushed_stamps(out: Path) -> int:
    """How many /sim/truth messages of the log written so far mcap's reader sees (flushed once a second)."""
    try:
        return len(read_mcap(Path(str(out) + ".partial") / "log.mcap", topics=["/sim/truth"]).get("/sim/truth", []))
    except (OSError, ValueError, McapError):  # not created yet, or its first bytes only
        return 0


def driving(out: Path) -> int:
    """How many robots drove, at the last tick recorded so far, as the router test needs them."""
    try:
        ticks = read_ticks(Path(str(out) + ".partial") / TICKS_FILE)
    except (OSError, ValueError):
        return 0
    if not len(ticks["t"]):
        return 0
    speed = np.hypot(*ticks["velocity"][-1].T)
    to_goal = np.hypot(*(ticks["pose"][-1, :, :2] - ticks["goal"][-1]).T)
    return int(((speed > 0.05) & (to_goal > 0.1)).sum())


def alive(pids: list[int]) -> list[int]:
    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def test_a_torn_tick_file_reads_up_to_its_last_whole_tick(tmp_path):
    log = TickLog(tmp_path / TICKS_FILE, robots=3)
    rng = np.random.default_rng(0)
    for k in range(5):
        pose = rng.normal(size=(3, 3))
        log.append(k * 0.1, 100.0 + k, (pose, pose[:, :2], np.full((3, 3), 7), np.full((3, 2), np.nan), np.arange(3)))
    log.close()
    path = tmp_path / TICKS_FILE
    path.write_bytes(path.read_bytes()[:-10])  # killed in the middle of the fifth record
    ticks = read_ticks(path)
    assert ticks["t"].tolist() == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert ticks["pose"].shape == (4, 3, 3) and ticks["color"].dtype == np.uint8
    assert np.isnan(ticks["goal"]).all() and ticks["assignment"][-1].tolist() == [0, 1, 2]
    (tmp_path / "other").write_bytes(b"not a tick file")
    with pytest.raises(ValueError, match="not a pixelswarm tick file"):
        read_ticks(tmp_path / "other")


def test_an_mcap_log_never_closed_reads_up_to_its_last_flush(tmp_path):
    log = McapLog(tmp_path / "log.mcap")
    channel = log.add_channel("/n", "N", {"type": "object"})
    for k in range(10):
        log_json(log, channel, k, {"k": k})
    log.flush()
    for k in range(10, 15):
        log_json(log, channel, k, {"k": k})  # the chunk in progress when the writer dies
    # no close: as a process killed outright leaves it
    assert [m["k"] for m in read_mcap(tmp_path / "log.mcap")["/n"]] == list(range(10))
    log.close()
    assert [m["k"] for m in read_mcap(tmp_path / "log.mcap")["/n"]] == list(range(15))


@pytest.mark.slow
def test_sigkill_of_the_launcher_leaves_no_process_and_a_readable_partial_run(tmp_path, spawned):
    scene = write_disk(tmp_path, hold=120.0)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out)

    # lock-step may run 30 ticks within a second of wall time: wait for a flush that holds ten of them too
    def started() -> bool:
        return ticks_so_far(out) >= 30 and flushed_stamps(out) >= 10

    assert wait_for(started, timeout=120), proc.stderr.read() if proc.poll() else ""
    everyone = [p.pid for p in descendants(proc.pid)]
    assert len(everyone) >= 12  # coordinator, world, 10 agents
    partial = Path(str(out) + ".partial")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    seen = read_ticks(partial / TICKS_FILE)["t"]  # the launcher is gone: nothing is appended any more
    # every process it started goes too (they watch their parent)
    assert wait_for(lambda: not alive(everyone), timeout=15), alive(everyone)
    assert not reap(everyone)
    assert not out.exists()  # never committed: the directory's name says it is incomplete
    # the trajectory holds every tick up to the kill, one after another
    ticks = read_ticks(partial / TICKS_FILE)
    assert len(ticks["t"]) == len(seen) >= 30
    assert ticks["t"][0] == 0.0
    np.testing.assert_allclose(np.diff(ticks["t"]), 0.1, atol=1e-9)
    assert ticks["pose"].shape == (len(seen), 10, 3) and np.isfinite(ticks["pose"]).all()
    # the MCAP log, never closed, is read by mcap's reader up to its last flushed chunk (once a second)
    log = read_mcap(partial / "log.mcap", topics=["/sim/truth"])
    stamps = [m["stamp"] for m in log["/sim/truth"]]
    assert len(stamps) >= 10 and stamps == sorted(stamps)
    assert stamps[-1] <= ticks["t"][-1] + 1e-9
    assert json.dumps(log["/sim/truth"][0])  # decoded messages


THREE_STEPS = """
name = "faults"
robots = 10
seed = 5
clock = "lockstep"
[layout]
kind = "grid"
spacing = 0.2
[[steps]]
shape = "disk"
hold = 10.0
[[steps]]
shape = "line"
hold = 30.0
[[steps]]
shape = "disk"
hold = 20.0
[end]
converge_hold = 2.0
"""


def process_of(proc: subprocess.Popen, module: str) -> psutil.Process | None:
    for p in descendants(proc.pid):
        try:
            if module in p.cmdline():
                return p
        except psutil.Error:
            pass
    return None


def finish(proc: subprocess.Popen, out: Path, timeout: float = 240) -> tuple[dict, dict]:
    _, stderr = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, stderr[-3000:]
    return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))


def assert_show_completed(traj: dict, robots: np.ndarray | None = None) -> None:
    """Every robot (of ``robots``) on a goal of the newest goal set, within TOLERANCE, at the end."""
    robots = np.arange(traj["pose"].shape[1]) if robots is None else robots
    err = np.hypot(*(traj["pose"][-1, robots, :2] - traj["goal"][-1, robots]).T)
    assert (traj["assignment_epoch"][-1, robots] == traj["goal_set_epochs"][-1]).all()
    assert np.all(err <= TOLERANCE), np.round(err * 1000).astype(int).tolist()


@pytest.mark.slow
def test_a_killed_coordinator_is_restarted_and_goes_on_with_the_show(tmp_path, spawned):
    scene = tmp_path / "three.toml"
    scene.write_text(THREE_STEPS)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out, "-k", "5")  # two agent hosts: the coordinator is what dies here
    # into the second image: a coordinator takes seconds to start on a loaded machine, and a lock-step
    # display does not wait for it (the robots hold the image they have meanwhile)
    assert wait_for(lambda: ticks_so_far(out) >= 120, timeout=120)
    coordinator = process_of(proc, "coordinator.service")
    assert coordinator is not None
    coordinator.send_signal(signal.SIGKILL)
    m, traj = finish(proc, out)
    assert m["contacts"] == 0
    assert [r["process"] for r in m["restarts"]] == ["coordinator"]
    # the new coordinator went on from the run's goal set: one epoch per image, not the show over
    assert traj["goal_set_epochs"].tolist() == [1, 2, 3] and traj["goal_set_steps"].tolist() == [0, 1, 2]
    published: dict[int, set] = {}
    for g in read_mcap(out / "log.mcap", topics=["/goals"])["/goals"]:
        published.setdefault(g["epoch"], set()).add(
            (g["timing"]["step"], g["timing"]["stamp"], json.dumps(g["positions"]))
        )
    assert all(len(versions) == 1 for versions in published.values()), "a goal set was published twice, changed"
    assert m["end_reason"] == "converged"
    assert_show_completed(traj)


OUTAGE_AT, OUTAGE = 3.0, 2.0  # s: the tracker sends no pose from 3 s (robots on their way) for 2 s


@pytest.mark.slow
def test_robots_stop_during_a_tracker_outage_and_resume(tmp_path, spawned):
    events = f'[[events]]\nkind = "tracker-outage"\nt = {OUTAGE_AT}\nduration = {OUTAGE}'
    scene = write_disk(tmp_path, hold=30.0, converge_hold=2.0, events=events)
    out = tmp_path / "run"
    # two agent hosts: the outage is the world's (a lock-step run is the same run in every engine)
    m, traj = finish(start_run(spawned, scene, out, "-k", "5"), out)
    assert m["contacts"] == 0
    assert m["withheld_ticks"] == round(OUTAGE / 0.1)
    t, pose, velocity = traj["t"], traj["pose"][:, :, :2], traj["velocity"]
    speed = np.hypot(*velocity.transpose(2, 0, 1))
    before = np.flatnonzero(t < OUTAGE_AT - 1e-9)[-1]
    assert speed[before].max() > 0.01  # they were on their way
    # blind, every robot stops once its last command runs out: one period and command_margin
    stopped = np.flatnonzero((t >= OUTAGE_AT + 0.1 + 0.05 + 0.1 - 1e-9) & (t <= OUTAGE_AT + OUTAGE + 1e-9))
    assert len(stopped) >= 15
    assert speed[stopped].max() == 0.0, np.round(speed[stopped].max(axis=1), 3).tolist()
    assert np.array_equal(pose[stopped[0]], pose[stopped[-1]])
    # ... and resume once the poses are back: each robot not yet within TOLERANCE of its goal drives
    # at least as far as it takes to get there (one that has arrived stands: a unicycle at its goal stops)
    away = np.hypot(*(traj["goal"][-1] - pose[stopped[-1]]).T)  # the goals of the one image, as at the end
    moved = np.hypot(*(pose[-1] - pose[stopped[-1]]).T)
    assert (away > TOLERANCE).any(), np.round(away, 4).tolist()
    assert np.all(moved[away > TOLERANCE] >= away[away > TOLERANCE] - TOLERANCE), (away.tolist(), moved.tolist())
    assert m["end_reason"] == "converged"
    assert_show_completed(traj)


KILL_AT = 6.0  # s: the disk of ten forms in about 4 s (converged_at 3.7 s in this seed's run)


@pytest.mark.slow
def test_a_tenth_of_the_agents_killed_at_once_and_the_rest_form_the_image_for_the_survivors(tmp_path, spawned):
    # converge_hold: longer than from the disk of ten formed to the kill, so the run ends only after
    # the nine hold theirs
    scene = write_disk(
        tmp_path, hold=30.0, converge_hold=4.0, events=f'[[events]]\nkind = "fail"\nt = {KILL_AT}\nrobot = 6'
    )
    out = tmp_path / "run"
    m, traj = finish(start_run(spawned, scene, out), out)
    assert m["contacts"] == 0 and len(m["agents_failed_by_scene"]) == 1
    survivors = np.flatnonzero(np.arange(10) != 6)
    assert traj["goal_set_robots"][-1].tolist() == [r != 6 for r in range(10)]  # paper 5.1.2: the set for nine
    t = traj["t"]
    err = np.hypot(*(traj["pose"][:, survivors, :2] - traj["goal"][:, survivors]).T).T
    newest = (traj["assignment_epoch"][:, survivors] == traj["goal_set_epochs"][-1]).all(axis=1)
    formed = np.flatnonzero(newest & (err <= TOLERANCE).all(axis=1) & (t >= KILL_AT))
    assert len(formed) and t[formed[0]] - KILL_AT <= 10.0
    assert m["end_reason"] == "converged"
    assert_show_completed(traj, survivors)


ROUTER_DOWN = 2.0  # s of wall time the standalone router is gone


@pytest.mark.slow
@pytest.mark.serial
def test_a_router_killed_and_restarted_every_component_reconnects_and_the_show_completes(tmp_path, spawned):
    endpoint = f"tcp/127.0.0.1:{free_port()}"

    def router() -> subprocess.Popen:
        proc = subprocess.Popen(pixelswarm_cmd("router", "-l", endpoint), cwd=REPO, stdout=subprocess.PIPE, text=True)
        spawned.append(proc)
        assert proc.stdout is not None and "listening" in proc.stdout.readline()
        return proc

    first = router()
    # real time: the world goes on while the router is gone (a lock-step world would wait for it).
    # The run ends 3 s after the ten hold the disk again: no robot is lost, so the disk is formed only
    # after the router is back, and what is checked is that it forms, not for how long it is held.
    # Spaced 0.4 m, three robots drive at once for about 3 s (at 0.2 m, for half a second: missed once)
    scene = write_disk(tmp_path, clock="realtime", hold=20.0, converge_hold=3.0, spacing=0.4)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out, "-e", endpoint)
    assert wait_for(lambda: driving(out) >= 3, timeout=120)  # on their way to the disk
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=10)
    time.sleep(ROUTER_DOWN)
    second = router()
    try:
        m, traj = finish(proc, out)
    finally:
        second.send_signal(signal.SIGINT)
        second.wait(timeout=20)
    assert m["contacts"] == 0 and m["agents_crashed"] == 0
    assert len(m["liveliness_lost"]) == 10  # every agent was cut off ...
    assert traj["goal_set_epochs"].tolist() == [1]  # ... and came back to the same show
    # The recorder is cut off too: the ticks on either side of the gap. Robots that drove on, blind,
    # for the router's ROUTER_DOWN seconds would have moved on by far more than robots that stopped.
    t, pose = traj["t"], traj["pose"][:, :, :2]
    gap = int(np.argmax(np.diff(t)))
    assert t[gap + 1] - t[gap] >= ROUTER_DOWN
    speed = np.hypot(*traj["velocity"][gap].T)
    to_goal = np.hypot(*(pose[gap] - traj["goal"][gap]).T)
    moving = (speed > 0.03) & (to_goal > 0.06)  # driving on, they would have moved 6 cm or more
    assert moving.sum() >= 2, (np.round(speed, 3).tolist(), np.round(to_goal, 3).tolist())
    moved = np.hypot(*(pose[gap + 1] - pose[gap]).T)
    assert moved[moving].max() <= 0.03, np.round(moved, 3).tolist()  # v_max x (dt + command_margin), and noise
    assert_show_completed(traj)


@pytest.mark.slow
def test_a_world_that_dies_ends_the_run_marked_incomplete(tmp_path, spawned):
    scene = write_disk(tmp_path, hold=60.0)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out, "-k", "5")  # two agent hosts: the world is what dies here
    assert wait_for(lambda: ticks_so_far(out) >= 20, timeout=120)
    everyone = [p.pid for p in descendants(proc.pid)]
    world = process_of(proc, "sim.node.world")
    assert world is not None
    world.send_signal(signal.SIGKILL)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "the world process exited with code -9" in stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["complete"] is False and m["end_reason"] == "world exited with code -9"
    assert len(np.load(out / "trajectory.npz")["t"]) >= 20  # what was recorded up to then
    assert wait_for(lambda: not alive(everyone), timeout=15)


def test_the_coordinator_has_the_set_for_one_robot_fewer_ready_before_any_dies(monkeypatch):
    """The survivors' goal set is made while the image is held, not when a robot dies: making the
    first set in the coordinator loads the image pipeline, seconds on a loaded machine, in which a
    lock-step world ran on for seconds of display without a goal set for the survivors."""
    from coordinator import service
    from coordinator.scene import scene_from_dict
    from coordinator.steps import StepGoals
    from tests.support.fake_bus import Bus
    from transport.codec import Tick

    made = []
    generate = StepGoals._generate
    monkeypatch.setattr(StepGoals, "_generate", lambda self, k, n, arena: made.append(n) or generate(self, k, n, arena))
    monkeypatch.setattr(service, "SETTLE_S", 0.0)
    scene = scene_from_dict(
        {"robots": 6, "seed": 5, "layout": {"kind": "grid", "spacing": 0.2}, "steps": [{"shape": "disk", "hold": 30}]}
    )
    bus = Bus()
    coordinator = service.Coordinator(bus, scene)
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in range(6)]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    assert coordinator._follow_show() and len(bus.published[-1].robots) == 6
    coordinator._prepare_for_a_loss()
    assert made[-1:] == [5]
    before = len(made)
    bus.alive.items = [("agent", "2", False, 0.0, "a")]
    coordinator.bodies.positions[2] = np.array([0.0, 0.0])  # its body's tracked position has come
    bus.clock.items = [("clock", Tick(10, 1.0, 0.1))]
    assert coordinator._follow_show()
    assert bus.published[-1].robots.tolist() == [0, 1, 3, 4, 5]
    assert len(made) == before, "the survivors' goal set was made when the robot died"
