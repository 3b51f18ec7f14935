"""pixelswarm's per-tick message kinds as protobuf ``pixelswarm.<Kind>`` for log.mcap, whose schemas the file holds
(Foxglove decodes them with no pixelswarm code): the fixed fields, each table as packed columns of the wire's
exact values, and ``key``, the bus key. Details: docs/outputs.md (log.mcap)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from transport.codec import Bid, Boards, Commands, Message, Poses, States, Truth

PACKAGE = "pixelswarm"
_F = descriptor_pb2.FieldDescriptorProto
# struct format characters and numpy types -> protobuf field types (the wire's own widths)
_BY_STRUCT = {"I": _F.TYPE_UINT32, "H": _F.TYPE_UINT32, "B": _F.TYPE_UINT32, "i": _F.TYPE_INT32}
_BY_STRUCT |= {"Q": _F.TYPE_UINT64, "f": _F.TYPE_FLOAT, "d": _F.TYPE_DOUBLE}
# numpy column types -> (protobuf field type, its packed values' type; VARINT for narrow integers: a byte or two
# where fixed32 takes four; wider ones fixed-width, so a large column goes in as numpy's own bytes)
VARINT = "varint"
_BY_DTYPE = {"u1": (_F.TYPE_UINT32, VARINT), "u2": (_F.TYPE_UINT32, VARINT), "u4": (_F.TYPE_FIXED32, "<u4")}
_BY_DTYPE |= {"i4": (_F.TYPE_SFIXED32, "<i4"), "u8": (_F.TYPE_FIXED64, "<u8")}
_BY_DTYPE |= {"f4": (_F.TYPE_FLOAT, "<f4"), "f8": (_F.TYPE_DOUBLE, "<f8")}
LENGTH_DELIMITED = 2  # protobuf's wire type of packed repeated fields, nested messages and bytes

# The world's poses are float64; logged as float32, as every pose crosses the bus (trajectory.npz keeps them whole)
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


def varint(value: int) -> bytes:
    """An unsigned integer as protobuf's varint: seven bits a byte, low first, the top bit set but on the last."""
    out = bytearray()
    while value > 0x7F:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _varints(values: np.ndarray) -> bytes:
    """Unsigned integers below 2**21 (uint8 and uint16 columns) as :func:`varint` s, one after the other."""
    if not len(values) or values.max() < 1 << 7:  # most columns: a byte each
        return values.astype(np.uint8).tobytes()
    v = values.astype(np.uint32)
    more = [v >= 1 << 7, v >= 1 << 14]  # whether a value takes a second, a third byte
    size = 1 + more[0].view(np.uint8) + more[1].view(np.uint8)
    first = np.cumsum(size, dtype=np.int64) - size  # where each value's bytes begin
    out = np.empty(int(first[-1] + size[-1]), np.uint8)
    out[first] = (v & 0x7F).astype(np.uint8) | more[0].view(np.uint8) << 7
    out[first[more[0]] + 1] = ((v[more[0]] >> 7) & 0x7F).astype(np.uint8) | more[1][more[0]].view(np.uint8) << 7
    out[first[more[1]] + 2] = (v[more[1]] >> 14).astype(np.uint8)
    return out.tobytes()


def length_delimited(number: int, body: bytes) -> bytes:
    """Field ``number`` of a message holding ``body`` (a nested message, bytes, a packed column)."""
    return varint(number << 3 | LENGTH_DELIMITED) + varint(len(body)) + body


FEW_ROWS = 16  # a table of at most this many rows goes through protobuf's setters: a column's
# numpy bytes cost more than setting a few values, and less than setting many


@dataclass(frozen=True)
class Table:
    """A message's table as a nested message of a packed column per field (``columns``: name, number, packed
    type), or bytes when it has none (Boards.known)."""

    name: str
    number: int
    rows_of: Callable[[Any], np.ndarray]
    columns: tuple[tuple[str, int, str], ...]

    def packed(self, rows: np.ndarray) -> bytes:
        """The table as its field's bytes, each column written whole."""
        fields = b"".join(
            length_delimited(k, _varints(rows[name]) if t == VARINT else rows[name].astype(t).tobytes())
            for name, k, t in self.columns
        )
        return length_delimited(self.number, fields)


@dataclass(frozen=True)
class LoggedKind:
    """One kind's protobuf message class and schema, and how a decoded message fills it."""

    name: str  # the schema's (and message's) full name, pixelswarm.<Kind>
    scalars: tuple[str, ...]  # the fixed fields, in order
    tables: tuple[Table, ...]
    message_class: Any
    descriptor_set: bytes  # the schema as MCAP stores it: a serialized FileDescriptorSet

    def encode(self, message: Message, key: str) -> bytes:
        # protobuf reads a message's fields in any order: the library's fields, then the large tables
        out = self.message_class(key=key, **{name: getattr(message, name) for name in self.scalars})
        large = []
        for table in self.tables:
            rows = table.rows_of(message)
            if not table.columns:
                setattr(out, table.name, np.ascontiguousarray(rows, np.uint8).tobytes())
            elif len(rows) <= FEW_ROWS:
                columns = getattr(out, table.name)
                for name, _, _ in table.columns:
                    getattr(columns, name).extend(rows[name].tolist())
            else:
                large.append(table.packed(rows))
        return out.SerializeToString() + b"".join(large)


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
    encoders = []
    for number, (table, (dtype, rows_of)) in enumerate(tables.items(), start=len(scalars) + 1):
        if dtype is None:
            _field(message, table, number, _F.TYPE_BYTES)
            encoders.append(Table(table, number, rows_of, ()))
            continue
        nested = message.nested_type.add(name=table.capitalize())
        columns = []
        for k, column in enumerate(dtype.names or (), start=1):
            field_type, packed = _BY_DTYPE[dtype[column].str[1:]]
            _field(nested, column, k, field_type, repeated=True)
            columns.append((column, k, packed))
        field = message.field.add(name=table, number=number, type=_F.TYPE_MESSAGE)
        field.type_name = f".{PACKAGE}.{name}.{nested.name}"
        encoders.append(Table(table, number, rows_of, tuple(columns)))
    _field(message, "key", number + 1, _F.TYPE_STRING)
    pool = descriptor_pool.DescriptorPool()  # its own: nothing else of ours is a protobuf type
    pool.Add(file)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{PACKAGE}.{name}"))
    descriptor_set = descriptor_pb2.FileDescriptorSet(file=[file]).SerializeToString()
    return LoggedKind(f"{PACKAGE}.{name}", scalars, tuple(encoders), cls, descriptor_set)


@functools.cache
def logged_kinds() -> dict[type[Message], LoggedKind]:
    """Every kind logged as protobuf, by its class."""
    kinds: dict[type[Message], LoggedKind] = {
        frame: _build(frame, {"records": (frame.RECORD, lambda m: m.records)})
        for frame in (Poses, States, Commands, Bid)
    }
    boards = {"words": (Boards.WORD, lambda m: m.words), "known": (None, lambda m: m.known)}
    kinds[Boards] = _build(Boards, boards | {"records": (Boards.RECORD, lambda m: m.records)})
    kinds[Truth] = _build(Truth, {"records": (TRUTH_ROW, _truth_rows)})
    return kinds


def kind_of(message: Message) -> LoggedKind | None:
    """The protobuf form of this message's kind, or None for a kind logged as JSON."""
    return logged_kinds().get(type(message))
