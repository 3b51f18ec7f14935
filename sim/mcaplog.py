"""Streaming MCAP writer with JSON messages and JSON-schema channels (what Foxglove opens).

Every channel has message encoding ``json`` and a schema with encoding ``jsonschema``.  Payloads
are Python dicts that may contain numpy scalars/arrays and NaN/inf; they are converted to JSON-safe
values (NaN/inf -> ``null``) before writing.

Also: :func:`read_mcap` / :func:`mcap_channels` (read back with mcap's reader, used by tests); the
``foxglove.SceneUpdate`` schema and messages (robots as discs in the 3D panel) are in :mod:`sim.foxglove`.

No zenoh here: the recorder (a bus subscriber) calls this.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from sim.foxglove import SCENE_UPDATE_SCHEMA_NAME, scene_update, scene_update_schema
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

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS: a process killed outright later
        leaves a file whose chunks up to here mcap's reader reads (see :func:`read_mcap`)."""
        with self._lock:
            if not self._closed:
                self._writer.flush()

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

    Channels without messages appear with an empty list.  ``topics`` restricts the result.  A file
    that was never closed (its writer was killed) is read up to its last flushed chunk.
    """
    wanted = None if topics is None else set(topics)
    out: dict[str, list[dict]] = {}
    if not is_closed_mcap(path):
        return _read_unfinished(path, wanted)
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


def is_closed_mcap(path: str | os.PathLike) -> bool:
    """Whether the file ends with MCAP's closing magic (its writer finished it)."""
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        if fh.tell() < 2 * len(MCAP0_MAGIC):
            return False
        fh.seek(-len(MCAP0_MAGIC), os.SEEK_END)
        return fh.read() == MCAP0_MAGIC


def _read_unfinished(path: str | os.PathLike, wanted: set[str] | None) -> dict[str, list[dict]]:
    """The messages of an unfinished file, read front to back until it ends mid-record."""
    out: dict[str, list[tuple[int, dict]]] = {}
    with open(path, "rb") as fh:
        try:
            for _schema, channel, message in NonSeekingReader(fh).iter_messages(log_time_order=False):
                if wanted is None or channel.topic in wanted:
                    out.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
        except EndOfFile:
            pass  # the chunk in progress when the writer died
    return {topic: [m for _, m in sorted(rows, key=lambda r: r[0])] for topic, rows in out.items()}


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
