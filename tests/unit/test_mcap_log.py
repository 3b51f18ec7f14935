"""log.mcap's channels (sim.outputs.recorder, sim.outputs.logschema, sim.outputs.mcaplog): every channel a Foxglove schema or
a documented pixelswarm one, read back with the `mcap` package's own protobuf support and Foxglove's
compiled schemas, without pixelswarm's reader; the per-tick kinds exactly as they crossed the bus.

The recorder is fed encoded messages in-process (no zenoh): what it logs is what is under test."""

from __future__ import annotations

import json

import numpy as np
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate as FoxgloveSceneUpdate
from google.protobuf.json_format import MessageToDict
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from sim.outputs.logschema import logged_kinds
from sim.outputs.recorder import SCENE_TOPIC, Recorder
from tests.support.fake_bus import RecorderBus
from transport.codec import Bid, Boards, Commands, Event, Poses, States, Tick, Truth

N = 6
PER_TICK = {"/pose": Poses, "/state": States, "/cmd": Commands, "/auction": Bid, "/boards": Boards, "/sim/truth": Truth}


def _table(dtype: np.dtype, rows: int, rng: np.random.Generator) -> np.ndarray:
    out = np.zeros(rows, dtype)
    for name in dtype.names or ():
        kind = out[name].dtype
        size = out[name].shape
        if kind.kind == "f":
            out[name] = rng.normal(0.0, 2.0, size).astype(kind)  # float32 columns: every bit kept?
        else:
            out[name] = rng.integers(0, min(np.iinfo(kind).max, 1000), size, endpoint=True).astype(kind)
    return out


def _messages(rng: np.random.Generator) -> dict[str, tuple[str, object]]:
    """One message of each kind logged as protobuf, with its key, and two logged as JSON."""
    keys = RecorderBus().keys
    states = _table(States.RECORD, N, rng)
    states["robot"], states["radius"] = np.arange(N), 0.05
    boards = _table(Boards.WORD, 3, rng)
    boards["flags"] = Boards.FRESH | Boards.GROWN
    boards["records"] = [1, 0, 2]
    records = _table(Boards.RECORD, 3, rng)
    records["goal"] = [0, 4, 2]
    commands = _table(Commands.RECORD, N, rng)
    commands["mode"] = np.arange(N) % 2  # velocity or wheel speeds: the codec refuses other modes
    pose = np.column_stack([rng.uniform(0, 4, (N, 2)), np.zeros(N)])  # float64, as the world has it
    truth = Truth(7, 0.7, 0.12, N, pose, rng.normal(0, 0.1, (N, 2)).astype(np.float32).astype(float))
    truth.color, truth.applied = rng.integers(0, 256, (N, 3)).astype(np.uint8), np.full(N, 7, np.uint32)
    return {
        "/clock": (keys.clock, Tick(7, 0.7, 0.1, 1)),
        "/pose": (keys.poses, Poses(7, 0.7, _table(Poses.RECORD, N, rng))),
        "/state": (keys.states(0), States(7, 0.7, states)),
        "/cmd": (keys.cmd(0), Commands(7, 0.7, commands)),
        "/auction": (keys.auction(1, 0), Bid(1, 4, 0, 9, 2**63 + 5, 5, _table(Bid.RECORD, 5, rng))),
        "/boards": (
            keys.boards(1, 0),
            Boards(1, 4, 0, 3, 5, N, 3, boards, rng.integers(0, 256, (3, 1), np.uint8), records),
        ),
        "/sim/truth": (keys.truth, truth),
        "/event": (keys.event, Event({"what": "end", "reason": "converged"})),
    }


@pytest.fixture
def log(tmp_path):
    """A recorder's log of one message of each kind (the truth twice: a scene per tick)."""
    rng = np.random.default_rng(11)
    sent = _messages(rng)
    bus = RecorderBus()
    rec = Recorder(bus, robots=N, tolerance=0.01, log_path=str(tmp_path / "log.mcap"))
    rec.heading = False  # holonomic robots: their heading never changes
    bus.raw.items = [(key, msg.encode(), 100.0 + k) for k, (key, msg) in enumerate(sent.values())]
    rec.poll()
    rec.close_log()
    return tmp_path / "log.mcap", sent


class JsonDecoders(McapDecoderFactory):
    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


def _read(path) -> dict[str, tuple[object, object, list]]:
    """Per topic: schema, channel, and the messages decoded by mcap's own protobuf support (or JSON)."""
    out: dict[str, tuple[object, object, list]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory(), JsonDecoders()])
        for schema, channel, _, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, (schema, channel, []))[2].append(decoded)
    return out


def test_every_channel_is_a_foxglove_schema_or_a_documented_pixelswarm_one(log):
    path, sent = log
    channels = _read(path)
    assert set(channels) == set(sent) | {SCENE_TOPIC}
    for topic, (schema, channel, _) in channels.items():
        if topic == SCENE_TOPIC:
            assert (schema.name, schema.encoding, channel.message_encoding) == (
                "foxglove.SceneUpdate",
                "protobuf",
                "protobuf",
            )
        elif topic in PER_TICK:
            name = f"pixelswarm.{PER_TICK[topic].__name__}"
            assert (schema.name, schema.encoding, channel.message_encoding) == (name, "protobuf", "protobuf")
        else:  # the low-rate kinds: JSON with a JSON schema of the same name pattern
            assert schema.name.startswith("pixelswarm.") and (schema.encoding, channel.message_encoding) == (
                "jsonschema",
                "json",
            )
            assert json.loads(schema.data)["type"] == "object"
    assert set(PER_TICK.values()) == set(logged_kinds())  # every protobuf kind is under test here


@pytest.mark.parametrize("topic", sorted(set(PER_TICK) - {"/sim/truth"}))
def test_a_per_tick_kind_reads_back_exactly_as_it_crossed_the_bus(log, topic):
    path, sent = log
    key, msg = sent[topic]
    (_, _, (decoded,)) = _read(path)[topic]
    got = MessageToDict(decoded, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
    assert got["key"] == key
    for name in msg.field_names():
        value = getattr(msg, name)
        if isinstance(value, np.ndarray) and value.dtype.names:  # a table: a packed column per field
            for column in value.dtype.names:
                logged = np.array(getattr(getattr(decoded, name), column), value.dtype[column])
                np.testing.assert_array_equal(logged, value[column], err_msg=f"{topic} {name}.{column}")
        elif isinstance(value, np.ndarray):  # Boards.known: its bit rows
            assert getattr(decoded, name) == value.tobytes()
        else:
            assert getattr(decoded, name) == pytest.approx(value, rel=1e-7), name


def test_the_truth_is_logged_a_row_per_robot_with_poses_as_float32(log):
    path, sent = log
    _, truth = sent["/sim/truth"]
    (_, _, (decoded,)) = _read(path)["/sim/truth"]
    assert (decoded.tick, decoded.count) == (7, N) and decoded.min_clearance == np.float32(0.12)
    rows = decoded.records
    for k, column in enumerate(("x", "y", "theta")):
        np.testing.assert_array_equal(getattr(rows, column), truth.pose[:, k].astype(np.float32))
    np.testing.assert_array_equal(np.column_stack([rows.vx, rows.vy]), truth.velocity)  # float32 on the wire
    np.testing.assert_array_equal(np.column_stack([rows.r, rows.g, rows.b]), truth.color)
    assert list(rows.applied) == [7] * N


def test_the_scene_of_robots_that_never_turn_has_no_heading_arrows(log):
    path, sent = log
    _, truth = sent["/sim/truth"]
    with open(path, "rb") as fh:
        (update,) = [FoxgloveSceneUpdate.FromString(m.data) for _, _, m in make_reader(fh).iter_messages([SCENE_TOPIC])]
    assert [e.id for e in update.entities] == [f"robot/{i}" for i in range(N)]
    for entity, xy in zip(update.entities, truth.pose[:, :2]):
        (disc,) = entity.cylinders
        assert len(entity.arrows) == 0  # an arrow that never turns says nothing
        assert (disc.pose.position.x, disc.pose.position.y) == pytest.approx(tuple(xy), abs=2.0**-15)
        assert disc.size.x == pytest.approx(0.1, abs=2.0**-14)  # the radius its state told
