"""ROS 2 robots (Twist on cmd_vel, ColorRGBA on led) and motion capture (PoseStamped), reached through
rmw_zenoh (docs/ros2.md). CDR and the RIHS01 type hashes come from rosbags' message definitions."""

from __future__ import annotations

import itertools
import math
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from transport.rmw_zenoh import (
    TYPE_HASH_NOT_SUPPORTED,
    RosNameError,
    RosNode,
    RosPublisher,
    RosSubscriber,
    check_name,
    qualified,
)
from transport.session import ZenohSettings, open_session

from .config import FromTable, HardwareConfigError, Started, is_number, need
from .poses import OneSource, PoseSample, StampGate

TWIST = "geometry_msgs/msg/Twist"
COLOR_RGBA = "std_msgs/msg/ColorRGBA"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
DISTROS = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY, "kilted": Stores.ROS2_KILTED}
ROBOT_ID = "{id}"  # where a pose topic names the robot
STOP_REPEATS = 3  # `pixelswarm stop` sends its stop this many times, a watchdog quarter apart: a fresh
# session's first puts may leave before the router has told it who subscribes
STOP_HEARD_WITHIN = 2.0  # s: ... and on, until each robot's stop went out to a subscriber, for at most this long


class Ros2Messages:
    """The messages of one ROS 2 distribution as CDR bytes (rosbags' definitions and serialiser)."""

    def __init__(self, distro: str = "jazzy") -> None:
        self.distro = distro
        self.store = get_typestore(DISTROS[distro])
        self._types = self.store.types

    def type_hash(self, ros_type: str) -> str:
        """The key's type hash: RIHS01 from Iron on; Humble's rmw_zenoh writes a fixed word instead."""
        return TYPE_HASH_NOT_SUPPORTED if self.distro == "humble" else self.store.hash_rihs01(ros_type)

    def twist(self, v_linear: float, omega: float) -> bytes:
        """A planar body velocity: forward speed (m/s) along x, turn rate (rad/s) about z."""
        vector3 = self._types["geometry_msgs/msg/Vector3"]
        msg = self._types[TWIST](
            linear=vector3(x=float(v_linear), y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=float(omega))
        )
        return bytes(self.store.serialize_cdr(msg, TWIST))

    def color(self, rgb255: Any) -> bytes:
        """An opaque LED colour; ColorRGBA holds 0-1 floats."""
        r, g, b = (float(c) / 255.0 for c in rgb255)
        return bytes(self.store.serialize_cdr(self._types[COLOR_RGBA](r=r, g=g, b=b, a=1.0), COLOR_RGBA))

    def pose_stamped(self, x: float, y: float, theta: float, stamp: float, frame_id: str = "world") -> bytes:
        """A planar pose in metres and radians as PoseStamped (heading as a rotation about z)."""
        t = self._types
        sec = math.floor(stamp)
        header = t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=min(round((stamp - sec) * 1e9), 999_999_999)),
            frame_id=frame_id,
        )
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)),
        )
        return bytes(self.store.serialize_cdr(t[POSE_STAMPED](header=header, pose=pose), POSE_STAMPED))

    def read_pose_stamped(self, cdr: bytes) -> tuple[float, float, float, float]:
        """(x, y, yaw, stamp in s) of a PoseStamped; raises ValueError if the bytes are not one."""
        try:
            msg: Any = self.store.deserialize_cdr(cdr, POSE_STAMPED)
        except Exception as err:  # rosbags raises several kinds on truncated or foreign bytes
            raise ValueError(f"not a PoseStamped: {err}") from None
        p, q = msg.pose.position, msg.pose.orientation
        # Motion-capture drivers publish NaN (or a zero quaternion) for a body they have lost.
        if not all(math.isfinite(v) for v in (p.x, p.y, q.x, q.y, q.z, q.w)) or q.x**2 + q.y**2 + q.z**2 + q.w**2 < 0.5:
            raise ValueError("not a valid pose: non-finite position or orientation")
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        return p.x, p.y, yaw, stamp


def _check_domain(value: Any) -> None:
    # ROS_DOMAIN_ID spans 0-232 (the DDS port arithmetic's limit; rmw_zenoh keeps it).
    whole = isinstance(value, int) and not isinstance(value, bool)
    need(whole and 0 <= value <= 232, f"domain must be a whole number 0-232, not {value!r}")


def _check_name(value: Any, key: str, what: str = "topic") -> None:
    need(isinstance(value, str), f"{key} must be a string, not {value!r}")
    try:
        check_name(value, what)
    except RosNameError as err:
        raise HardwareConfigError(f"{key}: {err}") from None


@dataclass(frozen=True)
class Ros2BackendConfig(FromTable):
    """`[backend] kind = "ros2"`: which robots, on which topics, in which ROS domain."""

    KIND = "ros2"

    namespaces: list[str]
    cmd_topic: str = "cmd_vel"
    led_topic: str = "led"
    domain: int = 0
    distro: str = "jazzy"  # humble keys carry no type hash
    watchdog: float = 0.3  # s: a robot left this long without a command is sent a zero Twist

    def __post_init__(self) -> None:
        need(isinstance(self.namespaces, list) and len(self.namespaces) > 0, "namespaces must be a non-empty list")
        for ns in self.namespaces:
            need(isinstance(ns, str) and ns.strip("/") != "", f"namespace {ns!r} must be a non-empty string")
            _check_name(ns, "namespaces", "namespace")
        cleaned = [ns.strip("/") for ns in self.namespaces]
        need(len(set(cleaned)) == len(cleaned), "namespaces must differ from each other")
        for key, topic in (("cmd_topic", self.cmd_topic), ("led_topic", self.led_topic)):
            _check_name(topic, key)
            need(not topic.startswith("/"), f"{key} is relative to each robot's namespace: no leading '/'")
        _check_domain(self.domain)
        need(self.distro in DISTROS, f"distro must be one of {', '.join(DISTROS)}, not {self.distro!r}")
        watchdog = self.watchdog
        need(is_number(watchdog) and watchdog > 0, f"watchdog must be a positive time in s, not {watchdog!r}")

    @property
    def robot_ids(self) -> list[int]:
        return list(range(len(self.namespaces)))

    def topic(self, robot: int, relative: str) -> str:
        """The fully qualified topic of one robot, e.g. /robot0/cmd_vel."""
        return qualified(relative, "/" + self.namespaces[robot].strip("/"))

    def stop_robots(self, settings: ZenohSettings | None = None) -> list[int]:
        """A zero Twist to every robot through the router ``settings`` reaches (`pixelswarm stop`); returns the
        robots whose cmd_vel nobody subscribed to (a put has no answer: a subscriber is all that can be told)."""
        if settings is None:
            raise HardwareConfigError("ROS 2 robots are reached through a router: give its endpoint (-e ENDPOINT)")
        with Ros2Backend(self, settings) as backend:
            return backend.stop_heard(STOP_REPEATS, STOP_HEARD_WITHIN)


@dataclass(frozen=True)
class Ros2PosesConfig(FromTable):
    """`[poses] kind = "ros2"`: PoseStamped per robot, e.g. from a motion-capture system's ROS 2 driver."""

    KIND = "ros2"

    topic: str = "/robot{id}/pose"
    domain: int | None = None  # None: any domain
    rate: float = 10.0  # Hz: the control rate that ticks() resamples to

    def __post_init__(self) -> None:
        need(
            isinstance(self.topic, str) and self.topic.count(ROBOT_ID) == 1,
            f"topic must name the robot once as {ROBOT_ID}, e.g. /robot{{id}}/pose, not {self.topic!r}",
        )
        _check_name(self.topic.replace(ROBOT_ID, "0"), "topic")
        if self.domain is not None:
            _check_domain(self.domain)
        need(is_number(self.rate) and self.rate > 0, f"rate must be a positive number of Hz, not {self.rate!r}")

    def topic_of(self, robot: int) -> str:
        """The fully qualified pose topic of one robot, e.g. /robot3/pose."""
        return qualified(self.topic.replace(ROBOT_ID, str(robot)))

    def robot_of(self, topic: str) -> int | None:
        """The robot a fully qualified topic belongs to, or None if it is not one of ours."""
        head, tail = qualified(self.topic).split(ROBOT_ID)
        match = re.fullmatch(re.escape(head) + r"(\d+)" + re.escape(tail), topic)
        return int(match.group(1)) if match else None

    @property
    def wildcard(self) -> str:
        """The topic as a Zenoh pattern matching every robot (`$*` stands for part of a chunk)."""
        return qualified(self.topic.replace(ROBOT_ID, "$*"))


class Ros2Node(Started):
    """A ROS 2 node on a Zenoh session of its own, opened by start(), maybe with a thread that ``_halt`` ends."""

    NODE_NAME = ""

    def __init__(self, session_config: ZenohSettings) -> None:
        self.session_config = session_config
        self._session: Any = None
        self.node: RosNode | None = None  # the ROS 2 node this appears as, once started
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    def _open(self, domain: int) -> RosNode:
        self._session = open_session(self.session_config)
        self.node = RosNode(self._session, self.NODE_NAME, domain)
        return self.node

    def close(self) -> None:
        if self._session is None:
            return
        self._halt.set()
        if self._thread is not None:
            self._thread.join()
        self._closing()
        assert self.node is not None
        self.node.close()
        self._session.close()
        self._session = None

    def _closing(self) -> None:
        """The last words once the thread has ended, before the node leaves the graph."""


class Ros2Backend(Ros2Node):
    """Robots that take Twist and ColorRGBA over rmw_zenoh; a watchdog stops a robot left without commands."""

    NODE_NAME = "pixelswarm_backend"

    def __init__(self, config: Ros2BackendConfig, session_config: ZenohSettings) -> None:
        super().__init__(session_config)
        self.config = config
        self.messages = Ros2Messages(config.distro)
        n = len(config.namespaces)
        self._last_command = np.full(n, -np.inf)  # monotonic s
        self._stopped = np.ones(n, bool)  # a zero Twist went out since the last command
        self._counts = {"commands": 0, "colors": 0, "zero_twists": 0, "watchdog_stops": 0}
        self._lock = threading.Lock()
        self._cmd: list[RosPublisher] = []  # per robot, once started
        self._led: list[RosPublisher] = []

    def start(self) -> None:
        node = self._open(self.config.domain)
        twist_hash = self.messages.type_hash(TWIST)
        color_hash = self.messages.type_hash(COLOR_RGBA)
        robots, config = range(len(self.config.namespaces)), self.config
        self._cmd = [node.publisher(config.topic(i, config.cmd_topic), TWIST, twist_hash) for i in robots]
        self._led = [node.publisher(config.topic(i, config.led_topic), COLOR_RGBA, color_hash) for i in robots]
        self._zero = self.messages.twist(0.0, 0.0)
        self._thread = threading.Thread(target=self._watch, name="ros2-watchdog", daemon=True)
        self._thread.start()

    def set_commands(self, robot_ids: Any, v_linear: Any, omega: Any, colors_rgb255: Any | None = None) -> None:
        """Forward speed (m/s) and turn rate (rad/s) per robot, and optionally its LED colour (0-255 RGB)."""
        if not self._cmd:
            raise RuntimeError("start() the backend before commanding robots")
        ids = np.asarray(robot_ids, dtype=np.int64).reshape(-1)
        v = np.asarray(v_linear, float).reshape(-1)
        w = np.asarray(omega, float).reshape(-1)
        if not (len(ids) == len(v) == len(w)):
            raise ValueError(f"{len(ids)} robot ids, {len(v)} speeds and {len(w)} turn rates")
        if len(ids) and (ids.min() < 0 or ids.max() >= len(self._cmd)):
            raise ValueError(f"robot ids must be 0-{len(self._cmd) - 1}")
        if not (np.isfinite(v).all() and np.isfinite(w).all()):
            raise ValueError("speeds and turn rates must be finite")
        colors = None if colors_rgb255 is None else np.asarray(colors_rgb255, float)
        if colors is not None and colors.shape != (len(ids), 3):
            raise ValueError(f"colours must be one RGB row per robot, shape ({len(ids)}, 3), not {colors.shape}")
        now = time.monotonic()
        with self._lock:
            for k, robot in enumerate(ids):
                self._cmd[robot].publish(self.messages.twist(v[k], w[k]))
                self._last_command[robot] = now
                self._stopped[robot] = False
                if colors is not None:
                    self._led[robot].publish(self.messages.color(np.clip(colors[k], 0, 255)))
            self._counts["commands"] += len(ids)
            self._counts["colors"] += 0 if colors is None else len(ids)

    def stop_all(self) -> None:
        """A zero Twist to every robot."""
        with self._lock:
            for robot in range(len(self._cmd)):
                self._send_zero(robot)

    def unheard(self) -> list[int]:
        """The robots whose cmd_vel topic has no subscription known now (their driver down, a wrong namespace)."""
        return [robot for robot, publisher in enumerate(self._cmd) if not publisher.heard]

    def stop_heard(self, repeats: int, within: float) -> list[int]:
        """Zero Twists to every robot, ``repeats`` times a watchdog quarter apart, and on until each robot's went
        out to a known subscriber or ``within`` s passed; returns the robots whose stop nobody was known to hear."""
        heard = np.zeros(len(self._cmd), bool)
        end = time.monotonic() + within
        for rounds in itertools.count(1):
            with self._lock:
                for robot, publisher in enumerate(self._cmd):
                    heard[robot] |= publisher.heard  # before the put: it then reaches that subscriber
                    self._send_zero(robot)
            if (rounds >= repeats and heard.all()) or time.monotonic() >= end:
                break
            time.sleep(self.config.watchdog / 4)
        return np.flatnonzero(~heard).tolist()

    def _send_zero(self, robot: int) -> None:
        self._cmd[robot].publish(self._zero)
        self._stopped[robot] = True
        self._counts["zero_twists"] += 1

    def _watch(self) -> None:
        # Checking four times per timeout keeps a silent robot moving at most 1.25 timeouts.
        while not self._halt.wait(self.config.watchdog / 4):
            now = time.monotonic()
            with self._lock:
                silent = np.flatnonzero(~self._stopped & (now - self._last_command > self.config.watchdog))
                for robot in silent:
                    self._send_zero(int(robot))
                self._counts["watchdog_stops"] += len(silent)

    def stats(self) -> dict[str, Any]:
        with self._lock:
            return dict(self._counts, robots=len(self.config.namespaces), moving=int((~self._stopped).sum()))

    def _closing(self) -> None:
        """Stop every robot before leaving the ROS graph."""
        self.stop_all()


class Ros2PoseSource(Ros2Node):
    """The latest PoseStamped of every robot, from any publisher of the topic pattern over rmw_zenoh."""

    NODE_NAME = "pixelswarm_poses"
    RING = 4096  # samples held between two reads; older ones are superseded anyway

    def __init__(self, config: Ros2PosesConfig, session_config: ZenohSettings) -> None:
        super().__init__(session_config)
        self.config = config
        self.messages = Ros2Messages()  # PoseStamped's layout is the same in every supported distro
        self._latest: dict[int, tuple[float, float, float, float, float]] = {}  # robot -> pose, stamp, arrival
        self._counts = {"received": 0, "undecodable": 0, "foreign": 0, "without_attachment": 0}
        self.gate = StampGate()  # stamps judged against this machine's clock (time.time())
        self.sources = OneSource()  # publishers told apart by the gid of rmw_zenoh's attachment
        self._sub: RosSubscriber | None = None

    def start(self) -> None:
        node = self._open(0 if self.config.domain is None else self.config.domain)
        pose_hash = self.messages.type_hash(POSE_STAMPED)
        self._sub = node.subscriber(
            self.config.wildcard, POSE_STAMPED, pose_hash, any_domain=self.config.domain is None, capacity=self.RING
        )

    def latest(self) -> dict[int, PoseSample]:
        """Every robot heard from so far, by id, with its newest pose (as `gate` takes them by stamp)."""
        if self._sub is None:
            raise RuntimeError("start() the pose source before reading it")
        wall, mono = time.time(), time.monotonic()
        for sample in self._sub.drain():
            self._counts["received"] += 1
            self._counts["without_attachment"] += sample.attachment is None
            robot = self.config.robot_of(sample.topic)
            if robot is None:
                self._counts["foreign"] += 1
                continue
            try:
                x, y, theta, stamp = self.messages.read_pose_stamped(sample.payload)
            except ValueError:
                self._counts["undecodable"] += 1
                continue
            a = sample.attachment  # None: a bare put, a source of its own
            gid, sequence = (None, -1) if a is None else (a.gid, a.sequence_number)
            if not self.sources.admit(robot, gid, sequence, sample.arrival):
                continue
            # judged by this machine's wall clock as it was when the sample arrived
            if self.gate.admit(robot, stamp, wall - (mono - sample.arrival), sample.arrival):
                self._latest[robot] = (x, y, theta, stamp, sample.arrival)
        now = time.monotonic()
        return {
            r: PoseSample(x, y, th, st, now - at)
            for r, (x, y, th, st, at) in sorted(self._latest.items())
            if not self.sources.doubted(r, now)
        }

    def ticks(self) -> Iterator[dict[int, PoseSample]]:
        """latest() at the configured rate, for ever: whatever arrived in between, the newest wins."""
        period = 1.0 / self.config.rate
        deadline = time.monotonic()
        while True:
            deadline += period
            time.sleep(max(0.0, deadline - time.monotonic()))
            deadline = max(deadline, time.monotonic() - period)  # after a stall, do not rush to catch up
            yield self.latest()

    def stats(self) -> dict[str, int]:
        return dict(
            self._counts, **self.gate.stats(), two_sources=self.sources.clashes.total(), robots=len(self._latest)
        )

    def robot_stats(self, robot: int) -> dict[str, int]:
        """One robot's poses dropped for their stamps or while two publishers clashed, and its source's restarts."""
        return dict(self.gate.robot_stats(robot), two_sources=self.sources.clashes[robot])
