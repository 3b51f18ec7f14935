"""The e-puck2 Wi-Fi backend against emulated robots on 127.0.0.1: packets as GCtronic documents them,
motion, reconnection, the safety stops, and the hardware file."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from agent.core.params import EPUCK
from hardware import config as hwconfig
from hardware.config import HardwareConfigError, SimBackendConfig, load_hardware
from hardware.epuck2 import (
    FIRMWARE_MAX_WHEEL_SPEED,
    Command,
    Epuck2Backend,
    Epuck2Config,
    RobotLink,
    encode_command,
    make_command,
    motor_steps,
)
from hardware.stop import stop_all
from sim.emulators.epuck2 import Epuck2Emulator, parse_command
from sim.emulators.epuck2 import main as emulator_main
from sim.node.hardware import WheelDrive
from tests.conftest import REPO, wait_for

WHEEL_BASE = 0.0525  # the paper's e-puck (Table 1), as the emulator drives it
PERIOD = 0.1  # the paper's control period


@pytest.fixture(autouse=True)
def no_link_or_server_thread_left():
    yield
    left = [t.name for t in threading.enumerate() if t.name.startswith("epuck2")]
    assert not left, f"threads left running: {left}"


# --- packets ---------------------------------------------------------------------------------------------
OFF = [0, 0, 0] * 4


def packet(request, settings, left_lsb, left_msb, right_lsb, right_msb, leds, rgb, speaker):
    return bytes([0x80, request, settings, left_lsb, left_msb, right_lsb, right_msb, leds, *rgb, speaker])


@pytest.mark.parametrize(
    "command, expected",
    [
        # at rest, everything off
        (Command(), packet(0, 0, 0x00, 0x00, 0x00, 0x00, 0, OFF, 0)),
        # 0.05 m/s = 388.18 steps/s; red 255 -> 100, blue 128 -> 50 on LED2, LED4, LED6, LED8
        (
            make_command(0.05, -0.05, (255, 0, 128), FIRMWARE_MAX_WHEEL_SPEED),
            packet(0, 0, 0x84, 0x01, 0x7C, 0xFE, 0, [100, 0, 50] * 4, 0),
        ),
        # clipped to the firmware's 1100 steps/s
        (
            make_command(1.0, -1.0, (0, 255, 0), FIRMWARE_MAX_WHEEL_SPEED),
            packet(0, 0, 0x4C, 0x04, 0xB4, 0xFB, 0, [0, 100, 0] * 4, 0),
        ),
        # clipped to a smaller limit (the paper's e-puck: 0.13 m/s = 1009.28 steps/s); colour clipped to 0-255
        (
            make_command(-0.5, 0.2, (300, -5, 200), 0.13),
            packet(0, 0, 0x0F, 0xFC, 0xF1, 0x03, 0, [100, 0, 78] * 4, 0),
        ),
        # a speed that is not a number does not move the robot
        (make_command(float("nan"), float("inf"), (0, 0, 0), 0.13), packet(0, 0, 0, 0, 0, 0, 0, OFF, 0)),
        # every field: sensors requested, LED1 + body LED, one RGB LED each, speaker
        (
            Command(
                left=-1, right=256, rgb=((1, 2, 3), (4, 5, 6), (7, 8, 9), (10, 11, 12)), leds=0x11, request=2, speaker=1
            ),
            packet(2, 0, 0xFF, 0xFF, 0x00, 0x01, 0x11, [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12], 1),
        ),
    ],
)
def test_command_packets_are_the_documented_bytes(command, expected):
    assert len(expected) == 21
    assert encode_command(command) == expected
    # the emulator reads the same packet back field by field
    read = parse_command(expected)
    assert (read.left, read.right, read.leds, read.request, read.speaker) == (
        command.left,
        command.right,
        command.leds,
        command.request,
        command.speaker,
    )
    assert read.rgb == command.rgb


# --- the emulator alone: motion --------------------------------------------------------------------------
def steps(n: int) -> bytes:
    return n.to_bytes(2, "little", signed=True)


def drive(sock: socket.socket, left: int, right: int) -> None:
    sock.sendall(bytes([0x80, 0, 0]) + steps(left) + steps(right) + bytes(14))
    assert sock.recv(1) == b"\x03"  # nothing requested: the robot acknowledges with an empty answer


def mps(steps_per_s: int) -> float:
    return steps_per_s / 1000 * math.pi * 0.041


def test_emulated_robot_moves_as_differential_drive_kinematics_says():
    with Epuck2Emulator(3, poses=[(0, 0, 0), (1, 1, math.pi / 2), (0, 1, 0)]) as emu:
        socks = [socket.create_connection(("127.0.0.1", int(a.rsplit(":", 1)[1])), timeout=2) for a in emu.addresses]
        try:
            commands = [(400, 400), (-300, 300), (2000, 2000)]  # straight, spin in place, beyond the speed limit
            for sock, (left, right) in zip(socks, commands):
                drive(sock, left, right)
            time.sleep(0.3)
            for sock in socks:
                drive(sock, 0, 0)
        finally:
            for sock in socks:
                sock.close()
        (t0, *_), (t1, *_) = emu.log(0)
        x, y, theta = emu.pose(0)
        assert (x, y, theta) == pytest.approx((mps(400) * (t1 - t0), 0, 0), abs=1e-9)

        (t0, *_), (t1, *_) = emu.log(1)
        x, y, theta = emu.pose(1)
        turned = 2 * mps(300) / WHEEL_BASE * (t1 - t0)
        assert (x, y, theta) == pytest.approx((1, 1, math.pi / 2 + turned), abs=1e-9)

        (t0, *_), (t1, *_) = emu.log(2)
        assert emu.pose(2) == pytest.approx((0.13 * (t1 - t0), 1, 0), abs=1e-9)  # the paper's v_max


def test_emulated_robot_arcs_and_keeps_its_speed_after_the_connection_closes():
    with Epuck2Emulator(1) as emu:
        with socket.create_connection(("127.0.0.1", int(emu.addresses[0].rsplit(":", 1)[1])), timeout=2) as sock:
            drive(sock, 200, 600)
        first = emu.pose(0)
        time.sleep(0.2)
        x, y, theta = emu.pose(0)  # nobody told it to stop: it goes on turning
        ((t0, *_),) = emu.log(0)
        left, right = mps(200), mps(600)
        omega, r = (right - left) / WHEEL_BASE, WHEEL_BASE / 2 * (right + left) / (right - left)
        # an arc of radius r about (0, r), starting at the origin facing +x
        assert (x, y) == pytest.approx((r * math.sin(theta), r - r * math.cos(theta)), abs=1e-9)
        assert theta > first[2] > 0
        assert theta == pytest.approx(omega * (emu.robots[0].since - t0), abs=1e-9)


def test_emulator_answers_sensor_requests_with_the_motor_steps():
    with Epuck2Emulator(1) as emu:
        with socket.create_connection(("127.0.0.1", int(emu.addresses[0].rsplit(":", 1)[1])), timeout=2) as sock:
            drive(sock, 500, -500)
            time.sleep(0.1)
            sock.sendall(bytes([0x80, 0x02, 0]) + bytes(18))  # request the sensors, wheels at rest
            answer = b""
            while len(answer) < 105:
                answer += sock.recv(105 - len(answer))
        (t0, *_), (t1, *_) = emu.log(0)
        assert answer[0] == 0x02
        left = int.from_bytes(answer[1 + 79 : 1 + 81], "little", signed=True)
        right = int.from_bytes(answer[1 + 81 : 1 + 83], "little", signed=True)
        assert (left, right) == (round(500 * (t1 - t0)), round(-500 * (t1 - t0)))


# --- the backend against the emulator --------------------------------------------------------------------
def backend_for(emu: Epuck2Emulator, **keys) -> Epuck2Backend:
    return Epuck2Backend(Epuck2Config.from_table({"kind": "epuck2", "addresses": emu.addresses, **keys}, "test"))


def command_periods(backend: Epuck2Backend, periods: int, left=0.05, right=0.05, colour=(255, 0, 128)) -> float:
    """Commands for every robot once per control period; returns the time of the last call."""
    ids = backend.robot_ids
    last = time.monotonic()
    for _ in range(periods):
        last = time.monotonic()
        backend.set_commands(ids, [left] * len(ids), [right] * len(ids), [colour] * len(ids))
        time.sleep(PERIOD)
    return last


def test_backend_reads_the_sensors_it_requests():
    with Epuck2Emulator(1) as emu, backend_for(emu, request_sensors=True) as backend:
        command_periods(backend, 3, left=0.05, right=-0.05)
        assert wait_for(lambda: backend.sensors(0) is not None and motor_steps(backend.sensors(0))[0] > 0, timeout=3)
        left, right = motor_steps(backend.sensors(0))
        assert left == -right


def test_backend_reconnects_when_the_robot_drops_the_connection():
    with Epuck2Emulator(2) as emu, backend_for(emu) as backend:
        command_periods(backend, 3)
        emu.drop_connection(0)
        reconnected = wait_for(
            lambda: command_periods(backend, 1) and emu.connections(0) == 2 and emu.log(0)[-1][1] == 388, timeout=5
        )
        assert reconnected
        stats = backend.stats()
        assert stats[0].reconnects == 1 and stats[0].connected
        assert stats[1].reconnects == 0
        assert emu.robots[0].rgb == ((100, 0, 50),) * 4


def test_watchdog_stops_a_robot_whose_commands_cease():
    with Epuck2Emulator(2) as emu, backend_for(emu, command_timeout=0.3) as backend:
        last_call = command_periods(backend, 5)
        # while commands flow, nothing stops the robots
        assert all(left == 388 for _, left, _ in emu.log(0)[1:])  # [0] is the stop sent on connecting
        assert wait_for(lambda: all(emu.log(r)[-1][1:] == (0, 0) for r in range(2)), timeout=3)
        for rid in range(2):
            stop_time = emu.log(rid)[-1][0]
            assert stop_time - last_call <= 0.3 + PERIOD
            assert backend.stats()[rid].watchdog_stops == 1
        resting = emu.pose(0)
        time.sleep(0.05)
        assert emu.pose(0) == resting


def test_close_sends_stops():
    with Epuck2Emulator(3) as emu:
        backend = backend_for(emu)
        backend.start()
        command_periods(backend, 2)
        assert wait_for(lambda: all(emu.log(r)[-1][1] == 388 for r in range(3)), timeout=3)
        assert backend.close() == []
        assert wait_for(lambda: all(emu.log(r)[-1][1:] == (0, 0) for r in range(3)), timeout=3)
        assert all(not s.connected for s in backend.stats().values())


def test_stop_all_waits_until_the_stops_are_sent_and_names_robots_out_of_reach(tmp_path):
    with socket.socket() as placeholder:  # a port on 127.0.0.1 where no robot listens
        placeholder.bind(("127.0.0.1", 0))
        absent = f"127.0.0.1:{placeholder.getsockname()[1]}"
    with Epuck2Emulator(1) as emu:
        config = Epuck2Config.from_table({"addresses": [emu.addresses[0], absent], "connect_timeout": 0.2}, "test")
        backend = Epuck2Backend(config)
        backend.start()
        command_periods(backend, 3)
        assert backend.stats()[1].late_commands == 2  # never sent: each replaced by the next
        assert backend.stop_all() == [1]
        assert wait_for(lambda: emu.log(0)[-1][1:] == (0, 0), timeout=3)
        assert backend.close() == [1]


class WrongProtocol:
    """A TCP server on 127.0.0.1 that is no e-puck2: per connection it answers as ``speak`` says (an HTTP
    error, an echo, or nothing) and then closes, or keeps silent with the connection open."""

    def __init__(self, speak: str) -> None:
        self.speak, self.accepted = speak, 0
        self.server = socket.create_server(("127.0.0.1", 0))
        self.address = f"127.0.0.1:{self.server.getsockname()[1]}"
        self.open: list[socket.socket] = []
        self.thread = threading.Thread(target=self._serve, name="wrong-protocol", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = self.server.accept()
                self.accepted += 1
                self.open.append(conn)
                if self.speak == "silent":
                    continue
                with contextlib.suppress(OSError):
                    data = conn.recv(64)
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n" if self.speak == "http" else data)
                conn.close()

    def close(self) -> None:
        self.server.shutdown(socket.SHUT_RDWR)
        self.server.close()
        self.thread.join(timeout=5)
        for conn in self.open:
            conn.close()


@pytest.mark.parametrize("speak", ["http", "echo", "silent"])
def test_an_address_that_does_not_answer_as_an_e_puck2_is_no_robot_and_is_not_hammered(speak):
    """Something listening at a robot's address (a web server at a mistyped port) is not a robot: the
    link waits out its backoff between attempts, start-up counts the robot unreached, and a stop
    it was sent is not counted as having reached a robot."""
    impostor = WrongProtocol(speak)
    config = Epuck2Config.from_table({"addresses": [impostor.address], "connect_timeout": 0.2}, "test")
    drive = WheelDrive(config, EPUCK)
    try:
        drive.start()
        time.sleep(1.0)
        # backoff 0.1 s doubling to 2 s: a handful of attempts a second, not thousands
        assert 1 <= impostor.accepted <= 6
        assert drive.unreached() == [0]
        assert "does not answer as an e-puck2" in drive.why_unreached(0)
        assert drive.backend.stop_all() == [0]
    finally:
        assert drive.close() == [0]
        impostor.close()


def test_a_robot_that_answers_is_reached_and_its_stop_confirmed():
    with Epuck2Emulator(1) as emu:
        drive = WheelDrive(Epuck2Config.from_table({"addresses": emu.addresses}, "test"), EPUCK)
        drive.start()
        assert wait_for(lambda: drive.unreached() == [], timeout=3)
        assert drive.backend.stats()[0].answered
        assert drive.close() == []
        assert emu.log(0)[-1][1:] == (0, 0)


def test_close_ends_a_robots_task_that_outlives_its_first_cancel(monkeypatch):
    """Python 3.11's asyncio.wait_for swallows a cancel that meets the result it waits for: a robot out of
    reach then went on trying to connect for ever, and close (the node's exit, `pixelswarm stop`) hung on it.
    Close asks such a task again until it ends."""

    async def swallows_one_cancel(link: RobotLink) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.sleep(3600)
        await asyncio.sleep(3600)

    monkeypatch.setattr(RobotLink, "run", swallows_one_cancel)
    with socket.socket() as placeholder:  # a port on 127.0.0.1 where no robot listens
        placeholder.bind(("127.0.0.1", 0))
        absent = f"127.0.0.1:{placeholder.getsockname()[1]}"
    backend = Epuck2Backend(Epuck2Config.from_table({"addresses": [absent], "connect_timeout": 0.2}, "test"))
    backend.start()
    unreached: list[list[int]] = []
    closing = threading.Thread(target=lambda: unreached.append(backend.close()), daemon=True)
    closing.start()
    closing.join(timeout=10)
    assert unreached == [[0]]


def test_stop_from_the_hardware_file_stops_robots_left_moving(tmp_path):
    with Epuck2Emulator(2) as emu:
        for address in emu.addresses:  # a run that died: robots left moving, connections gone
            with socket.create_connection(("127.0.0.1", int(address.rsplit(":", 1)[1])), timeout=2) as sock:
                drive(sock, 300, 300)
        path = tmp_path / "hw.toml"
        path.write_text(emu.hardware_toml())
        moving = emu.pose(1)
        time.sleep(0.05)
        assert emu.pose(1) != moving
        assert stop_all(load_hardware(path)) == []
        assert wait_for(lambda: all(emu.log(r)[-1][1:] == (0, 0) for r in range(2)), timeout=3)


# --- the hardware file -----------------------------------------------------------------------------------
def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hw.toml"
    path.write_text(text)
    return path


def test_hardware_file_with_defaults(tmp_path):
    config = load_hardware(write(tmp_path, '[backend]\nkind = "epuck2"\naddresses = ["127.0.0.1:41000", "robot7"]\n'))
    backend = config.backend
    assert isinstance(backend, Epuck2Config) and config.poses is None
    assert backend.robot_ids == [0, 1]
    assert backend.endpoints == [("127.0.0.1", 41000), ("robot7", 1000)]
    assert (backend.command_timeout, backend.max_wheel_speed) == (0.3, FIRMWARE_MAX_WHEEL_SPEED)
    assert isinstance(load_hardware(write(tmp_path, '[backend]\nkind = "sim"\n')).backend, SimBackendConfig)


EPUCK2 = '[backend]\nkind = "epuck2"\naddresses = ["127.0.0.1:41000"]\n'


@pytest.mark.parametrize(
    "text, message",
    [
        (EPUCK2 + "comand_timeout = 0.5\n", "unknown key 'comand_timeout'"),
        (EPUCK2 + "command_timeout = -1\n", "command_timeout must be a positive number"),
        (EPUCK2 + 'command_timeout = "fast"\n', "command_timeout must be a positive number"),
        (EPUCK2 + "max_wheel_speed = 1.0\n", "max_wheel_speed must be at most"),
        (EPUCK2 + "request_sensors = 1\n", "request_sensors must be true or false"),
        ('[backend]\nkind = "epuck2"\naddresses = []\n', "addresses must be a non-empty list"),
        ('[backend]\nkind = "epuck2"\naddresses = ["127.0.0.1:0"]\n', "is not 'host:port'"),
        ('[backend]\nkind = "epuck2"\naddresses = ["a:1", "a:1"]\n', "must not repeat"),
        ('[backend]\nkind = "epuck3"\n', "unknown kind 'epuck3'"),
        ("[backend]\naddresses = []\n", "missing key 'kind'"),
        ('[backend]\nkind = "sim"\nrobots = 3\n', "unknown key 'robots'"),
        (EPUCK2 + '[poses]\nkind = "gps"\n', "[poses]: unknown kind 'gps'"),
        (EPUCK2 + "[camera]\n", "unknown table [camera]"),
        ('[poses]\nkind = "camera"\n', "missing table [backend]"),
        ("[backend\n", "not valid TOML"),
    ],
)
def test_bad_hardware_files_are_one_line_errors(tmp_path, text, message):
    with pytest.raises(HardwareConfigError) as err:
        load_hardware(write(tmp_path, text))
    assert message in str(err.value) and str(tmp_path) in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_hardware_file_and_uninstalled_kind_are_one_line_errors(tmp_path, monkeypatch):
    with pytest.raises(HardwareConfigError, match="no such hardware file"):
        load_hardware(tmp_path / "absent.toml")
    monkeypatch.setitem(hwconfig.BACKEND_KINDS, "lego", "hardware.lego_not_installed:LegoConfig")
    with pytest.raises(HardwareConfigError, match="kind 'lego' is not available"):
        load_hardware(write(tmp_path, '[backend]\nkind = "lego"\n'))


# --- the emulator's command ------------------------------------------------------------------------------
def test_emulator_command_serves_robots_and_writes_their_hardware_file(tmp_path):
    path = tmp_path / "hw.toml"
    poses = tmp_path / "poses.json"
    poses.write_text("[[0.5, 0.5, 0.0], [1.0, 0.5, 3.14]]")
    cmd = [sys.executable, "-m", "sim.emulators.epuck2", "--robots", "2", "--poses", str(poses)]
    log = tmp_path / "log.json"
    cmd += ["--write-hardware", str(path), "--log", str(log)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert wait_for(path.exists, timeout=60), "the emulator did not start"
        config = load_hardware(path)
        with Epuck2Backend(config.backend) as backend:
            command_periods(backend, 2)
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0
    final_x = [float(line.split("x=")[1].split()[0]) for line in out.splitlines() if line.startswith("robot ")]
    assert final_x == pytest.approx([0.5, 1.0], abs=0.05)  # stopped by close() after a few periods
    robots = json.loads(log.read_text())["robots"]
    assert [r["address"] for r in robots] == list(config.backend.addresses)
    assert all(r["log"][-1][1:] == [0, 0] and any(e[1] == 388 for e in r["log"]) for r in robots)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--robots", "0"], "must be at least 1"),
        (["--robots", "2", "--poses", "absent.json"], "no such poses file"),
        (["--robots", "3", "--poses", "poses.json"], "1 poses for 3 robots"),
    ],
)
def test_emulator_command_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "poses.json").write_text("[[0, 0, 0]]")
    try:
        code = emulator_main(args)
    except SystemExit as exit:
        code = exit.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1
