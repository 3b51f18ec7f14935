"""The run's MCAP log, written through Foxglove's SDK: JSON channels (``jsonschema``), Foxglove's schemas and
sim.outputs.logschema's as protobuf, all in one SDK context that :meth:`McapLog.serve` can stream live; read
back with mcap's own reader (:func:`read_mcap`, :func:`mcap_channels`)."""

from __future__ import annotations

import contextlib
import json
import os
import struct
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from google.protobuf.descriptor import FieldDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from google.protobuf.message import Message
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Schema
from mcap.writer import MCAP0_MAGIC
from mcap_protobuf.decoder import DecoderFactory

from sim.outputs.rundir import dumps_json

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
PROTOBUF = "protobuf"
LOOPBACK = "127.0.0.1"

_COMPRESSION = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, "none": None, None: None}


class McapLog(contextlib.AbstractContextManager["McapLog"]):
    """Append-only MCAP log, thread-safe; :meth:`close` writes the summary section Foxglove wants (an
    unclosed file is readable up to its last flushed chunk)."""

    def __init__(self, path: str | os.PathLike, *, compression: str | None = "zstd"):
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(k for k in _COMPRESSION if k)} or None")
        self.path = Path(path)
        self._context = foxglove.Context()
        # compressed on the caller's thread: the recorder has a core to share
        options = MCAPWriteOptions(compression=_COMPRESSION[compression], chunk_size=1 << 20, compression_threads=0)
        self._writer = foxglove.open_mcap(
            self.path, allow_overwrite=True, context=self._context, writer_options=options
        )
        self._lock = threading.Lock()
        self._channels: dict[str, tuple[int, Any]] = {}  # topic -> (channel id, schema key)
        self._by_id: dict[int, foxglove.Channel] = {}
        self._server: Any = None
        self.closed = False
        self.message_count = 0

    def add_channel(self, topic: str, schema_name: str, json_schema: dict) -> int:
        """Register (or look up: ValueError if with another schema) a JSON channel; returns its id."""
        if not isinstance(json_schema, dict):
            raise TypeError("json_schema must be a dict")
        schema_text = dumps_json(json_schema, sort_keys=True)
        schema = foxglove.Schema(name=schema_name, encoding=SCHEMA_ENCODING, data=schema_text.encode("utf-8"))
        return self._add(topic, (schema_name, schema_text), MESSAGE_ENCODING, schema)

    def add_foxglove_channel(self, topic: str, message_type: Any) -> int:
        """Register (or look up) a channel of a :mod:`foxglove.messages` type, e.g. ``SceneUpdate``."""
        schema = message_type.get_schema()
        return self._add(topic, (schema.name, schema.encoding), schema.encoding, schema)

    def add_protobuf_channel(self, topic: str, schema_name: str, descriptor_set: bytes) -> int:
        """Register (or look up) a protobuf channel of our own schema (sim.outputs.logschema)."""
        schema = foxglove.Schema(name=schema_name, encoding=PROTOBUF, data=descriptor_set)
        return self._add(topic, (schema_name, PROTOBUF), PROTOBUF, schema)

    def _add(self, topic: str, key: Any, encoding: str, schema: Any) -> int:
        with self._lock:
            self._check_open()
            if topic in self._channels:
                cid, known = self._channels[topic]
                if known != key:
                    raise ValueError(f"topic {topic!r} already registered with a different schema")
                return cid
            channel = foxglove.Channel(
                topic, message_encoding=encoding, schema=schema, metadata={}, context=self._context
            )
            cid = channel.id()
            self._channels[topic] = (cid, key)
            self._by_id[cid] = channel
            return cid

    def write_bytes(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        """Write an already encoded message unchanged (JSON: UTF-8, without NaN/Infinity literals)."""
        log_time_ns = int(log_time_ns)
        if log_time_ns < 0:
            raise ValueError("MCAP times are unsigned nanoseconds")
        with self._lock:
            self._check_open()
            channel = self._by_id.get(channel_id)
            if channel is None:
                raise KeyError(f"unknown channel id {channel_id}")
            channel.log(bytes(data), log_time=log_time_ns)
            self.message_count += 1

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """An MCAP metadata record (string -> string; other values are JSON-encoded)."""
        flat = {str(k): (v if isinstance(v, str) else dumps_json(v)) for k, v in data.items()}
        with self._lock:
            self._check_open()
            self._writer.write_metadata(name, flat)

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS: a kill later leaves it readable."""
        with self._lock:
            if not self.closed:
                self._writer.flush()

    def serve(self, port: int = 0) -> int:
        """Stream every channel live over Foxglove's WebSocket protocol on 127.0.0.1 (``port`` 0: a free
        one) until :meth:`close`; returns the port."""
        with self._lock:
            self._check_open()
            if self._server is None:
                self._server = foxglove.start_server(name="pixelswarm", host=LOOPBACK, port=port, context=self._context)
            return int(self._server.port)

    def _check_open(self) -> None:
        if self.closed:
            raise ValueError(f"McapLog {self.path} is closed")

    def close(self) -> None:
        """Finish the file (summary, indexes) and stop the live server. Idempotent."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._writer.close()
            finally:
                for channel in self._by_id.values():
                    channel.close()
                if self._server is not None:
                    self._server.stop()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


def proto_to_dict(message: Message) -> dict[str, Any]:
    """A protobuf message as the dict Foxglove's JSON schema describes: every field (default when unset),
    times as ``{"sec", "nsec"}``, enums as numbers."""
    out: dict[str, Any] = {}
    for field in message.DESCRIPTOR.fields:
        value = getattr(message, field.name)
        if field.message_type is not None and field.message_type.GetOptions().map_entry:
            out[field.name] = {k: _proto_value(v) for k, v in value.items()}
        elif _is_repeated(field):
            out[field.name] = [_proto_value(v) for v in value]
        else:
            out[field.name] = _proto_value(value)
    return out


def _is_repeated(field: FieldDescriptor) -> bool:
    repeated = getattr(field, "is_repeated", None)  # protobuf >= 6; label before it
    return bool(repeated) if repeated is not None else field.label == FieldDescriptor.LABEL_REPEATED


def _proto_value(value: Any) -> Any:
    if not isinstance(value, Message):  # a number, string, bytes or enum
        return value
    if value.DESCRIPTOR.full_name in ("google.protobuf.Timestamp", "google.protobuf.Duration"):
        return {"sec": value.seconds, "nsec": value.nanos}
    return proto_to_dict(value)


class _Decoders(DecoderFactory):
    """Message bytes -> dict for mcap's reader: JSON parsed, protobuf by the file's schema (:func:`proto_to_dict`)."""

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any] | None:
        if message_encoding == MESSAGE_ENCODING:
            return json.loads
        decode = super().decoder_for(message_encoding, schema)
        return None if decode is None else lambda data: proto_to_dict(decode(data))


def read_mcap(path: str | os.PathLike, topics: Iterable[str] | None = None) -> dict[str, list[dict]]:
    """All messages (of ``topics``) by topic, decoded, in log-time order; empty channels too. A file never
    closed (its writer was killed) is read up to its last flushed chunk."""
    wanted = None if topics is None else set(topics)
    if not is_closed_mcap(path):
        return _read_unfinished(path, wanted)
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[_Decoders()])
        summary = reader.get_summary()
        channels = summary.channels.values() if summary is not None else ()
        out: dict[str, list[dict]] = {ch.topic: [] for ch in channels if wanted is None or ch.topic in wanted}
        for _, channel, _, decoded in reader.iter_decoded_messages(topics=wanted):
            out.setdefault(channel.topic, []).append(decoded)
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
        reader = NonSeekingReader(fh, decoder_factories=[_Decoders()])
        try:
            for _, channel, message, decoded in reader.iter_decoded_messages(topics=wanted, log_time_order=False):
                out.setdefault(channel.topic, []).append((message.log_time, decoded))
        except (McapError, struct.error):
            pass  # the record in progress when the writer died (cut inside a length: struct.error)
    return {topic: [m for _, m in sorted(rows, key=lambda r: r[0])] for topic, rows in out.items()}


def mcap_channels(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Per topic of a closed file: its channel id, schema (name, encoding, parsed), message encoding,
    metadata and message count."""
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
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
            "schema": _schema_of(sc),
            "message_encoding": ch.message_encoding,
            "metadata": dict(ch.metadata),
            "message_count": int(counts.get(cid, 0)),
        }
    return out


def _schema_of(schema: Any) -> Any:
    """A JSON schema parsed; a protobuf schema as its ``FileDescriptorSet``."""
    if schema is None or not schema.data:
        return None
    return FileDescriptorSet.FromString(schema.data) if schema.encoding == PROTOBUF else json.loads(schema.data)
