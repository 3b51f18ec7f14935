"""ROS 2 over Zenoh as rmw_zenoh_cpp puts it on the wire: keys, attachments, liveliness tokens.

A message is a put of its CDR bytes on a topic key, with an attachment (sequence number, source timestamp,
gid); every node, publisher and subscription holds a liveliness token that ROS graph tools read. Layouts:
docs/ros2.md ("On the wire"). Only bytes here: CDR (through rosbags) is the caller's.
"""

from __future__ import annotations

import contextlib
import itertools
import re
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import xxhash
import zenoh

ADMIN_SPACE = "@ros2_lv"
CDR = zenoh.Encoding.APPLICATION_CDR
TYPE_HASH_NOT_SUPPORTED = "TypeHashNotSupported"  # what Humble's rmw_zenoh writes in place of a hash
# Reliable, volatile, keep-last 10 (rclcpp's default profile) in rmw_zenoh's compact form: a field
# equal to rmw_zenoh's own default (reliable, volatile, keep-last, depth 42, infinite times) is left empty.
DEFAULT_QOS = "::,10:,:,:,,"
GID_SIZE = 16
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"

_ATTACHMENT = struct.Struct(f"<qqB{GID_SIZE}s")
_ROS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv|action)/([A-Za-z][A-Za-z0-9_]*)$")
_NAME_CHUNK = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class RosNameError(ValueError):
    """A topic, namespace or type name that ROS 2 would not accept."""


def dds_type_name(ros_type: str) -> str:
    """`geometry_msgs/msg/Twist` -> `geometry_msgs::msg::dds_::Twist_`, the name rmw_zenoh puts in keys."""
    match = _ROS_TYPE.match(ros_type)
    if match is None:
        raise RosNameError(f"{ros_type!r} is not a ROS 2 type name like geometry_msgs/msg/Twist")
    package, kind, name = match.groups()
    return f"{package}::{kind}::dds_::{name}_"


def check_name(name: str, what: str = "topic") -> str:
    """A ROS 2 name (topic or namespace), relative or absolute; returned unchanged if valid."""
    if name in ("", "/") and what == "namespace":
        return name  # the root namespace
    if not all(_NAME_CHUNK.match(c) for c in name.removeprefix("/").split("/")):
        raise RosNameError(f"{what} {name!r} is not a ROS 2 name (letters, digits and '_', separated by '/')")
    return name


def qualified(topic: str, namespace: str = "/") -> str:
    """The fully qualified topic name: absolute names stay, relative ones go under the namespace."""
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"


def topic_key(domain: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The data key of a topic: `<domain>/<topic without leading slash>/<dds type name>/<type hash>`."""
    return f"{domain}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def mangle(name: str) -> str:
    """A name as one key chunk: every `/` becomes `%`; the empty name (or just `/`) is `%`."""
    return name.replace("/", "%") or "%"


@dataclass(frozen=True)
class NodeName:
    """A ROS 2 node as rmw_zenoh names it in its liveliness tokens."""

    domain: int
    zid: str  # its Zenoh session's id
    node_id: int
    namespace: str
    node: str
    enclave: str = "/"

    def head(self, entity_id: int, kind: str) -> str:
        """The part of a token every entity of the node shares, for one entity."""
        where = f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}"
        return f"{where}/{mangle(self.enclave)}/{mangle(self.namespace)}/{self.node}"


def node_token(name: NodeName) -> str:
    """The liveliness token of a node (its id stands as both node id and entity id)."""
    return name.head(name.node_id, NODE)


def entity_token(
    name: NodeName, entity_id: int, kind: str, topic: str, ros_type: str, type_hash: str, qos: str = DEFAULT_QOS
) -> str:
    """The liveliness token of a publisher (MP) or subscription (MS) of a node; `topic` fully qualified."""
    return f"{name.head(entity_id, kind)}/{mangle(topic)}/{dds_type_name(ros_type)}/{mangle(type_hash)}/{qos}"


def gid_of(token: str) -> bytes:
    """An entity's gid as rmw_zenoh_cpp derives it: the XXH3 128-bit hash of its liveliness token,
    low 64 bits then high 64 bits, each little-endian."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to every message; its subscribers drop a sample that has none."""

    sequence_number: int
    source_timestamp: int  # ns since the UNIX epoch
    gid: bytes

    def encode(self) -> bytes:
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"a gid has {GID_SIZE} bytes, not {len(self.gid)}")
        return _ATTACHMENT.pack(self.sequence_number, self.source_timestamp, GID_SIZE, self.gid)

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        if len(data) != _ATTACHMENT.size:
            raise ValueError(f"an rmw_zenoh attachment has {_ATTACHMENT.size} bytes, not {len(data)}")
        sequence_number, source_timestamp, gid_size, gid = _ATTACHMENT.unpack(data)
        if gid_size != GID_SIZE:
            raise ValueError(f"gid length byte is {gid_size}, not {GID_SIZE}")
        return cls(sequence_number, source_timestamp, gid)


@dataclass(frozen=True)
class RosSample:
    """One message as it arrived: CDR bytes, where from, its attachment (None: none, or malformed)."""

    domain: int
    topic: str  # fully qualified
    type_hash: str
    payload: bytes
    attachment: Attachment | None
    arrival: float  # time.monotonic() when it arrived


class _Declares:
    """A node, publisher or subscription: what it declared on its session, undeclared in order on close."""

    _declared: list[Any]

    def close(self) -> None:
        declared, self._declared = self._declared, []
        for thing in declared:
            thing.undeclare()


class RosNode(_Declares):
    """A ROS 2 node on a Zenoh session: its token, and the publishers and subscriptions it declares."""

    def __init__(
        self, session: zenoh.Session, name: str, domain: int = 0, namespace: str = "/", node_id: int = 0
    ) -> None:
        if not _NAME_CHUNK.match(name):
            raise RosNameError(f"node name {name!r} may hold only letters, digits and '_'")
        self.session = session
        self.domain = domain
        self.namespace = check_name(namespace, "namespace")
        self.zid = str(session.info.zid())
        self.entity_ids = itertools.count(node_id + 1)  # a fresh id for each publisher or subscription
        self.names = NodeName(domain, self.zid, node_id, self.namespace, name)
        self.token = node_token(self.names)
        self._declared = [session.liveliness().declare_token(self.token)]
        self._entities: list[RosPublisher | RosSubscriber] = []

    def publisher(self, topic: str, ros_type: str, type_hash: str, qos: str = DEFAULT_QOS) -> RosPublisher:
        pub = RosPublisher(self, qualified(check_name(topic), self.namespace), ros_type, type_hash, qos)
        self._entities.append(pub)
        return pub

    def subscriber(
        self, topic: str, ros_type: str, type_hash: str, any_domain: bool = False, capacity: int = 1024
    ) -> RosSubscriber:
        sub = RosSubscriber(self, topic, ros_type, type_hash, any_domain, capacity)
        self._entities.append(sub)
        return sub

    def close(self) -> None:
        """Undeclare every entity, then the node: ROS graph tools see them go."""
        for entity in self._entities:
            entity.close()
        self._entities.clear()
        super().close()


class RosPublisher(_Declares):
    """Puts CDR bytes on a topic's key with rmw_zenoh's attachment; holds an MP token meanwhile."""

    def __init__(self, node: RosNode, topic: str, ros_type: str, type_hash: str, qos: str = DEFAULT_QOS) -> None:
        self.topic = topic
        self.key = topic_key(node.domain, topic, ros_type, type_hash)
        self.token = entity_token(node.names, next(node.entity_ids), PUBLISHER, topic, ros_type, type_hash, qos)
        self.gid = gid_of(self.token)
        self.sequence_number = 0
        self._lock = threading.Lock()  # the watchdog and the control loop may publish at once
        self._publisher = node.session.declare_publisher(self.key, encoding=CDR)
        self._declared = [node.session.liveliness().declare_token(self.token), self._publisher]

    @property
    def heard(self) -> bool:
        """Whether a subscription on the topic is known to this session now (a put then reaches someone)."""
        status = self._publisher.matching_status  # a MatchingStatus (zenoh's stub says bool)
        return bool(status.matching)  # type: ignore[attr-defined]

    def publish(self, cdr: bytes) -> Attachment:
        """Send one message (CDR bytes with their 4-byte header); returns the attachment sent with it."""
        with self._lock:
            self.sequence_number += 1
            attachment = Attachment(self.sequence_number, time.time_ns(), self.gid)
            self._publisher.put(bytes(cdr), attachment=attachment.encode())
        return attachment


class RosSubscriber(_Declares):
    """Receives a topic of any type hash (Humble's too) and, with ``any_domain``, of any domain; ``topic``
    may hold Zenoh wildcards (`*`, or `$*` inside a name). Samples wait in a ring of ``capacity`` until
    drained. An exact topic and domain hold an MS token naming ``type_hash``, for ROS graph tools."""

    def __init__(
        self, node: RosNode, topic: str, ros_type: str, type_hash: str, any_domain: bool, capacity: int
    ) -> None:
        self.topic = qualified(topic, node.namespace)
        domain = "*" if any_domain else str(node.domain)
        self.key = f"{domain}/{self.topic.strip('/')}/{dds_type_name(ros_type)}/*"
        self.token: str | None = None
        self._declared = []
        if not any_domain and "*" not in self.topic:
            check_name(self.topic)
            self.token = entity_token(node.names, next(node.entity_ids), SUBSCRIPTION, self.topic, ros_type, type_hash)
            self._declared.append(node.session.liveliness().declare_token(self.token))
        self._ring: deque[tuple[float, str, bytes, bytes | None]] = deque(maxlen=capacity)
        self._declared.append(node.session.declare_subscriber(self.key, self._on_sample))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs on a zenoh thread: only copy out and keep (a deque's append is thread-safe).
        attachment = None if sample.attachment is None else sample.attachment.to_bytes()
        self._ring.append((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes(), attachment))

    def drain(self) -> list[RosSample]:
        """Every sample waiting, oldest first."""
        out = []
        while self._ring:
            arrival, key, payload, raw_attachment = self._ring.popleft()
            # a data key: <domain>/<topic without leading slash>/<dds type name>/<type hash>
            parts = key.split("/")
            if len(parts) < 4 or not parts[0].isdigit():  # not an rmw_zenoh key
                continue
            attachment = None
            with contextlib.suppress(ValueError):  # a malformed attachment: the message without it
                attachment = None if raw_attachment is None else Attachment.decode(raw_attachment)
            topic = "/" + "/".join(parts[1:-2])
            out.append(RosSample(int(parts[0]), topic, parts[-1], payload, attachment, arrival))
        return out
