"""Streaming MCAP writer with JSON messages and JSON-schema channels (what Foxglove opens).

Every channel has message encoding ``json`` and a schema with encoding ``jsonschema``.  Payloads
are Python dicts that may contain numpy scalars/arrays and NaN/inf; they are converted to JSON-safe
values (NaN/inf -> ``null``) before writing.

Also: :func:`read_mcap` / :func:`mcap_channels` (read back with mcap's reader, used by tests), and
helpers that build a ``foxglove.SceneUpdate`` message so the 3D panel shows the robots as discs.

No zenoh here: the recorder (a bus subscriber) calls this.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from sim.rundir import dumps_json, json_safe

__all__ = [
    "McapLog",
    "read_mcap",
    "mcap_channels",
    "SCENE_UPDATE_SCHEMA_NAME",
    "scene_update_schema",
    "scene_update",
]

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
    None: CompressionType.NONE,
}


class McapLog:
    """Append-only MCAP log.  Thread-safe (bus callbacks may arrive on several threads).

    ``McapLog(path)`` opens and starts the file; :meth:`close` (or leaving a ``with`` block)
    writes the summary section.  A file that was not closed is still readable by mcap's
    non-seeking reader up to the last complete chunk, but Foxglove wants a closed file.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        compression: str | None = "zstd",
        chunk_size: int = 1 << 20,
        profile: str = "",
        library: str = "pixelswarm",
    ):
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(k for k in _COMPRESSION if k)} or None")
        self.path = Path(path)
        self._fh = open(self.path, "wb")
        try:
            self._writer = Writer(self._fh, chunk_size=chunk_size, compression=_COMPRESSION[compression])
            self._writer.start(profile=profile, library=library)
        except BaseException:
            self._fh.close()
            raise
        self._lock = threading.Lock()
        self._schemas: dict[tuple[str, str], int] = {}  # (name, schema json) -> schema id
        self._channels: dict[str, tuple[int, int]] = {}  # topic -> (channel id, schema id)
        self._seq: dict[int, int] = {}
        self._closed = False
        self.message_count = 0

    # -- channels ----------------------------------------------------------------------------
    def add_channel(
        self,
        topic: str,
        schema_name: str,
        json_schema: dict,
        *,
        metadata: dict[str, str] | None = None,
    ) -> int:
        """Register (or look up) a channel; returns its id.

        Adding the same topic again with the same schema returns the existing id; with a
        different schema it raises ``ValueError``.  Identical schemas are stored once.
        """
        if not isinstance(json_schema, dict):
            raise TypeError("json_schema must be a dict")
        schema_text = json.dumps(json_safe(json_schema), sort_keys=True, separators=(",", ":"))
        key = (schema_name, schema_text)
        with self._lock:
            self._check_open()
            schema_id = self._schemas.get(key)
            if topic in self._channels:
                cid, sid = self._channels[topic]
                if sid != schema_id:
                    raise ValueError(f"topic {topic!r} already registered with a different schema")
                return cid
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=schema_name, encoding=SCHEMA_ENCODING, data=schema_text.encode("utf-8")
                )
                self._schemas[key] = schema_id
            cid = self._writer.register_channel(
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                schema_id=schema_id,
                metadata={str(k): str(v) for k, v in (metadata or {}).items()},
            )
            self._channels[topic] = (cid, schema_id)
            self._seq[cid] = 0
            return cid

    def channel_id(self, topic: str) -> int | None:
        """Id of an already registered topic, or None."""
        entry = self._channels.get(topic)
        return entry[0] if entry else None

    # -- messages ----------------------------------------------------------------------------
    def write(
        self,
        channel_id: int,
        log_time_ns: int,
        payload: dict,
        publish_time_ns: int | None = None,
    ) -> None:
        """Write one message; ``payload`` is converted to JSON (numpy -> lists, NaN -> null)."""
        data = dumps_json(payload).encode("utf-8")
        self.write_bytes(channel_id, log_time_ns, data, publish_time_ns)

    def write_bytes(
        self,
        channel_id: int,
        log_time_ns: int,
        data: bytes,
        publish_time_ns: int | None = None,
    ) -> None:
        """Write an already JSON-encoded message (e.g. bytes received off the bus) unchanged.

        The caller guarantees ``data`` is UTF-8 JSON without NaN/Infinity literals.
        """
        log_time_ns = int(log_time_ns)
        publish_time_ns = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        if log_time_ns < 0 or publish_time_ns < 0:
            raise ValueError("MCAP times are unsigned nanoseconds")
        with self._lock:
            self._check_open()
            if channel_id not in self._seq:
                raise KeyError(f"unknown channel id {channel_id}")
            seq = self._seq[channel_id]
            self._seq[channel_id] = (seq + 1) & 0xFFFFFFFF
            self._writer.add_message(
                channel_id=channel_id,
                log_time=log_time_ns,
                data=bytes(data),
                publish_time=publish_time_ns,
                sequence=seq,
            )
            self.message_count += 1

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """An MCAP metadata record (string -> string; other values are JSON-encoded)."""
        flat = {str(k): (v if isinstance(v, str) else dumps_json(v)) for k, v in data.items()}
        with self._lock:
            self._check_open()
            self._writer.add_metadata(name, flat)

    # -- lifecycle ---------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"McapLog {self.path} is closed")

    def close(self) -> None:
        """Finish the file (summary, indexes). Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
            finally:
                self._fh.close()

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


# ------------------------------------------------------------------------------------------------
# Reading back
# ------------------------------------------------------------------------------------------------


def read_mcap(path: str | os.PathLike, topics: Iterable[str] | None = None) -> dict[str, list[dict]]:
    """All messages by topic, decoded from JSON, in log-time order.

    Channels without messages appear with an empty list.  ``topics`` restricts the result.
    """
    wanted = None if topics is None else set(topics)
    out: dict[str, list[dict]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        if summary is not None:
            for ch in summary.channels.values():
                if wanted is None or ch.topic in wanted:
                    out.setdefault(ch.topic, [])
        for _schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
            if channel.message_encoding != MESSAGE_ENCODING:
                raise ValueError(f"channel {channel.topic!r} has encoding {channel.message_encoding!r}")
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out


def mcap_channels(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Per topic: ``schema_name``, ``schema_encoding``, ``message_encoding``, ``schema`` (parsed
    JSON schema), ``metadata`` and ``message_count`` (from the summary statistics)."""
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
    if summary is None:
        raise ValueError(f"{path}: no summary section (file not closed?)")
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    out: dict[str, dict[str, Any]] = {}
    for cid, ch in summary.channels.items():
        sc = summary.schemas.get(ch.schema_id)
        out[ch.topic] = {
            "channel_id": cid,
            "schema_name": sc.name if sc else "",
            "schema_encoding": sc.encoding if sc else "",
            "schema": json.loads(sc.data) if sc and sc.data else None,
            "message_encoding": ch.message_encoding,
            "metadata": dict(ch.metadata),
            "message_count": int(counts.get(cid, 0)),
        }
    return out


# ------------------------------------------------------------------------------------------------
# foxglove.SceneUpdate (robots as discs in Foxglove's 3D panel)
# ------------------------------------------------------------------------------------------------

SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"


def _num() -> dict:
    return {"type": "number"}


def _obj(title: str, props: dict, required: list[str] | None = None) -> dict:
    return {
        "title": title,
        "type": "object",
        "properties": props,
        "required": list(props) if required is None else required,
    }


def _vec3() -> dict:
    return _obj("foxglove.Vector3", {"x": _num(), "y": _num(), "z": _num()})


def _time() -> dict:
    return {
        "title": "time",
        "type": "object",
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
        },
    }


def _duration() -> dict:
    return {
        "title": "duration",
        "type": "object",
        "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
    }


def _pose() -> dict:
    quat = _obj("foxglove.Quaternion", {"x": _num(), "y": _num(), "z": _num(), "w": _num()})
    return _obj("foxglove.Pose", {"position": _vec3(), "orientation": quat})


def _color() -> dict:
    return _obj("foxglove.Color", {"r": _num(), "g": _num(), "b": _num(), "a": _num()})


def scene_update_schema() -> dict:
    """JSON schema for the subset of ``foxglove.SceneUpdate`` that :func:`scene_update` emits
    (entities with cylinders and arrows; deletions)."""
    cylinder = _obj(
        "foxglove.CylinderPrimitive",
        {
            "pose": _pose(),
            "size": _vec3(),
            "bottom_scale": _num(),
            "top_scale": _num(),
            "color": _color(),
        },
    )
    arrow = _obj(
        "foxglove.ArrowPrimitive",
        {
            "pose": _pose(),
            "shaft_length": _num(),
            "shaft_diameter": _num(),
            "head_length": _num(),
            "head_diameter": _num(),
            "color": _color(),
        },
    )
    kv = _obj("foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}})
    entity = _obj(
        "foxglove.SceneEntity",
        {
            "timestamp": _time(),
            "frame_id": {"type": "string"},
            "id": {"type": "string"},
            "lifetime": _duration(),
            "frame_locked": {"type": "boolean"},
            "metadata": {"type": "array", "items": kv},
            "cylinders": {"type": "array", "items": cylinder},
            "arrows": {"type": "array", "items": arrow},
        },
        required=["timestamp", "frame_id", "id", "lifetime", "frame_locked"],
    )
    deletion = _obj(
        "foxglove.SceneEntityDeletion",
        {
            "timestamp": _time(),
            "type": {"type": "integer", "enum": [0, 1]},
            "id": {"type": "string"},
        },
    )
    return {
        "title": SCENE_UPDATE_SCHEMA_NAME,
        "description": "An update to the entities displayed in a 3D scene (pixelswarm subset)",
        "type": "object",
        "properties": {
            "deletions": {"type": "array", "items": deletion},
            "entities": {"type": "array", "items": entity},
        },
        "required": ["deletions", "entities"],
    }


def _stamp(t_ns: int) -> dict:
    t_ns = int(t_ns)
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def scene_update(
    t_ns: int,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None = None,
    *,
    ids: Iterable[Any] | None = None,
    frame_id: str = "world",
    height: float = 0.05,
    heading: bool = True,
) -> dict:
    """A ``foxglove.SceneUpdate`` payload with one entity per robot: a disc (flat cylinder) in its
    LED colour (``color`` (N,3) uint8 RGB; grey if None) and a small heading arrow.
    Robots with non-finite poses are skipped.  Write it on a channel added with
    ``add_channel(topic, SCENE_UPDATE_SCHEMA_NAME, scene_update_schema())``."""
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    n = len(pose)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    rgb = (np.full((n, 3), 160, dtype=float) if color is None else np.asarray(color, dtype=float).reshape(n, 3)) / 255.0
    ids = [str(i) for i in (range(n) if ids is None else ids)]
    stamp = _stamp(t_ns)
    entities = []
    for i in range(n):
        x, y, th = pose[i]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        th = float(th) if np.isfinite(th) else 0.0
        q = {"x": 0.0, "y": 0.0, "z": float(np.sin(th / 2)), "w": float(np.cos(th / 2))}
        r = float(radius[i])
        col = {"r": float(rgb[i, 0]), "g": float(rgb[i, 1]), "b": float(rgb[i, 2]), "a": 1.0}
        ent = {
            "timestamp": stamp,
            "frame_id": frame_id,
            "id": f"robot/{ids[i]}",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [],
            "cylinders": [
                {
                    "pose": {"position": {"x": float(x), "y": float(y), "z": height / 2}, "orientation": q},
                    "size": {"x": 2 * r, "y": 2 * r, "z": height},
                    "bottom_scale": 1.0,
                    "top_scale": 1.0,
                    "color": col,
                }
            ],
            "arrows": [],
        }
        if heading:
            ent["arrows"].append(
                {
                    "pose": {"position": {"x": float(x), "y": float(y), "z": height + 0.001}, "orientation": q},
                    "shaft_length": 0.6 * r,
                    "shaft_diameter": 0.15 * r,
                    "head_length": 0.35 * r,
                    "head_diameter": 0.35 * r,
                    "color": {"r": 0.1, "g": 0.1, "b": 0.1, "a": 1.0},
                }
            )
        entities.append(ent)
    return {"deletions": [], "entities": entities}
