"""pixelswarm's per-tick message kinds as protobuf, for log.mcap: documented custom schemas.

The kinds a run sends every tick carry tables of records (a robot's pose, state or command, an
auction record, a world truth row). As JSON each number cost its decimal digits (a float32 written
as the double it widens to: ~19 characters, and digits compress badly), which made them most of
``log.mcap``. Here each becomes a protobuf message ``pixelswarm.<Kind>`` (the class name in
:mod:`transport.codec`) whose schema, a ``FileDescriptorSet``, is stored in the file, so Foxglove and
``mcap``'s protobuf support decode it with no pixelswarm code:

- the kind's fixed fields, in their wire types (``uint32``, ``uint64``, ``float``, ``double``);
- each table as a nested message with one packed repeated field per column, in the column's wire
  type (a float32 stays a ``float``: the log holds exactly what crossed the bus), the JSON log's
  ``records: {column: [...]}`` shape; ``Boards`` has ``words`` and ``records``, and ``known`` as
  bytes (the bit rows one after the other, ``(robots + 7) // 8`` bytes each);
- ``Truth`` (the world's true state, sim only) has a table ``records`` of a row per robot: ``x``,
  ``y``, ``theta`` (float, as poses cross the bus; the world's doubles are in trajectory.npz), ``vx``,
  ``vy``, ``r``, ``g``, ``b``, ``applied``;
- ``key``: the bus key it came on (who sent it).

Docs: docs/outputs.md (log.mcap).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from transport.codec import Bid, Boards, Commands, Message, Poses, States, Truth

__all__ = ["PACKAGE", "LoggedKind", "kind_of", "logged_kinds"]

PACKAGE = "pixelswarm"
_F = descriptor_pb2.FieldDescriptorProto
# struct format characters and numpy types -> protobuf field types (the wire's own widths)
_BY_STRUCT = {"I": _F.TYPE_UINT32, "H": _F.TYPE_UINT32, "B": _F.TYPE_UINT32, "i": _F.TYPE_INT32}
_BY_STRUCT |= {"Q": _F.TYPE_UINT64, "f": _F.TYPE_FLOAT, "d": _F.TYPE_DOUBLE}
_BY_DTYPE = {"u1": _F.TYPE_UINT32, "u2": _F.TYPE_UINT32, "u4": _F.TYPE_UINT32, "i4": _F.TYPE_INT32}
_BY_DTYPE |= {"u8": _F.TYPE_UINT64, "f4": _F.TYPE_FLOAT, "f8": _F.TYPE_DOUBLE}

# The world's poses are float64; logged as float32, as every pose crosses the bus (0.24 um at 4 m). Their
# noise-like low bytes were a quarter of the log, and trajectory.npz keeps them whole.
TRUTH_ROW = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("theta", "<f4"), ("vx", "<f4"), ("vy", "<f4")]
    + [("r", "u1"), ("g", "u1"), ("b", "u1"), ("applied", "<u4")]
)


def _truth_rows(m: Truth) -> np.ndarray:
    rows = np.empty(len(m.pose), TRUTH_ROW)
    rows["x"], rows["y"], rows["theta"] = np.asarray(m.pose, float).reshape(-1, 3).T
    rows["vx"], rows["vy"] = np.asarray(m.velocity, float).reshape(-1, 2).T
    rows["r"], rows["g"], rows["b"] = np.asarray(m.color).reshape(-1, 3).T
    rows["applied"] = m.applied
    return rows


@dataclass(frozen=True)
class LoggedKind:
    """One kind's protobuf message class and schema, and how a decoded message fills it."""

    name: str  # the schema's (and message's) full name, pixelswarm.<Kind>
    scalars: tuple[str, ...]  # the fixed fields, in order
    tables: dict[str, Callable[[Any], np.ndarray]]  # table name -> its records of a message
    message_class: Any
    descriptor_set: bytes  # the schema as MCAP stores it: a serialized FileDescriptorSet

    def encode(self, message: Message, key: str) -> bytes:
        out = self.message_class(key=key, **{name: getattr(message, name) for name in self.scalars})
        for table, rows_of in self.tables.items():
            rows = rows_of(message)
            if rows.dtype.names is None:  # Boards.known: its bit rows as bytes
                setattr(out, table, np.ascontiguousarray(rows, np.uint8).tobytes())
                continue
            columns = getattr(out, table)
            for column in rows.dtype.names:
                getattr(columns, column).extend(rows[column].tolist())
        return out.SerializeToString()


def _field(message: Any, name: str, number: int, kind: int, repeated: bool = False) -> None:
    field = message.field.add(name=name, number=number, type=kind)
    field.label = _F.LABEL_REPEATED if repeated else _F.LABEL_OPTIONAL  # proto3: repeated scalars packed


def _build(kind: type[Message], tables: dict[str, tuple[np.dtype | None, Callable[[Any], np.ndarray]]]) -> LoggedKind:
    name = kind.__name__
    codes = kind._fixed.format.lstrip("<")
    scalars = kind.field_names()[: len(codes)]  # the fixed part: the fields before the tables
    file = descriptor_pb2.FileDescriptorProto(name=f"{PACKAGE}/{name}.proto", package=PACKAGE, syntax="proto3")
    message = file.message_type.add(name=name)
    for number, (field, code) in enumerate(zip(scalars, codes), start=1):
        _field(message, field, number, _BY_STRUCT[code])
    number = len(scalars)
    for table, (dtype, _) in tables.items():
        number += 1
        if dtype is None:
            _field(message, table, number, _F.TYPE_BYTES)
            continue
        nested = message.nested_type.add(name=table.capitalize())
        for k, column in enumerate(dtype.names or (), start=1):
            _field(nested, column, k, _BY_DTYPE[dtype[column].str[1:]], repeated=True)
        field = message.field.add(name=table, number=number, type=_F.TYPE_MESSAGE)
        field.type_name = f".{PACKAGE}.{name}.{nested.name}"
    _field(message, "key", number + 1, _F.TYPE_STRING)
    pool = descriptor_pool.DescriptorPool()  # its own: nothing else of ours is a protobuf type
    pool.Add(file)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{PACKAGE}.{name}"))
    descriptor_set = descriptor_pb2.FileDescriptorSet(file=[file]).SerializeToString()
    getters = {table: getter for table, (_, getter) in tables.items()}
    return LoggedKind(f"{PACKAGE}.{name}", scalars, getters, cls, descriptor_set)


def _records(m: Any) -> np.ndarray:
    return m.records


def logged_kinds() -> dict[type[Message], LoggedKind]:
    """Every kind logged as protobuf, by its class."""
    if not _KINDS:
        for frame in (Poses, States, Commands, Bid):
            _KINDS[frame] = _build(frame, {"records": (frame.RECORD, _records)})
        _KINDS[Boards] = _build(
            Boards,
            {
                "words": (Boards.WORD, lambda m: m.words),
                "known": (None, lambda m: m.known),
                "records": (Boards.RECORD, _records),
            },
        )
        _KINDS[Truth] = _build(Truth, {"records": (TRUTH_ROW, _truth_rows)})
    return _KINDS


_KINDS: dict[type[Message], LoggedKind] = {}


def kind_of(message: Message) -> LoggedKind | None:
    """The protobuf form of this message's kind, or None for a kind logged as JSON."""
    return logged_kinds().get(type(message))
