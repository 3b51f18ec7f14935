"""GCtronic e-puck2 robots over Wi-Fi, one TCP connection per robot (the packets: docs/hardware.md). A robot
keeps its last wheel speeds until told otherwise, so the backend stops every robot whose commands cease
(the watchdog), on `stop_all()` and on `close()`."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from .config import FromTable, HardwareConfigError, Started, is_number, need

log = logging.getLogger(__name__)

DEFAULT_PORT = 1000
POSITIVE_KEYS = ("command_timeout", "connect_timeout", "reconnect_backoff", "reconnect_backoff_max", "max_wheel_speed")
COMMAND_ID = 0x80
COMMAND_FORMAT = "<BBBhhB12BB"  # id, request, settings, left, right, LEDs, 4 x RGB, speaker
IMAGE_ID, SENSORS_ID, EMPTY_ID = 0x01, 0x02, 0x03
ANSWER_SIZES = {IMAGE_ID: 160 * 120 * 2, SENSORS_ID: 104, EMPTY_ID: 0}
REQUEST_SENSORS = 0x02  # the request byte's bit for the sensors answer
STEPS_OFFSET = 79  # in the sensors answer
RGB_LEDS = 4  # LED2, LED4, LED6, LED8
RGB_LEVEL_MAX = 100
CANCEL_AGAIN = 0.1  # s: close asks a robot's task again to end if it has not after this long
UNANSWERED_KEPT = 64  # commands awaiting their answer: a peer that answers none is no robot anyway

STEPS_PER_REVOLUTION = 1000
WHEEL_DIAMETER = 0.041  # m
FIRMWARE_SPEED_LIMIT = 1100  # steps/s: the firmware clamps wheel speeds here


def metres_per_second(steps: float) -> float:
    """Motor steps/s -> wheel rim speed (m/s)."""
    return steps / STEPS_PER_REVOLUTION * math.pi * WHEEL_DIAMETER


FIRMWARE_MAX_WHEEL_SPEED = metres_per_second(FIRMWARE_SPEED_LIMIT)


@dataclass(frozen=True)
class Command:
    """One command packet's fields, in the protocol's units (steps/s, LED levels 0-100)."""

    left: int = 0
    right: int = 0
    rgb: tuple[tuple[int, int, int], ...] = ((0, 0, 0),) * RGB_LEDS
    leds: int = 0
    request: int = 0
    settings: int = 0
    speaker: int = 0

    def stopped(self) -> Command:
        """The same LEDs, wheels at rest."""
        return replace(self, left=0, right=0)


def encode_command(c: Command) -> bytes:
    """The 21-byte packet for a command."""
    levels = [level for led in c.rgb for level in led]
    return struct.pack(COMMAND_FORMAT, COMMAND_ID, c.request, c.settings, c.left, c.right, c.leds, *levels, c.speaker)


def wheel_steps(speed: float, limit: float) -> int:
    """A wheel speed (m/s) clipped to `limit` (m/s), in whole steps/s within the firmware's limit.
    A speed that is not a number becomes 0: a controller's fault must not drive a robot."""
    if not math.isfinite(speed):
        return 0
    steps = round(max(-limit, min(limit, speed)) / (math.pi * WHEEL_DIAMETER) * STEPS_PER_REVOLUTION)
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
    return struct.unpack_from("<hh", sensors, STEPS_OFFSET)


def take_answers(buffer: bytearray) -> list[tuple[int, bytes]]:
    """The whole answers (id, payload) at the front of the robot's byte stream, taken off it."""
    answers = []
    while buffer:
        answer_id = buffer[0]
        if answer_id not in ANSWER_SIZES:
            raise ConnectionError(f"unknown answer id 0x{answer_id:02x}")
        end = 1 + ANSWER_SIZES[answer_id]
        if len(buffer) < end:
            break
        answers.append((answer_id, bytes(buffer[1:end])))
        del buffer[:end]
    return answers


def parse_address(address: Any) -> tuple[str, int]:
    """ "host:port" or "host" (port DEFAULT_PORT) -> (host, port)."""
    if not isinstance(address, str) or not address.strip():
        raise HardwareConfigError(f"an address must be a non-empty string like 'host:port', not {address!r}")
    host, colon, port_text = address.strip().rpartition(":")
    if not colon:
        return port_text, DEFAULT_PORT
    if not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise HardwareConfigError(f"address {address!r} is not 'host:port' with a port 1-65535")
    return host, int(port_text)


@dataclass(frozen=True)
class Epuck2Config(FromTable):
    """The `[backend]` table of kind "epuck2". Times in s, speeds in m/s."""

    KIND = "epuck2"
    addresses: tuple[str, ...] = ()  # a robot's "host:port" or "host" (a list in the table)
    command_timeout: float = 0.3  # a robot whose last command is older than this is stopped
    connect_timeout: float = 1.0  # one attempt to connect, or to send a packet
    reconnect_backoff: float = 0.1  # wait after a failed attempt; doubles up to reconnect_backoff_max
    reconnect_backoff_max: float = 2.0
    max_wheel_speed: float = FIRMWARE_MAX_WHEEL_SPEED  # wheel speeds are clipped to this before they leave
    request_sensors: bool = False  # ask for the 104-byte sensors answer with every command

    def __post_init__(self) -> None:
        addresses = self.addresses
        listed = isinstance(addresses, list | tuple) and len(addresses) > 0
        need(listed, "addresses must be a non-empty list of 'host:port' strings")
        endpoints = [parse_address(a) for a in addresses]
        need(len(set(endpoints)) == len(endpoints), "addresses must not repeat a robot")
        object.__setattr__(self, "addresses", tuple(a.strip() for a in addresses))  # frozen: set once, here
        for key in POSITIVE_KEYS:
            value = getattr(self, key)
            need(is_number(value) and value > 0, f"{key} must be a positive number, not {value!r}")
            object.__setattr__(self, key, float(value))
        sensors = self.request_sensors
        need(isinstance(sensors, bool), f"request_sensors must be true or false, not {sensors!r}")
        limit = FIRMWARE_MAX_WHEEL_SPEED
        need(self.max_wheel_speed <= limit, f"max_wheel_speed must be at most {limit:.4f} m/s (the firmware's limit)")
        ordered = self.reconnect_backoff_max >= self.reconnect_backoff
        need(ordered, "reconnect_backoff_max must be at least reconnect_backoff")

    @property
    def robot_ids(self) -> list[int]:
        return list(range(len(self.addresses)))

    @property
    def endpoints(self) -> list[tuple[str, int]]:
        return [parse_address(a) for a in self.addresses]

    def stop_robots(self, settings: object = None) -> list[int]:
        """Connect to every robot and stop it (`pixelswarm stop`); returns the robots not reached."""
        return Epuck2Backend(self).close()


@dataclass
class RobotStats:
    commands_sent: int = 0  # packets that left, stops included
    late_commands: int = 0  # commands replaced by the next one before they could leave
    connections: int = 0  # connections made
    reconnects: int = 0  # connections made again after one was lost
    watchdog_stops: int = 0  # stops sent because commands ceased for command_timeout
    connected: bool = False
    answered: bool = False  # the robot answered in protocol on this connection (not merely something listening)


class RobotLink:
    """One robot's TCP connection: a task on the backend's event loop (its thread), so a slow or lost robot
    delays no other. Its 16 attributes are one link's state; splitting them would split one protocol."""

    def __init__(self, robot_id: int, host: str, port: int, config: Epuck2Config) -> None:
        self.robot_id, self.host, self.port, self.config = robot_id, host, port, config
        self.stats = RobotStats()
        self.sensors: bytes | None = None  # the last sensors answer, when they were requested
        self.wanted = Command()  # what the robot should be doing now
        self.pending: Command | None = None  # not yet sent
        self.pending_seq = 0
        self.answered_seq = 0  # the newest command the robot answered: it arrived
        self._unanswered: deque[int] = deque(maxlen=UNANSWERED_KEPT)  # sent on this connection, oldest first
        self.last_command_time: float | None = None  # time.monotonic() of the last set_commands for this robot
        self.urgent = False  # a stop waits: connect without waiting out the backoff
        self._changed = asyncio.Event()  # a command came, or the connection was lost
        self._answered = asyncio.Condition()
        self._lost: Exception | None = None

    def submit(self, command: Command, now: float, *, urgent: bool = False) -> int:
        """Queue a command (replacing an unsent one); returns its sequence number."""
        if self.pending is not None:
            self.stats.late_commands += 1
        self.wanted = self.pending = command
        self.pending_seq += 1
        if urgent:
            self.urgent = True
        else:
            self.last_command_time = now
        self._changed.set()
        return self.pending_seq

    async def wait_answered(self, seq: int, timeout: float) -> bool:
        """Until the robot has answered command ``seq`` (or a newer one); False after ``timeout`` s."""
        async with self._answered:
            try:
                async with asyncio.timeout(timeout):
                    await self._answered.wait_for(lambda: self.answered_seq >= seq)
            except TimeoutError:
                return False
        return True

    async def run(self) -> None:
        """Connect, serve the connection until it is lost, connect again: until cancelled."""
        backoff = 0.0  # the first attempt, and the first after a drop, is immediate
        while True:
            try:
                async with asyncio.timeout(self.config.connect_timeout):
                    reader, writer = await asyncio.open_connection(self.host, self.port)
            except (OSError, TimeoutError):
                self.urgent = False  # the immediate attempt was made: back to the backoff
                answered = False
            else:
                try:
                    await self._serve(reader, writer)
                except OSError as err:
                    log.warning("e-puck2 %d (%s:%d): connection lost (%s)", self.robot_id, self.host, self.port, err)
                except Exception:  # a fault of ours must not leave the robot unattended: log it, connect again
                    log.exception("e-puck2 %d: link failed", self.robot_id)
                    await asyncio.sleep(self.config.reconnect_backoff_max)
                finally:
                    answered = self.stats.answered
                    self.stats.connected = self.stats.answered = False
                    writer.close()
            # a robot that dropped: connect again at once; one out of reach, or something there that is no e-puck2
            # (it closed or spoke another protocol), after the backoff, lest the link reconnect in a tight loop
            backoff = 0.0 if answered else self._next_backoff(backoff)
            await self._sleep_unless_urgent(backoff)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # no batching
        if self.stats.connections:
            self.stats.reconnects += 1
            log.warning("e-puck2 %d (%s:%d): connected again", self.robot_id, self.host, self.port)
        self.stats.connections += 1
        self.stats.connected = True
        self._unanswered.clear()
        if self.pending is None:  # the robot gets what it should be doing now (a stop once commands are stale)
            self.pending = self.wanted
            self.pending_seq += 1
        self._lost = None
        reading = asyncio.create_task(self._read(reader))
        try:
            while True:
                self._changed.clear()
                if self._lost is not None:
                    raise self._lost
                self._watchdog()
                if self.pending is not None:
                    await self._send(writer)
                    continue
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(self._watchdog_due()):
                        await self._changed.wait()
        finally:
            reading.cancel()

    async def _send(self, writer: asyncio.StreamWriter) -> None:
        command, seq = self.pending, self.pending_seq
        assert command is not None
        writer.write(encode_command(command))
        self._unanswered.append(seq)  # before the drain: its answer may be read while the drain waits
        async with asyncio.timeout(self.config.connect_timeout):
            await writer.drain()
        if self.pending_seq == seq:
            self.pending = None
            self.urgent = False
        self.stats.commands_sent += 1

    async def _read(self, reader: asyncio.StreamReader) -> None:
        stream = bytearray()
        try:
            while data := await reader.read(65536):
                stream += data
                for answer_id, payload in take_answers(stream):
                    if answer_id == SENSORS_ID:
                        self.sensors = payload
                    # the robot answers each command in turn: the oldest unanswered one has arrived
                    self.stats.answered = True
                    if self._unanswered:
                        self.answered_seq = max(self.answered_seq, self._unanswered.popleft())
                async with self._answered:
                    self._answered.notify_all()
            raise ConnectionError("closed by the robot")
        except OSError as err:
            self._lost = err
            self._changed.set()

    def _watchdog(self) -> None:
        due = self._watchdog_due()
        if due is not None and due <= 0:
            self.wanted = self.pending = self.wanted.stopped()
            self.pending_seq += 1
            self.stats.watchdog_stops += 1
            log.warning("e-puck2 %d: no command for %.2f s: stopped", self.robot_id, self.config.command_timeout)

    def _watchdog_due(self) -> float | None:
        """Seconds until a moving robot's commands are stale (None: nothing to watch)."""
        if self.last_command_time is None or self.wanted.left == self.wanted.right == 0:
            return None
        return self.last_command_time + self.config.command_timeout - time.monotonic()

    def _next_backoff(self, backoff: float) -> float:
        """The wait after another failure: reconnect_backoff, doubling up to reconnect_backoff_max."""
        return min(self.config.reconnect_backoff_max, max(self.config.reconnect_backoff, 2 * backoff))

    async def _sleep_unless_urgent(self, duration: float) -> None:
        deadline = time.monotonic() + duration
        while not self.urgent and (left := deadline - time.monotonic()) > 0:
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(left):
                    await self._changed.wait()


class Epuck2Backend(Started):
    """Drives e-puck2 robots over Wi-Fi (robot ids: positions in `config.addresses`) from one thread's event
    loop; calls return at once, but stop_all and close wait for the stops to leave."""

    def __init__(self, config: Epuck2Config) -> None:
        self.config = config
        self.links = [RobotLink(i, host, port, config) for i, (host, port) in enumerate(config.endpoints)]
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="epuck2-io", daemon=True)
        self._tasks: list[asyncio.Task[None]] = []
        self._closed = False

    @property
    def robot_ids(self) -> list[int]:
        return self.config.robot_ids

    def start(self) -> None:
        """Connect to every robot in the background (a robot out of reach is tried again with backoff)."""
        if not self._thread.is_alive() and not self._closed:
            self._thread.start()
            asyncio.run_coroutine_threadsafe(self._start_links(), self._loop).result()

    async def _start_links(self) -> None:
        self._tasks = [asyncio.create_task(link.run(), name=f"epuck2-{link.robot_id}") for link in self.links]

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
        commands = []
        for rid, left, right, colour in zip(robot_ids, wheel_left_mps, wheel_right_mps, colors_rgb255):
            if not 0 <= rid < len(self.links):
                raise ValueError(f"no robot {rid}: the hardware file has robots 0-{len(self.links) - 1}")
            command = replace(make_command(float(left), float(right), colour, limit), request=request)
            commands.append((self.links[rid], command))
        self._loop.call_soon_threadsafe(self._submit, commands, time.monotonic())

    @staticmethod
    def _submit(commands: list[tuple[RobotLink, Command]], now: float) -> None:
        for link, command in commands:
            link.submit(command, now)

    def stop_all(self) -> list[int]:
        """Send a stop to every robot and wait until the stops have left; returns the robots not reached."""
        if self._closed:
            return []
        self.start()
        return asyncio.run_coroutine_threadsafe(self._stop_all(), self._loop).result()

    async def _stop_all(self) -> list[int]:
        now = time.monotonic()
        seqs = [link.submit(link.wanted.stopped(), now, urgent=True) for link in self.links]
        wait = 2 * self.config.connect_timeout  # a connection attempt, then the send and the robot's answer
        answered = await asyncio.gather(*(link.wait_answered(seq, wait) for link, seq in zip(self.links, seqs)))
        return [link.robot_id for link, ok in zip(self.links, answered) if not ok]

    def close(self) -> list[int]:
        """Stop every robot, then close the connections; returns the robots the stop did not reach."""
        if self._closed:
            return []
        unreached = self.stop_all()
        asyncio.run_coroutine_threadsafe(self._cancel_links(), self._loop).result()
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join()
        self._loop.close()
        self._closed = True
        return unreached  # the caller says it, once

    async def _cancel_links(self) -> None:
        pending = set(self._tasks)
        # until each has ended: a cancel that meets what a task awaits can be lost (Python 3.11's wait_for loses it)
        while pending:
            for task in pending:
                task.cancel()
            _, pending = await asyncio.wait(pending, timeout=CANCEL_AGAIN)
        await asyncio.sleep(0)  # let the transports finish closing
        await self._loop.shutdown_default_executor()  # the threads that resolved host names

    def sensors(self, robot_id: int) -> bytes | None:
        """The robot's last 104-byte sensors answer (with `request_sensors = true`), or None."""
        return self.links[robot_id].sensors

    def stats(self) -> dict[int, RobotStats]:
        return {link.robot_id: replace(link.stats) for link in self.links}
