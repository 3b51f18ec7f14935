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

from sim.outputs.foxglove import GOALS_ENTITY, SWARM_ENTITY, goal_markers, swarm_scene
from sim.outputs.logschema import logged_kinds
from sim.outputs.recorder import GOALS_TOPIC, LOG_ROBOTS, SCENE_PERIOD, SCENE_TOPIC, Recorder
from tests.support.fake_bus import RecorderBus
from transport.codec import Bid, Boards, Commands, Event, Goals, Poses, States, Tick, Timing, Truth

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
    # more rows than FEW_ROWS (logschema: their columns go in as numpy's bytes), robot ids in one,
    # two and three bytes of varint
    boards = _table(Boards.WORD, 20, rng)
    boards["robot"] = rng.integers(0, 2**16, 20)
    boards["robot"][:3] = [5, 300, 40000]
    boards["flags"] = Boards.FRESH | Boards.GROWN
    boards["records"] = 1
    boards["records"][:2] = [0, 2]
    records = _table(Boards.RECORD, 20, rng)
    records["goal"] = np.arange(20) % 5
    bid = _table(Bid.RECORD, 40, rng)  # a column of 160 bytes or more: its length takes two bytes
    bid["goal"][0] = -1  # a robot that holds no goal yet: signed integers read back signed
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
        "/auction": (keys.auction(1, 0), Bid(1, 4, 0, 9, 2**63 + 5, 40, bid)),
        "/boards": (
            keys.boards(1, 0),
            Boards(1, 4, 0, 3, 5, N, 20, boards, rng.integers(0, 256, (20, 1), np.uint8), records),
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
    rec.out.heading = False  # holonomic robots: their heading never changes
    bus.raw.items = [(key, msg.encode(), 100.0 + k) for k, (key, msg) in enumerate(sent.values())]
    rec.poll()
    rec.out.close()
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
            assert getattr(decoded, name) == value, name  # a float32 field's value is a float32 already


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


# ------------------------------------------------------------------------------------------------
# A swarm of thousands: one entity of discs at SCENE_PERIOD, goals once a goal set
# ------------------------------------------------------------------------------------------------


def _sdk_swarm(t_ns, xy, d, rgb):
    """The swarm's message built object by object with Foxglove's SDK: what swarm_scene must encode."""
    from foxglove.messages import (
        Color,
        CylinderPrimitive,
        Duration,
        Pose,
        Quaternion,
        SceneEntity,
        SceneUpdate,
        Timestamp,
        Vector3,
    )

    discs = [
        CylinderPrimitive(
            pose=Pose(position=Vector3(x=x, y=y, z=0.005), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
            size=Vector3(x=size, y=size, z=0.01),
            bottom_scale=1.0,
            top_scale=1.0,
            color=Color(r=r, g=g, b=b, a=1.0),
        )
        for (x, y), size, (r, g, b) in zip(xy.tolist(), d.tolist(), rgb.tolist())
    ]
    stamp = Timestamp(sec=t_ns // 10**9, nsec=t_ns % 10**9)
    forever = Duration(sec=0, nsec=0)
    entity = SceneEntity(timestamp=stamp, frame_id="display", id=SWARM_ENTITY, lifetime=forever, cylinders=discs)
    return FoxgloveSceneUpdate.FromString(SceneUpdate(entities=[entity]).encode())


def test_the_swarms_one_entity_is_what_foxgloves_sdk_builds_disc_by_disc():
    rng = np.random.default_rng(5)
    n = 300
    pose = np.column_stack([rng.uniform(-40, 40, (n, 2)), rng.uniform(-3, 3, n)])
    pose[7] = np.nan  # not there: not drawn
    pose[8, :2] = 0.0  # at the origin: its zero coordinates are still there
    radius, color = rng.uniform(0.03, 0.05, n), rng.integers(0, 256, (n, 3), dtype=np.uint8)
    got = FoxgloveSceneUpdate.FromString(swarm_scene(12_345_678_901, pose, radius, color))
    q = 2.0**-14
    keep = np.arange(n) != 7
    want = _sdk_swarm(
        12_345_678_901,
        np.round(pose[keep, :2] / q) * q,
        np.round(2 * radius[keep] / q) * q,
        np.round(color[keep] / 255.0 / q) * q,
    )
    assert got == want and len(got.entities[0].cylinders) == n - 1
    assert got.entities[0].cylinders[7].pose.position.x == 0.0
    gone = FoxgloveSceneUpdate.FromString(swarm_scene(0, np.full((3, 3), np.nan), 0.04))
    assert [d.id for d in gone.deletions] == [SWARM_ENTITY] and not gone.entities
    goals = FoxgloveSceneUpdate.FromString(goal_markers(0, pose[:, :2], color, 0.03))
    (entity,) = goals.entities
    assert entity.id == GOALS_ENTITY and len(entity.spheres) == n - 1
    sphere = entity.spheres[0]
    assert sphere.size.x == sphere.size.z == pytest.approx(0.03, abs=q) and sphere.pose.position.z == sphere.size.z / 2
    assert sphere.color.a == 0.5 and sphere.color.r == pytest.approx(color[0, 0] / 255, abs=q)


def test_a_swarm_is_logged_as_one_entity_every_scene_period_and_its_goals_once(tmp_path):
    n = LOG_ROBOTS + 1
    rng = np.random.default_rng(2)
    start, goal = rng.uniform(0, 30, (n, 2)), rng.uniform(0, 30, (n, 2))
    bus = RecorderBus()
    rec = Recorder(bus, robots=n, tolerance=0.01, log_path=str(tmp_path / "log.mcap"))
    rec.said.radius[:] = 0.037  # as the robots' states tell it
    color = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    goals = Goals(1, 0, goal, color, np.arange(n), Timing(stamp=0.0))
    items = [(bus.keys.goals(1), goals.encode(), 50.0)]
    for k in range(36):  # moving until tick 15, then at rest
        xy = start + (goal - start) * min(k, 15) / 15
        truth = Truth(k, 0.1 * k, 0.1, n, np.column_stack([xy, np.zeros(n)]), np.zeros((n, 2)))
        truth.color, truth.applied = color, np.full(n, k, np.uint32)
        items.append((bus.keys.truth, truth.encode(), 100.0 + 0.1 * k))
    bus.raw.items = items
    rec.poll()
    rec.out.close()
    with open(tmp_path / "log.mcap", "rb") as fh:
        logged = [
            (c.topic, m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages([SCENE_TOPIC, GOALS_TOPIC])
        ]
    scenes = [(t, FoxgloveSceneUpdate.FromString(d)) for topic, t, d in logged if topic == SCENE_TOPIC]
    # at 0, 1 and 2 s of display time; at 3 s nothing had moved since 2 s
    assert [round((t - 100e9) / 1e8) for t, _ in scenes] == [0, round(10 * SCENE_PERIOD), round(20 * SCENE_PERIOD)]
    for _, update in scenes:
        (entity,) = update.entities
        assert entity.id == SWARM_ENTITY and len(entity.cylinders) == n
    last = scenes[-1][1].entities[0].cylinders
    np.testing.assert_allclose([[c.pose.position.x, c.pose.position.y] for c in last], goal, atol=2.0**-15)
    ((topic, _, data),) = [row for row in logged if row[0] == GOALS_TOPIC]
    (entity,) = FoxgloveSceneUpdate.FromString(data).entities
    assert entity.id == GOALS_ENTITY and len(entity.spheres) == n
    assert entity.spheres[0].size.x == pytest.approx(0.4 * 2 * 0.037, abs=2.0**-14)


def test_a_goal_set_published_again_unchanged_is_logged_once_and_a_changed_one_again(tmp_path):
    """The coordinator republishes its goal set every second for late joiners: the log keeps the
    first copy (the recorder still counts every copy), and a copy that changed is logged too."""
    rng = np.random.default_rng(5)
    bus = RecorderBus()
    rec = Recorder(bus, robots=N, tolerance=0.01, log_path=str(tmp_path / "log.mcap"))
    color = rng.integers(0, 256, (N, 3)).astype(np.uint8)
    first = Goals(1, 0, rng.uniform(0, 3, (N, 2)), color, np.arange(N), Timing(stamp=0.0))
    changed = Goals(1, 0, rng.uniform(0, 3, (N, 2)), color, np.arange(N), Timing(stamp=0.0))
    second = Goals(2, 0, rng.uniform(0, 3, (N, 2)), color, np.arange(N), Timing(stamp=5.0))
    sent = [(1, first), (1, first), (1, first), (1, changed), (2, second), (2, second)]
    bus.raw.items = [(bus.keys.goals(e), g.encode(), 100.0 + k) for k, (e, g) in enumerate(sent)]
    rec.poll()
    rec.out.close()
    logged = _read(tmp_path / "log.mcap")["/goals"][2]
    assert [(g["epoch"], g["positions"]) for g in logged] == [
        (g.epoch, g.positions.astype(np.float32).astype(float).tolist()) for g in (first, changed, second)
    ]  # positions cross the bus as float32
    assert rec.tally.counts["goals"] == len(sent)
