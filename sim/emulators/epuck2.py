"""Emulated e-puck2 robots on Wi-Fi, one TCP server per robot on 127.0.0.1 (docs/hardware.md), written from
GCtronic's documentation independently of hardware/epuck2.py so that each checks the other.

    python -m sim.emulators.epuck2 --robots 4 --write-hardware hw.toml
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import struct
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from agent.core.params import EPUCK, RobotParams
from hardware.config import Started, is_number
from sim.args import OneLineParser, UsageError, positive_int, refuse, refuse_if
from sim.processes import stopped_by_signals

COMMAND_PACKET = 0x80
COMMAND_LENGTH = 21
ANSWER_IMAGE, ANSWER_SENSORS, ANSWER_EMPTY = 0x01, 0x02, 0x03
IMAGE_LENGTH = 160 * 120 * 2  # QQVGA, RGB565
SENSORS_LENGTH = 104
STEPS_OFFSET = 79  # in the sensors answer: left and right motor steps, int16 little-endian
STEPS_PER_TURN = 1000
WHEEL_CIRCUMFERENCE = math.pi * 0.041  # m
FIRMWARE_LIMIT = 1100  # steps/s
HOST = "127.0.0.1"
SEND_TIMEOUT = 1  # whole seconds (SO_SNDTIMEO's) an answer may wait for a client to read

Pose = tuple[float, float, float]  # x (m), y (m), heading (rad)


@dataclass(frozen=True)
class ReceivedCommand:
    """A command packet as the robot reads it."""

    request: int
    settings: int
    left: int  # steps/s
    right: int
    leds: int
    rgb: tuple[tuple[int, int, int], ...]  # LED2, LED4, LED6, LED8, 0-100
    speaker: int


def parse_command(packet: bytes) -> ReceivedCommand:
    """The 21 bytes of a command packet (starting with 0x80), field by field."""
    if len(packet) != COMMAND_LENGTH or packet[0] != COMMAND_PACKET:
        raise ValueError("not a command packet")
    rgb = tuple((packet[i], packet[i + 1], packet[i + 2]) for i in range(8, 20, 3))
    left, right = (int.from_bytes(packet[at : at + 2], "little", signed=True) for at in (3, 5))
    return ReceivedCommand(packet[1], packet[2], left, right, packet[7], rgb, packet[20])


def step_pose(pose: Pose, left: float, right: float, wheel_base: float, dt: float) -> Pose:
    """Exact differential-drive motion for dt seconds at constant wheel speeds (m/s)."""
    x, y, theta = pose
    v, omega = (left + right) / 2, (right - left) / wheel_base
    if abs(omega) < 1e-12:
        return x + v * dt * math.cos(theta), y + v * dt * math.sin(theta), theta
    turned = theta + omega * dt
    r = v / omega
    return x + r * (math.sin(turned) - math.sin(theta)), y - r * (math.cos(turned) - math.cos(theta)), turned


@dataclass
class EmulatedRobot:
    """One robot's body: pose, wheel speeds and the commands it received."""

    pose: Pose
    params: RobotParams
    since: float  # time of `pose`
    left: float = 0.0  # wheel speeds (m/s) since `since`
    right: float = 0.0
    steps: list[float] = field(default_factory=lambda: [0.0, 0.0])  # motor step counters
    rgb: tuple[tuple[int, int, int], ...] = ((0, 0, 0),) * 4
    log: list[tuple[float, int, int]] = field(default_factory=list)  # (receive time, left, right steps/s)
    connections: int = 0

    def advance(self, now: float) -> None:
        dt = max(0.0, now - self.since)
        self.pose = step_pose(self.pose, self.left, self.right, self.params.wheel_base, dt)
        for i, speed in enumerate((self.left, self.right)):
            self.steps[i] += speed / WHEEL_CIRCUMFERENCE * STEPS_PER_TURN * dt
        self.since = now

    def wheel_speed(self, steps: int) -> float:
        """steps/s as the motors turn them: the firmware's clamp, then the paper's e-puck speed limit."""
        steps = max(-FIRMWARE_LIMIT, min(FIRMWARE_LIMIT, steps))
        speed = steps / STEPS_PER_TURN * WHEEL_CIRCUMFERENCE
        return max(-self.params.v_max, min(self.params.v_max, speed))

    def apply(self, command: ReceivedCommand, now: float) -> None:
        self.advance(now)
        self.left, self.right = self.wheel_speed(command.left), self.wheel_speed(command.right)
        self.rgb = command.rgb
        self.log.append((now, command.left, command.right))

    def answer(self, command: ReceivedCommand) -> bytes:
        parts = []
        if command.request & 0x01:
            parts.append(bytes([ANSWER_IMAGE]) + bytes(IMAGE_LENGTH))  # a black image
        if command.request & 0x02:
            sensors = bytearray(SENSORS_LENGTH)  # only the motor steps are emulated; the rest read 0
            wrapped = [(round(count) + 2**15) % 2**16 - 2**15 for count in self.steps]
            struct.pack_into("<hh", sensors, STEPS_OFFSET, *wrapped)
            parts.append(bytes([ANSWER_SENSORS]) + bytes(sensors))
        return b"".join(parts) or bytes([ANSWER_EMPTY])


class Epuck2Emulator(Started):
    """N emulated e-puck2 robots, each its own TCP server on 127.0.0.1 with a thread of its own; a new
    connection to a robot replaces the old one."""

    def __init__(
        self,
        count: int,
        poses: Sequence[Pose] | None = None,
        ports: Sequence[int] | None = None,
        params: RobotParams = EPUCK,
    ) -> None:
        # by default in a row along x, two diameters apart, facing +x
        poses = list(poses) if poses is not None else [(i * 4 * params.radius, 0.0, 0.0) for i in range(count)]
        ports = list(ports) if ports is not None else [0] * count
        if count < 1 or len(poses) != count or len(ports) != count:
            raise ValueError(f"need one pose and one port for each of {count} robots")
        now = time.monotonic()
        self.robots = [
            EmulatedRobot(pose=(float(x), float(y), float(t)), params=params, since=now) for x, y, t in poses
        ]
        self._lock = threading.Lock()
        with contextlib.ExitStack() as opened:  # a port taken: the listeners opened before it are closed
            self._listeners = [opened.enter_context(socket.create_server((HOST, port))) for port in ports]
            opened.pop_all()
        self._addresses = [f"{HOST}:{listener.getsockname()[1]}" for listener in self._listeners]  # also once closed
        self._clients: dict[int, tuple[socket.socket, threading.Thread]] = {}  # robot -> connection, its reader
        self._closing = False
        self._accepting = [
            threading.Thread(target=self._accept, args=(rid,), name=f"epuck2-emulator-{rid}", daemon=True)
            for rid in range(count)
        ]

    @property
    def addresses(self) -> list[str]:
        return list(self._addresses)

    def pose(self, robot_id: int) -> Pose:
        """The robot's true pose now."""
        with self._lock:
            robot = self.robots[robot_id]
            robot.advance(time.monotonic())
            return robot.pose

    def log(self, robot_id: int) -> list[tuple[float, int, int]]:
        """(receive time, left, right steps/s) of every command the robot received."""
        with self._lock:
            return list(self.robots[robot_id].log)

    def connections(self, robot_id: int) -> int:
        with self._lock:
            return self.robots[robot_id].connections

    def drop_connection(self, robot_id: int) -> None:
        """Close the robot's connection from its side (as a Wi-Fi drop does); it keeps its wheel speeds."""
        with self._lock:
            client = self._clients.get(robot_id)
        if client is not None:
            conn, reader = client
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)  # its reader's recv returns: it closes the connection
            reader.join()

    def report(self) -> dict:
        """Each robot's address, final pose and commands received (time.monotonic() seconds, steps/s)."""
        robots = [
            {"address": address, "pose": list(self.pose(rid)), "log": [list(entry) for entry in self.log(rid)]}
            for rid, address in enumerate(self.addresses)
        ]
        return {"robots": robots}

    def hardware_toml(self) -> str:
        addresses = ", ".join(f'"{a}"' for a in self.addresses)
        return (
            f"# {len(self.robots)} emulated e-puck2 robots (python -m sim.emulators.epuck2)\n"
            f'[backend]\nkind = "epuck2"\naddresses = [{addresses}]\n'
        )

    def start(self) -> Epuck2Emulator:
        for thread in self._accepting:
            thread.start()
        return self

    def close(self) -> None:
        """Stop serving, once every command already received is applied (a client's last stop may still
        be in the socket)."""
        if self._closing:
            return
        self._closing = True
        for listener in self._listeners:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)  # its accept returns
        for thread in self._accepting:
            if thread.is_alive():
                thread.join()
        with self._lock:
            clients = list(self._clients.values())
        for conn, reader in clients:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RD)  # what the client sent before is still read, then recv returns b""
            reader.join()
        for listener in self._listeners:
            listener.close()

    def _accept(self, rid: int) -> None:
        """Robot ``rid``'s server: each connection read by a thread of its own, replacing the one before."""
        while True:
            try:
                conn, _ = self._listeners[rid].accept()
            except OSError:  # closing
                return
            if self._closing:
                conn.close()
                return
            # answers are sent whole; a client that stops reading for SEND_TIMEOUT is dropped
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", SEND_TIMEOUT, 0))
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.drop_connection(rid)
            reader = threading.Thread(target=self._receive, args=(rid, conn), name="epuck2-robot", daemon=True)
            with self._lock:
                self._clients[rid] = (conn, reader)
                self.robots[rid].connections += 1
                reader.start()  # under the lock: a drop_connection can join it at once

    def _receive(self, rid: int, conn: socket.socket) -> None:
        buffer = bytearray()
        try:
            while data := conn.recv(4096):
                buffer += data
                while buffer:
                    if buffer[0] != COMMAND_PACKET:
                        del buffer[0]  # not the start of a packet: the robot skips it
                        continue
                    if len(buffer) < COMMAND_LENGTH:
                        break
                    command = parse_command(bytes(buffer[:COMMAND_LENGTH]))
                    del buffer[:COMMAND_LENGTH]
                    with self._lock:
                        robot = self.robots[rid]
                        robot.apply(command, time.monotonic())
                        answer = robot.answer(command)
                    conn.sendall(answer)
        except OSError:  # the client went, or stopped reading
            pass
        finally:
            conn.close()
            with self._lock:
                if self._clients.get(rid, (None,))[0] is conn:
                    del self._clients[rid]


def read_poses(path: Path, count: int) -> list[Pose]:
    """A JSON list of [x, y, theta], one per robot."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: no such poses file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(f"{path}: not a JSON list of poses: {err}") from None
    ok = isinstance(data, list) and all(isinstance(p, list) and len(p) == 3 and all(map(is_number, p)) for p in data)
    refuse_if(not ok, f"{path}: poses must be a JSON list of [x, y, theta] numbers")
    refuse_if(len(data) != count, f"{path}: {len(data)} poses for {count} robots")
    return [(float(x), float(y), float(t)) for x, y, t in data]


def write_atomically(path: Path, text: str) -> None:
    """A reader never sees half a file: write beside it, then rename."""
    partial = path.with_name(path.name + ".partial")
    try:
        partial.write_text(text, encoding="utf-8")
        os.replace(partial, path)
    except OSError as err:
        partial.unlink(missing_ok=True)
        raise UsageError(f"{path}: cannot write: {err.strerror or err}") from None


def say_final(report: dict, log: Path | None) -> None:
    """Each robot's final pose (from the report) on stdout, and the report in ``log`` if asked for."""
    for rid, (x, y, theta) in enumerate(robot["pose"] for robot in report["robots"]):
        print(f"robot {rid}: x={x:.4f} m y={y:.4f} m theta={theta:.4f} rad", flush=True)
    if log:
        write_atomically(log, json.dumps(report))


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m sim.emulators.epuck2",
        description="Emulated e-puck2 robots on Wi-Fi (TCP servers on 127.0.0.1) until SIGINT or SIGTERM.",
    )
    parser.add_argument("--robots", type=positive_int, required=True, help="number of robots")
    parser.add_argument("--poses", type=Path, help="JSON list of [x, y, theta] starting poses, one per robot")
    parser.add_argument("--write-hardware", type=Path, metavar="FILE.toml", help="write a hardware file for them")
    parser.add_argument(
        "--log", type=Path, metavar="FILE.json", help="on exit, write each robot's received commands and final pose"
    )
    args = parser.parse_args(argv)
    with stopped_by_signals() as stop:
        try:
            poses = read_poses(args.poses, args.robots) if args.poses else None
            with Epuck2Emulator(args.robots, poses=poses) as emulator:
                if args.write_hardware:
                    write_atomically(args.write_hardware, emulator.hardware_toml())
                print(f"{args.robots} emulated e-puck2 robots at {' '.join(emulator.addresses)}", flush=True)
                stop.wait()
                emulator.close()
                say_final(emulator.report(), args.log)
        except (UsageError, OSError) as err:
            return refuse(parser.prog, err)
    return 0


if __name__ == "__main__":
    sys.exit(main())
