"""`pixelswarm run SCENE --hardware FILE` through emulated e-puck2 robots and emulated motion capture.

Real processes, real TCP and Zenoh on 127.0.0.1: the lab (sim/emulators/lab.py) is the robots' side,
the run is the pixelswarm side, and the assertions read the emulated bodies' TRUE poses and the commands
the robots received, never what the run believed.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from agent.core.params import EPUCK, RobotParams
from coordinator.scene import load_scene, resolve_scene_path
from hardware.config import load_hardware
from hardware.epuck2 import Epuck2Config
from hardware.ros2 import TWIST, Ros2BackendConfig, Ros2PosesConfig, Ros2PoseSource
from sim.cli.main import main as cli_main
from sim.emulators.epuck2 import Epuck2Emulator
from sim.emulators.lab import MOCAP_RATE, Lab
from sim.emulators.lab import main as lab_main
from sim.emulators.mocap import MocapEmulator
from sim.node.hardware import POLL, STARTUP_TIMEOUT, TwistDrive, WheelDrive, hardware_node, wait_for_hardware
from sim.node.hardware import main as hardware_main
from tests.conftest import REPO, agent_process, descendants, pixelswarm_cmd, reap, run_pixelswarm, wait_for
from tests.support.hardware import GOALS, all_moving, moving_commands, scene_file, start_run
from transport.bus import Bus
from transport.codec import BEFORE_START, Command, Commands, Pose, Tick
from transport.session import client_of, free_port, loopback_router, open_session

TIMEOUT = Epuck2Config.command_timeout  # s: the hardware files here keep the default
PERIOD = EPUCK.dt  # s: the control period


def start_lab(tmp_path: Path, scene: Path, spawned: list) -> tuple[subprocess.Popen, str, Path, Path]:
    """The lab as its own process, embedding the router: (process, endpoint, hardware file, log file)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hw, log = tmp_path / "hw.toml", tmp_path / "lab.json"
    cmd = [sys.executable, "-m", "sim.emulators.lab", "--scene", str(scene), "-m", "router", "-l", endpoint]
    proc = subprocess.Popen(
        [*cmd, "--write-hardware", str(hw), "--log", str(log)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(proc)
    assert wait_for(lambda: hw.exists() or proc.poll() is not None, 30), "the lab wrote no hardware file"
    assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
    return proc, endpoint, hw, log


def stop_lab(proc: subprocess.Popen, log: Path) -> tuple[dict, str]:
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    return json.loads(log.read_text()), out


def assert_one_line_error(result: subprocess.CompletedProcess, words: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], result.stderr
    assert "Traceback" not in result.stderr


def in_process(main, args: list[str], capsys) -> subprocess.CompletedProcess:
    """A command's main() called here (bad input is refused before any process or socket is made)."""
    try:
        code = main(args)
    except SystemExit as exit:
        code = exit.code
    captured = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, captured.out, captured.err)


@pytest.mark.slow
@pytest.mark.wall_clock
@pytest.mark.xdist_group("emulated-hardware")
def test_a_crossing_through_emulated_robots_converges_without_contacts(tmp_path, spawned):
    scene = scene_file(tmp_path)
    lab, endpoint, hw, log = start_lab(tmp_path, scene, spawned)
    out = tmp_path / "run"
    run = run_pixelswarm(
        "run",
        str(scene),
        "--hardware",
        str(hw),
        "-e",
        endpoint,
        "--out",
        str(out),
        "--no-video",
        "--no-plots",
        "-q",
        timeout=120,
    )
    report, printed = stop_lab(lab, log)
    assert run.returncode == 0, run.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["end_reason"] == "converged"

    # Every robot within 1 cm of its goal, measured on the emulated bodies themselves.
    true_xy = np.array([robot["pose"][:2] for robot in report["robots"]])
    assert np.all(np.hypot(*(true_xy - GOALS).T) <= 0.01), true_xy
    assert report["contacts"] == [] and "contacts: 0" in printed
    assert len(report["trajectory"]["t"]) > 0

    # Commands reached every robot at about the control rate while it moved.
    for robot in report["robots"]:
        moving = moving_commands(robot["log"])
        rate = (len(moving) - 1) / (moving[-1, 0] - moving[0, 0])
        assert 8.0 <= rate <= 12.0, rate
        assert robot["log"][-1][1:] == [0, 0]  # stopped when the run ended

    # The run's per-robot hardware statistics reach metrics.json.
    robots = metrics["hardware"]["robots"]
    assert len(robots) == 4 and all(r["commands_sent"] > 0 and r["reconnects"] == 0 for r in robots)
    assert metrics["hardware"]["not_stopped_at_end"] == []
    missed = [r["missed_ticks"] for r in robots]
    assert missed == metrics["missed_ticks_by_robot"] and sum(missed) == metrics["missed_ticks"]


@pytest.mark.slow
@pytest.mark.wall_clock
@pytest.mark.xdist_group("emulated-hardware")
def test_a_killed_agent_stops_its_robot_and_the_end_of_the_run_stops_all(tmp_path, spawned):
    scene_path = scene_file(tmp_path)
    router = loopback_router()
    with Lab(load_scene(str(scene_path)), router) as lab:
        hw = tmp_path / "hw.toml"
        hw.write_text(lab.hardware_toml())
        cmd = pixelswarm_cmd("run", str(scene_path), "--hardware", str(hw), "-e", router.listen[0])
        run = subprocess.Popen(
            [*cmd, "--out", str(tmp_path / "run"), "--no-video", "--no-plots", "-q"],
            cwd=REPO,
            stderr=subprocess.PIPE,
            text=True,
        )
        spawned.append(run)
        victim = 0
        # Mid-run: the robot has been driving for a second.
        started = wait_for(lambda: len(moving_commands(lab.emulator.log(victim))) >= 10, 60)
        assert started, "the robot never moved"
        agent = agent_process(run.pid, victim)
        killed_at = time.monotonic()
        agent.kill()
        time.sleep(1.0)
        after_kill = lab.emulator.pose(victim)
        time.sleep(0.5)
        still = lab.emulator.pose(victim)
        moving_elsewhere = any(moving_commands(lab.emulator.log(r))[-1, 0] > killed_at for r in (1, 2, 3))
        if run.poll() is None:  # the others may have converged already: the run ended by itself
            run.send_signal(signal.SIGTERM)  # interrupted: every robot is stopped too
        _, err = run.communicate(timeout=60)
        logs = [np.array(lab.emulator.log(r), float) for r in range(4)]
    assert run.returncode in (0, 128 + signal.SIGTERM), err  # converged, or ended by the signal (docs/cli.md)

    log = logs[victim]
    by_then = log[log[:, 0] <= killed_at + TIMEOUT]
    assert by_then[-1, 1] == 0 and by_then[-1, 2] == 0, log[-5:]  # stopped within the timeout (0.3 s)
    later = log[log[:, 0] > killed_at + TIMEOUT]
    assert not np.any(later[:, 1:] != 0)  # and never driven again
    assert np.allclose(after_kill, still, atol=1e-9)  # the body stands still
    assert moving_elsewhere  # the other robots went on
    for other in logs:
        assert other[-1, 1] == 0 and other[-1, 2] == 0  # all stopped at the end


@pytest.mark.slow
@pytest.mark.wall_clock
@pytest.mark.xdist_group("emulated-hardware")
def test_robots_stop_while_the_pose_source_is_down_and_the_display_completes_when_it_returns(tmp_path, spawned):
    """The motion capture stops mid-run (its session closes) and restarts 1.5 s later; the router stays up."""
    scene_path = scene_file(tmp_path)
    router = loopback_router()
    with open_session(router), Lab(load_scene(str(scene_path)), client_of(router)) as lab:
        hw = tmp_path / "hw.toml"
        hw.write_text(lab.hardware_toml())
        run = start_run(tmp_path, scene_path, hw, router.listen[0], spawned)
        assert wait_for(lambda: all_moving(lab), 60), "the robots never moved"
        lab.mocap.close()
        off_at = lab.mocap.last_sent  # the last poses left then (a frame under way when close was called)
        time.sleep(1.0)
        dark = lab.true_poses()
        time.sleep(0.5)
        still = lab.true_poses()
        on_at = time.monotonic()
        lab.mocap.start()
        _, err = run.communicate(timeout=90)
        report = lab.close()
    assert run.returncode == 0, err[-3000:]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["end_reason"] == "converged"

    # the node looks at the poses once a period and stops a robot whose pose is too old at its next
    # look at safety, POLL later; the last frame reached the node within a frame's time
    stopped_by = off_at + TIMEOUT + PERIOD + POLL + 1 / MOCAP_RATE
    for robot in report["robots"]:
        log = np.array(robot["log"], float)
        by_then = log[log[:, 0] <= stopped_by]
        assert by_then[-1, 1:].tolist() == [0, 0], log[-5:]  # stopped within the timeout, a period and a poll
        while_dark = log[(log[:, 0] > by_then[-1, 0]) & (log[:, 0] < on_at)]
        assert not np.any(while_dark[:, 1:])  # and not driven blind while the poses are missing
        assert len(moving_commands(log[log[:, 0] > on_at])) > 0  # driven again once they are back
    assert np.allclose(dark, still, atol=1e-9)  # every body stands still while the pose source is down
    assert all(r["stops"]["pose_lost"] >= 1 for r in metrics["hardware"]["robots"])

    # The display completes: every robot within 1 cm of its goal by its TRUE pose, no contacts.
    true_xy = np.array([robot["pose"][:2] for robot in report["robots"]])
    assert np.all(np.hypot(*(true_xy - GOALS).T) <= 0.01), true_xy
    assert report["contacts"] == []


# Not serial: nothing it checks is on the wall clock (every robot drove, was last told to stop and
# stands still, and no process is left), whatever the load beside it.
@pytest.mark.slow
@pytest.mark.parametrize("to", ["the run", "its process group"])
def test_ctrl_c_stops_every_robot_and_leaves_no_process(tmp_path, spawned, to):
    """SIGINT to the run's process only, or to its whole process group (Ctrl-C in a terminal)."""
    scene_path = scene_file(tmp_path)
    router = loopback_router()
    with Lab(load_scene(str(scene_path)), router) as lab:
        hw = tmp_path / "hw.toml"
        hw.write_text(lab.hardware_toml())
        group = to == "its process group"
        run = start_run(tmp_path, scene_path, hw, router.listen[0], spawned, own_group=group)
        assert wait_for(lambda: all_moving(lab), 60), "the robots never moved"
        processes = [p.pid for p in descendants(run.pid)]
        assert len(processes) >= 6  # the hardware node, the coordinator, four agents
        if group:
            os.killpg(run.pid, signal.SIGINT)
        else:
            run.send_signal(signal.SIGINT)
        _, err = run.communicate(timeout=60)
        stopped = lab.true_poses()
        time.sleep(0.5)
        still = lab.true_poses()
        logs = [lab.emulator.log(r) for r in range(lab.scene.robots)]
    assert run.returncode in (0, 130), err[-3000:]
    assert all(len(moving_commands(log)) >= 10 and log[-1][1:] == (0, 0) for log in logs)  # last: a stop
    assert np.allclose(stopped, still, atol=1e-9)  # and every body stands still
    assert reap(processes) == []  # no process of the run remains


def drive(address: str, left_steps: int, right_steps: int) -> None:
    """A command packet straight to a robot, and the connection closed: the robot keeps its speeds."""
    host, port = address.rsplit(":", 1)
    packet = bytes([0x80, 0, 0]) + left_steps.to_bytes(2, "little", signed=True)
    packet += right_steps.to_bytes(2, "little", signed=True) + bytes(14)
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        sock.sendall(packet)
        sock.recv(1)  # its answer: the command was applied


def test_pixelswarm_stop_halts_moving_robots(tmp_path):
    with Epuck2Emulator(3) as emulator:
        hw = tmp_path / "hw.toml"
        hw.write_text(emulator.hardware_toml())
        for address in emulator.addresses:
            drive(address, 300, 200)
        before = [emulator.pose(r) for r in range(3)]
        result = run_pixelswarm("stop", "--hardware", str(hw), timeout=60)
        assert result.returncode == 0, result.stderr
        stopped = [emulator.pose(r) for r in range(3)]
        time.sleep(0.3)
        assert [emulator.pose(r) for r in range(3)] == stopped  # standing still
        assert all(emulator.log(r)[-1][1:] == (0, 0) for r in range(3))
        assert stopped != before  # they were moving


BACKEND = '[backend]\nkind = "epuck2"\naddresses = ["127.0.0.1:{port}"]\n'
POSES = '[poses]\nkind = "ros2"\ntopic = "/robot{id}/pose"\n'


@pytest.mark.parametrize(
    "text, words",
    [
        (None, "no such hardware file"),
        (BACKEND + "comand_timeout = 0.3\n" + POSES, "unknown key 'comand_timeout'"),
        (BACKEND, "needs a [poses] table"),
    ],
)
def test_bad_hardware_files_are_refused_in_one_line(tmp_path, capsys, text, words):
    hw = tmp_path / "hw.toml"
    if text is not None:
        hw.write_text(text.replace("{port}", "41000"))
    out = tmp_path / "run"
    result = in_process(cli_main, ["run", str(scene_file(tmp_path)), "--hardware", str(hw), "--out", str(out)], capsys)
    assert_one_line_error(result, words)
    assert not out.exists() and not out.with_name("run.partial").exists()


def test_bad_run_options_with_hardware_are_refused(tmp_path, capsys):
    hw = tmp_path / "hw.toml"
    hw.write_text(BACKEND.replace("{port}", "41000") + POSES)
    ros2 = tmp_path / "ros2.toml"
    ros2.write_text('[backend]\nkind = "ros2"\nnamespaces = ["robot0"]\n' + POSES)
    scene = str(scene_file(tmp_path))
    for args, words in [
        (["run", "circle", "--hardware", str(hw)], "holonomic"),
        (["run", scene, "--hardware", str(hw), "-n", "3"], "--robots"),
        (["run", scene, "--hardware", str(hw), "--clock", "lockstep"], "wall clock"),
        (["stop", "--hardware", str(tmp_path / "nope.toml")], "no such hardware file"),
        (["stop"], "--hardware"),
        (["stop", "--hardware", str(ros2)], "-e ENDPOINT"),
    ]:
        assert_one_line_error(in_process(cli_main, args, capsys), words)


def test_the_lab_refuses_bad_input(capsys):
    for args, words in [
        (["--scene", "no-such-scene", "-m", "router", "-l", f"tcp/127.0.0.1:{free_port()}"], "no-such-scene"),
        (["--scene", "paper-sequence"], "-e ENDPOINT"),
        (["--scene", "paper-sequence", "-e", "tcp/127.0.0.1:7447", "--rate", "0"], "--rate"),
        # the robots' ports PORT + i would pass 65535: refused before any is opened
        (["--scene", "paper-sequence", "--port", "65530", "-e", "tcp/127.0.0.1:7447"], "--port at most 65522"),
    ]:
        assert_one_line_error(in_process(lab_main, args, capsys), words)


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--robots", "3"], "takes the number of robots from the hardware file (1): drop --robots"),
        (["--clock", "lockstep"], "wall clock: drop --clock lockstep"),
    ],
)
def test_the_hardware_node_run_by_hand_refuses_what_the_hardware_file_decides(tmp_path, capsys, flags, words):
    hw = tmp_path / "hw.toml"
    hw.write_text(BACKEND.replace("{port}", "9") + POSES)
    scene = str(scene_file(tmp_path, robots=1))
    args = ["--hardware", str(hw), "--scene", scene, *flags, "-e", "tcp/127.0.0.1:9"]
    assert_one_line_error(in_process(hardware_main, args, capsys), words)


def test_pixelswarm_stop_names_a_robot_it_did_not_reach_once(tmp_path):
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    hw = tmp_path / "hw.toml"
    hw.write_text(BACKEND.replace("{port}", str(port)) + "connect_timeout = 0.2\n")
    result = run_pixelswarm("stop", "--hardware", str(hw), timeout=60)  # its own process: its logging as a user sees it
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == ["pixelswarm stop: error: robots 0 were not reached"]


def test_a_bad_hardware_file_is_refused_by_the_real_command(tmp_path):
    out = tmp_path / "run"
    args = ("run", str(scene_file(tmp_path)), "--hardware", str(tmp_path / "nope.toml"), "--out", str(out))
    assert_one_line_error(run_pixelswarm(*args, timeout=60), "no such hardware file")
    assert not out.exists() and not out.with_name("run.partial").exists()


def test_a_scene_with_a_scripted_robot_is_refused_on_hardware(tmp_path):
    """A scripted robot has no agent: its real body would be on nobody's bus and the others would drive into it."""
    scene = scene_file(tmp_path, robots=2)
    scene.write_text(scene.read_text() + "\n[[scripted]]\nrobot = 1\nwaypoints = [[0.0, 0.0, 0.0], [5.0, 0.1, 0.0]]\n")
    hw = tmp_path / "hw.toml"
    hw.write_text('[backend]\nkind = "epuck2"\naddresses = ["127.0.0.1:9", "127.0.0.1:10"]\n' + POSES)
    out = tmp_path / "run"
    result = run_pixelswarm("run", str(scene), "--hardware", str(hw), "--out", str(out), timeout=60)
    assert_one_line_error(result, "has scripted or pursuing robots, which real robots cannot run")
    assert not out.exists() and not out.with_name("run.partial").exists()


# Not serial: what it checks does not depend on the wall clock. The run is refused whatever the load
# (no motion capture, and nobody on the port); the reachable robot is an emulator on loopback, reached
# well within the start-up timeout (passed at a load average of 19 on 2 cores).
@pytest.mark.slow
def test_an_unreachable_robot_or_a_robot_without_poses_refuses_the_run(tmp_path):
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    with Epuck2Emulator(1) as emulator:
        hw = tmp_path / "hw.toml"
        addresses = f'addresses = ["{emulator.addresses[0]}", "127.0.0.1:{port}"]'
        hw.write_text(f'[backend]\nkind = "epuck2"\n{addresses}\n' + POSES)  # and no motion capture
        out = tmp_path / "run"
        result = run_pixelswarm("run", str(scene_file(tmp_path, robots=2)), "--hardware", str(hw), "--out", str(out))
        log = emulator.log(0)
    words = f"within {STARTUP_TIMEOUT:g} s, robots not reachable: 1 (127.0.0.1:{port}); no pose for robots 0, 1 (topic /robot{{id}}/pose)"
    assert_one_line_error(result, words)
    assert not out.exists() and not out.with_name("run.partial").exists()
    assert log and log[-1][1:] == (0, 0)  # the reachable robot was only ever told to stand still


def test_the_shipped_lab_file_names_the_paper_sequence_robots_on_the_labs_ports():
    config = load_hardware(REPO / "examples" / "epuck2-emulated.toml")
    with open(resolve_scene_path("paper-sequence"), "rb") as f:
        robots = tomllib.load(f)["robots"]
    # python -m sim.emulators.lab --scene paper-sequence --port 41000: robot i on port 41000 + i
    assert list(config.backend.addresses) == [f"127.0.0.1:{41000 + i}" for i in range(robots)]
    assert config.poses.topic == Ros2PosesConfig.topic  # where the lab's motion capture publishes


# Its bounds are wall-clock (a timeout plus a period): alone on the machine, as a robot's node runs.
@pytest.mark.slow
@pytest.mark.wall_clock
@pytest.mark.xdist_group("emulated-hardware")
def test_the_hardware_node_stops_a_robot_whose_pose_is_lost_or_whose_commands_cease(tmp_path):
    """The node between real parts: emulated robots over TCP, motion capture over rmw_zenoh, and this test
    in the agents' place (liveliness tokens, a command per tick)."""
    router = loopback_router()
    client = client_of(router)
    scene = load_scene(str(scene_file(tmp_path, robots=2, duration=60.0)), clock="realtime")
    lost = threading.Event()  # robot 1 out of the motion capture's sight
    with Bus(router, name="agents") as agents, Epuck2Emulator(2, poses=[(0, 0, 0), (0, 0.5, 0)]) as emulator:

        def mocap(t: float) -> np.ndarray:
            rows = np.array([emulator.pose(r) for r in range(2)])
            rows[1] = np.nan if lost.is_set() else rows[1]  # a lost body: NaN, as mocap drivers send
            return rows

        hw = tmp_path / "hw.toml"
        hw.write_text(emulator.hardware_toml() + POSES)
        config = load_hardware(hw)
        with MocapEmulator(mocap, client, rate=MOCAP_RATE), Bus(client, name="hardware") as node_bus:
            drive = WheelDrive(config.backend, RobotParams.from_dict(scene.robot))
            poses = Ros2PoseSource(config.poses, client)
            node = hardware_node(node_bus, scene, drive, poses, timeout=TIMEOUT)
            runner = threading.Thread(target=node.run)
            last_tick = [0]
            try:
                drive.start()
                poses.start()
                assert wait_for_hardware(node, 10.0) is None
                runner.start()
                ticks = agents.subscribe(agents.keys.clock, Tick)
                seen_1 = agents.subscribe(agents.keys.pose(1), Pose)
                for robot in (0, 1):
                    agents.declare_alive("agent", robot)

                def drive_for(seconds: float, robots: tuple[int, ...]) -> None:
                    end = time.monotonic() + seconds
                    while time.monotonic() < end:
                        got = ticks.get(timeout=0.2)
                        for robot in robots if got is not None else ():
                            tick = last_tick[0] = got[1].tick
                            stamp = got[1].stamp  # an agent answers a tick with its stamp
                            agents.publish(
                                agents.keys.cmd(robot),
                                Commands.one(Command(robot, tick, stamp, 1, 0.05, 0.05, 0, 0, 0)),
                            )

                drive_for(1.5, (0, 1))
                lost.set()
                lost_at, lost_tick = time.monotonic(), last_tick[0]
                drive_for(1.5, (0, 1))  # robot 1 is still commanded, but out of sight
                quiet_at = time.monotonic()
                time.sleep(1.0)  # and now robot 0's commands cease
            finally:
                node.running = False
                if runner.is_alive():
                    runner.join(timeout=30)
                unreached = drive.close()
                poses.close()
        logs = [np.array(emulator.log(r), float) for r in range(2)]
        shown_1 = [pose.tick for _, pose in seen_1.drain() if pose.tick != BEFORE_START]
    stats = node.stats()["hardware"]["robots"]

    # Robot 1: stopped once its pose was older than the timeout (plus a period, the node's next look at
    # safety POLL later, and a mocap frame) ...
    log = logs[1]
    by_then = log[log[:, 0] <= lost_at + TIMEOUT + PERIOD + POLL + 1 / MOCAP_RATE]
    assert by_then[-1, 1:].tolist() == [0, 0] and len(moving_commands(by_then)) > 5
    assert not np.any(log[log[:, 0] > by_then[-1, 0], 1:])  # ... and never driven blind
    assert stats[1]["stops"]["pose_lost"] == 1
    # Its agent heard its pose until it was lost, then no more (so it waits).
    assert shown_1 and max(shown_1) <= lost_tick + round((TIMEOUT + PERIOD) / PERIOD) + 1 < last_tick[0]
    # Robot 0: stopped when its commands ceased for the timeout.
    log = logs[0]
    assert len(moving_commands(log[log[:, 0] > lost_at])) > 5  # it went on while robot 1 was lost
    by_then = log[log[:, 0] <= quiet_at + TIMEOUT + PERIOD + POLL]
    assert by_then[-1, 1:].tolist() == [0, 0]
    assert stats[0]["stops"]["command_timeout"] == 1
    assert unreached == []


def test_a_ros2_backend_gets_wheel_speeds_as_a_body_velocity():
    """v = (l + r) / 2 along x and omega = (r - l) / wheel base about z, as Twist on rmw_zenoh."""
    router = loopback_router()
    config = Ros2BackendConfig(namespaces=["robot0", "robot1"])
    twists: list[bytes] = []

    def twist(k: int):  # a Twist received, decoded
        return get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(twists[k], TWIST)

    with open_session(router) as observer:
        observer.declare_subscriber("0/robot1/cmd_vel/**", lambda sample: twists.append(sample.payload.to_bytes()))
        drive = TwistDrive(config, client_of(router), EPUCK)
        drive.start()
        try:
            assert wait_for(lambda: drive.send([1], np.array([0.04]), np.array([0.06]), np.zeros((1, 3))) or twists, 10)
        finally:
            drive.close()  # a zero Twist to every robot
        # sent before close returns, it may still be on the router's side of the link (one run in 30 under load)
        wait_for(lambda: twist(-1).linear.x == 0, 5)
    first, last = twist(0), twist(-1)
    assert first.linear.x == pytest.approx(0.05) and first.angular.z == pytest.approx(0.02 / EPUCK.wheel_base)
    assert (first.linear.y, first.linear.z, first.angular.x, first.angular.y) == (0, 0, 0, 0)
    assert last.linear.x == 0 and last.angular.z == 0


def test_a_hardware_file_can_name_the_simulator(tmp_path):
    """`[backend] kind = "sim"`: the same run on the simulated world, so one command line serves both."""
    hw = tmp_path / "sim.toml"
    hw.write_text('[backend]\nkind = "sim"\n')
    out = tmp_path / "run"
    result = run_pixelswarm(
        "run",
        "circle",
        "--robots",
        "4",
        "--hardware",
        str(hw),
        "--duration",
        "1",
        "--no-video",
        "--no-plots",
        "-q",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["engine"] == "distributed" and metrics["robots"] == 4 and "hardware" not in metrics


def test_pixelswarm_stop_of_simulated_robots_says_there_is_nothing_to_stop(tmp_path):
    """It said it had stopped every robot of a file whose robots are simulated."""
    hw = tmp_path / "sim.toml"
    hw.write_text('[backend]\nkind = "sim"\n')
    result = run_pixelswarm("stop", "--hardware", str(hw), timeout=60)
    assert result.returncode == 0 and result.stdout.strip() == f"{hw}: simulated robots: nothing to stop", result
