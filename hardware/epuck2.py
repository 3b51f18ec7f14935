"""GCtronic e-puck2 robots over Wi-Fi: one TCP connection per robot, the robot being the server.

Protocol (GCtronic wiki, "e-puck2 PC side development", section "Communication protocol: WiFi"):
the PC sends a 21-byte command packet, 0x80 followed by

    byte  1      request: bit 0 image stream, bit 1 sensors
    byte  2      settings: bit 0 calibrate IR sensors, bit 1 onboard obstacle avoidance, bit 2 set motor steps
    bytes 3-4    left motor speed, int16 little-endian, steps/s
    bytes 5-6    right motor speed, int16 little-endian, steps/s
    byte  7      LEDs: bit 0 LED1, bit 1 LED3, bit 2 LED5, bit 3 LED7, bit 4 body LED, bit 5 front LED
    bytes 8-19   red, green, blue of LED2, LED4, LED6, LED8, each 0-100
    byte  20     speaker (0: leave the sound as it is)

and the robot answers each command with 0x03 (nothing requested), 0x02 + 104 bytes of sensors or 0x01 +
38,400 bytes of QQVGA RGB565 image. A robot keeps its last wheel speeds until told otherwise, so the
backend stops every robot whose commands cease (the watchdog), on `stop_all()` and on `close()`.

Usage, once per control period: `backend.set_commands(ids, left_mps, right_mps, colours_rgb255)`.
"""

from __future__ import annotations

import logging
import math
import selectors
import socket
import struct
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

from .config import HardwareConfigError, check_keys, positive_number

log = logging.getLogger(__name__)

DEFAULT_PORT = 1000
COMMAND_ID = 0x80
COMMAND_FORMAT = "<BBBhhB12BB"  # id, request, settings, left, right, LEDs, 4 x RGB, speaker
COMMAND_SIZE = struct.calcsize(COMMAND_FORMAT)
IMAGE_ID, SENSORS_ID, EMPTY_ID = 0x01, 0x02, 0x03
ANSWER_SIZES = {IMAGE_ID: 160 * 120 * 2, SENSORS_ID: 104, EMPTY_ID: 0}
REQUEST_IMAGE, REQUEST_SENSORS = 0x01, 0x02
STEPS_OFFSET = 79  # in the sensors answer
RGB_LEDS = 4  # LED2, LED4, LED6, LED8
RGB_LEVEL_MAX = 100

STEPS_PER_REVOLUTION = 1000
WHEEL_DIAMETER = 0.041  # m
FIRMWARE_SPEED_LIMIT = 1100  # steps/s: the firmware clamps wheel speeds here


def steps_per_second(speed: float) -> float:
    """Wheel rim speed (m/s) -> motor steps/s."""
    return speed / (math.pi * WHEEL_DIAMETER) * STEPS_PER_REVOLUTION


def metres_per_second(steps: float) -> float:
    """Motor steps/s -> wheel rim speed (m/s)."""
    return steps / STEPS_PER_REVOLUTION * math.pi * WHEEL_DIAMETER


FIRMWARE_MAX_WHEEL_SPEED = metres_per_second(FIRMWARE_SPEED_LIMIT)


@dataclass(frozen=True)
class Command:
    """One command packet's fields, in the protocol's units (steps/s, LED levels 0-100)."""

    left: int = 0
    right: int = 0
    rgb: tuple[tuple[int, int, int], ...] = ((0, 0, 0),) * RGB_LEDS  # LED2, LED4, LED6, LED8
    leds: int = 0
    request: int = 0
    settings: int = 0
    speaker: int = 0

    @property
    def moving(self) -> bool:
        return self.left != 0 or self.right != 0

    def stopped(self) -> Command:
        """The same LEDs, wheels at rest."""
        return replace(self, left=0, right=0)


def encode_command(command: Command) -> bytes:
    """The 21-byte packet for a command."""
    levels = [level for led in command.rgb for level in led]
    return struct.pack(
        COMMAND_FORMAT,
        COMMAND_ID,
        command.request,
        command.settings,
        command.left,
        command.right,
        command.leds,
        *levels,
        command.speaker,
    )


def wheel_steps(speed: float, limit: float) -> int:
    """A wheel speed (m/s) clipped to `limit` (m/s), in whole steps/s within the firmware's limit.
    A speed that is not a number becomes 0: a controller's fault must not drive a robot."""
    if not math.isfinite(speed):
        return 0
    steps = round(steps_per_second(max(-limit, min(limit, speed))))
    return max(-FIRMWARE_SPEED_LIMIT, min(FIRMWARE_SPEED_LIMIT, steps))


def led_level(channel: float) -> int:
    """A colour channel 0-255 -> an LED level 0-100."""
    if not math.isfinite(channel):
        return 0
    return round(max(0.0, min(255.0, channel)) * RGB_LEVEL_MAX / 255)


def make_command(left: float, right: float, colour_rgb255: Sequence[float], limit: float) -> Command:
    """Wheel speeds (m/s) and a robot's colour (0-255, shown on all four RGB LEDs) -> a Command."""
    rgb = tuple(led_level(c) for c in colour_rgb255)
    if len(rgb) != 3:
        raise ValueError(f"a colour has three channels, not {len(rgb)}")
    return Command(left=wheel_steps(left, limit), right=wheel_steps(right, limit), rgb=(rgb,) * RGB_LEDS)


def motor_steps(sensors: bytes) -> tuple[int, int]:
    """Left and right motor step counters from a sensors answer (bytes 79-82, int16 little-endian)."""
    left, right = struct.unpack_from("<hh", sensors, STEPS_OFFSET)
    return left, right


class AnswerReader:
    """Splits the robot's byte stream into answers (id, payload)."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        self._buffer += data
        answers = []
        while self._buffer:
            answer_id = self._buffer[0]
            if answer_id not in ANSWER_SIZES:
                raise ConnectionError(f"unknown answer id 0x{answer_id:02x}")
            end = 1 + ANSWER_SIZES[answer_id]
            if len(self._buffer) < end:
                break
            answers.append((answer_id, bytes(self._buffer[1:end])))
            del self._buffer[:end]
        return answers


def parse_address(address: Any, where: str) -> tuple[str, int]:
    """ "host:port" or "host" (port 1000) -> (host, port)."""
    if not isinstance(address, str) or not address.strip():
        raise HardwareConfigError(f"{where}: an address must be a non-empty string like 'host:port', not {address!r}")
    host, colon, port_text = address.strip().rpartition(":")
    if not colon:
        return port_text, DEFAULT_PORT
    if not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise HardwareConfigError(f"{where}: address {address!r} is not 'host:port' with a port 1-65535")
    return host, int(port_text)


@dataclass(frozen=True)
class Epuck2Config:
    """The `[backend]` table of kind "epuck2". Times in s, speeds in m/s."""

    addresses: tuple[str, ...]
    command_timeout: float = 0.3  # a robot whose last command is older than this is stopped
    connect_timeout: float = 1.0  # one attempt to connect, or to send a packet
    reconnect_backoff: float = 0.1  # wait after a failed attempt; doubles up to reconnect_backoff_max
    reconnect_backoff_max: float = 2.0
    max_wheel_speed: float = FIRMWARE_MAX_WHEEL_SPEED  # wheel speeds are clipped to this before they leave
    request_sensors: bool = False  # ask for the 104-byte sensors answer with every command
    kind: str = "epuck2"

    @classmethod
    def from_table(cls, table: Mapping[str, Any], where: str) -> Epuck2Config:
        defaults = {f.name: f.default for f in fields(cls) if f.name != "addresses"}
        check_keys(table, ["addresses", *defaults], where)
        addresses = table.get("addresses")
        if not isinstance(addresses, list) or not addresses:
            raise HardwareConfigError(f"{where}: addresses must be a non-empty list of 'host:port' strings")
        endpoints = [parse_address(a, where) for a in addresses]
        if len(set(endpoints)) != len(endpoints):
            raise HardwareConfigError(f"{where}: addresses must not repeat a robot")
        flags = {"kind", "request_sensors"}
        numbers = {key: positive_number(table, key, defaults[key], where) for key in defaults if key not in flags}
        request_sensors = table.get("request_sensors", defaults["request_sensors"])
        if not isinstance(request_sensors, bool):
            raise HardwareConfigError(f"{where}: request_sensors must be true or false, not {request_sensors!r}")
        if numbers["max_wheel_speed"] > FIRMWARE_MAX_WHEEL_SPEED:
            raise HardwareConfigError(
                f"{where}: max_wheel_speed must be at most {FIRMWARE_MAX_WHEEL_SPEED:.4f} m/s (the firmware's limit)"
            )
        if numbers["reconnect_backoff_max"] < numbers["reconnect_backoff"]:
            raise HardwareConfigError(f"{where}: reconnect_backoff_max must be at least reconnect_backoff")
        return cls(addresses=tuple(a.strip() for a in addresses), request_sensors=request_sensors, **numbers)

    @property
    def robot_ids(self) -> list[int]:
        return list(range(len(self.addresses)))

    @property
    def endpoints(self) -> list[tuple[str, int]]:
        return [parse_address(a, "address") for a in self.addresses]

    @property
    def stop_wait(self) -> float:
        """How long stop_all() waits for the stops to leave: a connection attempt, then the send."""
        return 2 * self.connect_timeout


@dataclass
class RobotStats:
    commands_sent: int = 0  # packets that left, stops included
    late_commands: int = 0  # commands replaced by the next one before they could leave
    reconnects: int = 0  # connections made again after one was lost
    watchdog_stops: int = 0  # stops sent because commands ceased for command_timeout
    connected: bool = False


@dataclass
class _Outbox:
    """What one robot's link should send, shared between the control loop and the link's thread."""

    wanted: Command = field(default_factory=Command)  # what the robot should be doing now
    pending: Command | None = None  # not yet sent
    pending_seq: int = 0
    sent_seq: int = 0
    last_command_time: float | None = None  # monotonic time of the last set_commands for this robot
    urgent: bool = False  # a stop waits: connect without waiting out the backoff


class RobotLink:
    """One robot's TCP connection, run by its own thread so that a slow or lost robot delays no other."""

    def __init__(self, robot_id: int, host: str, port: int, config: Epuck2Config) -> None:
        self.robot_id, self.host, self.port, self.config = robot_id, host, port, config
        self.stats = RobotStats()
        self.sensors: bytes | None = None  # the last sensors answer, when they were requested
        self._out = _Outbox()
        self._cond = threading.Condition()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._sock: socket.socket | None = None
        self._reader = AnswerReader()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=f"epuck2-{robot_id}", daemon=True)

    # --- called by the control loop ---
    def start(self) -> None:
        self._thread.start()

    def submit(self, command: Command, *, from_controller: bool) -> int:
        """Queue a command (replacing an unsent one); returns its sequence number."""
        with self._cond:
            out = self._out
            if out.pending is not None:
                self.stats.late_commands += 1
            out.wanted = out.pending = command
            out.pending_seq += 1
            if from_controller:
                out.last_command_time = time.monotonic()
            else:
                out.urgent = True
            seq = out.pending_seq
        self._wake()
        return seq

    def submit_stop(self) -> int:
        """Queue a stop that keeps the LEDs; the link connects for it without waiting out a backoff."""
        with self._cond:
            stop = self._out.wanted.stopped()
        return self.submit(stop, from_controller=False)

    def wait_sent(self, seq: int, deadline: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._out.sent_seq >= seq, max(0.0, deadline - time.monotonic()))

    def close(self) -> None:
        with self._cond:
            self._closing = True
        self._wake()
        if self._thread.is_alive():
            self._thread.join()
        self._disconnect()
        self._wake_r.close()
        self._wake_w.close()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass  # already awake (buffer full) or closing

    # --- the link's thread ---
    def _run(self) -> None:
        backoff = 0.0  # the first attempt, and the first after a drop, is immediate
        ever_connected = False
        while not self._closing:
            if self._sock is None:
                if self._connect():
                    if ever_connected:
                        self.stats.reconnects += 1
                        log.warning("e-puck2 %d (%s:%d): connected again", self.robot_id, self.host, self.port)
                    ever_connected = True
                    backoff = 0.0
                    self._resend_wanted()
                else:
                    with self._cond:
                        self._out.urgent = False  # the immediate attempt was made: back to the backoff
                    backoff = min(self.config.reconnect_backoff_max, max(self.config.reconnect_backoff, 2 * backoff))
                    self._sleep_unless_urgent(backoff)
                    continue
            self._watchdog()
            self._send_pending()
            self._wait_and_read()
        self._disconnect()

    def _connect(self) -> bool:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.config.connect_timeout)
        except OSError:
            return False
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # one small packet per period: no batching
        self._sock, self._reader = sock, AnswerReader()
        self.stats.connected = True
        return True

    def _disconnect(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self.stats.connected = False

    def _resend_wanted(self) -> None:
        """After a (re)connection the robot gets what it should be doing now (a stop once commands are stale)."""
        with self._cond:
            if self._out.pending is None:
                self._out.pending = self._out.wanted
                self._out.pending_seq += 1

    def _sleep_unless_urgent(self, duration: float) -> None:
        deadline = time.monotonic() + duration
        while not self._closing and time.monotonic() < deadline:
            with self._cond:
                if self._out.urgent:
                    return
            self._wait_readable([self._wake_r], deadline - time.monotonic())

    def _watchdog(self) -> None:
        with self._cond:
            out = self._out
            stale = out.last_command_time is not None and (
                time.monotonic() - out.last_command_time >= self.config.command_timeout
            )
            if stale and out.wanted.moving:
                out.wanted = out.pending = out.wanted.stopped()
                out.pending_seq += 1
                self.stats.watchdog_stops += 1
                log.warning("e-puck2 %d: no command for %.2f s: stopped", self.robot_id, self.config.command_timeout)

    def _send_pending(self) -> None:
        with self._cond:
            command, seq = self._out.pending, self._out.pending_seq
        if command is None or self._sock is None:
            return
        try:
            self._sock.sendall(encode_command(command))
        except OSError as err:
            self._lost(err)
            return
        with self._cond:
            if self._out.pending_seq == seq:
                self._out.pending = None
                self._out.urgent = False
            self._out.sent_seq = max(self._out.sent_seq, seq)
            self.stats.commands_sent += 1
            self._cond.notify_all()

    def _wait_and_read(self) -> None:
        """Sleep until a command comes, the robot answers or the watchdog is due."""
        with self._cond:
            if self._out.pending is not None:
                return
            due = None
            if self._out.last_command_time is not None and self._out.wanted.moving:
                due = self._out.last_command_time + self.config.command_timeout - time.monotonic()
        assert self._sock is not None
        ready = self._wait_readable([self._wake_r, self._sock], due)
        if self._sock in ready:
            self._read()

    def _wait_readable(self, sockets: list[socket.socket], timeout: float | None) -> list[socket.socket]:
        with selectors.DefaultSelector() as selector:
            for s in sockets:
                selector.register(s, selectors.EVENT_READ)
            ready = [key.fileobj for key, _ in selector.select(None if timeout is None else max(0.0, timeout))]
        if self._wake_r in ready:
            try:
                while self._wake_r.recv(4096):
                    pass
            except BlockingIOError:
                pass
        return ready  # type: ignore[return-value]

    def _read(self) -> None:
        assert self._sock is not None
        try:
            data = self._sock.recv(65536)
            if not data:
                raise ConnectionError("closed by the robot")
            for answer_id, payload in self._reader.feed(data):
                if answer_id == SENSORS_ID:
                    self.sensors = payload
        except OSError as err:
            self._lost(err)

    def _lost(self, err: Exception) -> None:
        log.warning("e-puck2 %d (%s:%d): connection lost (%s)", self.robot_id, self.host, self.port, err)
        self._disconnect()


class Epuck2Backend:
    """Drives e-puck2 robots over Wi-Fi; robot ids are positions in `config.addresses`."""

    def __init__(self, config: Epuck2Config) -> None:
        self.config = config
        self.links = [RobotLink(i, host, port, config) for i, (host, port) in enumerate(config.endpoints)]
        self._started = self._closed = False

    @property
    def robot_ids(self) -> list[int]:
        return self.config.robot_ids

    def start(self) -> None:
        """Connect to every robot in the background (a robot out of reach is tried again with backoff)."""
        if not self._started:
            self._started = True
            for link in self.links:
                link.start()

    def set_commands(
        self,
        robot_ids: Sequence[int],
        wheel_left_mps: Sequence[float],
        wheel_right_mps: Sequence[float],
        colors_rgb255: Sequence[Sequence[float]],
    ) -> None:
        """This control period's wheel speeds (m/s) and colours (0-255); returns without waiting for the network."""
        if not len(robot_ids) == len(wheel_left_mps) == len(wheel_right_mps) == len(colors_rgb255):
            raise ValueError("set_commands needs one left speed, right speed and colour per robot id")
        limit = self.config.max_wheel_speed
        request = REQUEST_SENSORS if self.config.request_sensors else 0
        for rid, left, right, colour in zip(robot_ids, wheel_left_mps, wheel_right_mps, colors_rgb255):
            command = replace(make_command(float(left), float(right), colour, limit), request=request)
            self.links[rid].submit(command, from_controller=True)

    def stop_all(self) -> list[int]:
        """Send a stop to every robot and wait until the stops have left; returns the robots not reached."""
        seqs = [link.submit_stop() for link in self.links]
        deadline = time.monotonic() + self.config.stop_wait
        if not self._started:
            self.start()
        return [link.robot_id for link, seq in zip(self.links, seqs) if not link.wait_sent(seq, deadline)]

    def close(self) -> list[int]:
        """Stop every robot, then close the connections; returns the robots the stop did not reach."""
        if self._closed:
            return []
        unreached = self.stop_all()
        for link in self.links:
            link.close()
        self._closed = True
        if unreached:
            log.error("e-puck2 robots %s were not reached by the stop", unreached)
        return unreached

    def sensors(self, robot_id: int) -> bytes | None:
        """The robot's last 104-byte sensors answer (with `request_sensors = true`), or None."""
        return self.links[robot_id].sensors

    def stats(self) -> dict[int, RobotStats]:
        return {link.robot_id: replace(link.stats) for link in self.links}

    def __enter__(self) -> Epuck2Backend:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def stop_robots(config: Epuck2Config) -> list[int]:
    """Connect to every robot of a config and stop it (`pixelswarm stop`); returns the robots not reached."""
    return Epuck2Backend(config).close()
