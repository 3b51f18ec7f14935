"""Run outputs people open without a converter: display.mp4 is H.264 (browsers play it) and log.mcap
has the display as a foxglove.SceneUpdate in protobuf (Foxglove's 3D panel shows it unconfigured),
written by Foxglove's SDK and read back here with Foxglove's own compiled schemas."""

from __future__ import annotations

import json
import re
import struct
import time
from pathlib import Path

import av
import numpy as np
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate as FoxgloveSceneUpdate
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.reader import make_reader
from websockets.sync.client import connect

from agent.core.params import RobotParams
from coordinator.scene import load_scene
from sim.outputs import render
from sim.outputs.foxglove import DISPLAY_FRAME, QUANTUM, SCENE_UPDATE_SCHEMA_NAME, SceneUpdate, scene_update
from sim.outputs.mcaplog import McapLog, mcap_channels, read_mcap
from sim.outputs.recorder import SCENE_TOPIC
from sim.outputs.render import Recording, _View, frame_indices, held_frames, write_video
from sim.outputs.rundir import RunDir
from sim.outputs.write import RunOutcome, write_run
from tests.conftest import run_pixelswarm

ARENA = (0.0, 0.0, 4.0, 3.0)
FOXGLOVE_WS = "foxglove.sdk.v1"  # the subprotocol Foxglove's SDK serves its WebSocket protocol under
RED, GREEN, OFF = (255, 0, 0), (0, 255, 0), (0, 0, 0)


def _scene(T: int = 25, N: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Three robots driving right, red, green and dark, each with a goal above it."""
    t = np.arange(T) * 0.1
    pose = np.zeros((T, N, 3))
    pose[:, :, 0] = np.linspace(0.5, 1.5, T)[:, None] + np.arange(N)[None]
    pose[:, :, 1] = 0.6
    color = np.zeros((T, N, 3), np.uint8)
    color[:] = [RED, GREEN, OFF]
    goal = np.broadcast_to(pose[-1, :, :2] + [0.0, 1.5], (T, N, 2)).copy()
    return t, pose, np.full(N, 0.15), color, goal


def _decode(path: Path) -> tuple[av.codec.context.CodecContext, list[np.ndarray]]:
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [f.to_ndarray(format="bgr24") for f in container.decode(stream)]
        return stream.codec_context, frames


def _top_level_boxes(path: Path) -> list[str]:
    """The MP4 boxes in file order (size, type headers; 64-bit sizes followed)."""
    data, boxes, at = path.read_bytes(), [], 0
    while at + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[at : at + 8])
        if size == 1:
            size = struct.unpack(">Q", data[at + 8 : at + 16])[0]
        boxes.append(kind.decode("ascii"))
        at += size if size else len(data)
    return boxes


# ------------------------------------------------------------------------------------------------
# display.mp4
# ------------------------------------------------------------------------------------------------


def test_display_mp4_is_h264_that_browsers_play(tmp_path):
    t, pose, r, color, goal = _scene()
    path = tmp_path / "display.mp4"
    n = write_video(path, Recording(t, pose, r, ARENA, goal=goal, color=color), fps=10, size_px=320)
    codec, frames = _decode(path)
    view = _View(ARENA, 320)
    assert codec.name == "h264" and codec.profile == "High" and codec.pix_fmt == "yuv420p"
    assert (codec.width, codec.height) == (view.width, view.height)
    assert n == len(frames) == 25
    boxes = _top_level_boxes(path)
    assert boxes.index("moov") < boxes.index("mdat")  # 'faststart': a browser plays while downloading
    # the red robot shows red (lossy codec: a loose check) on the dark background
    for k in (0, 24):
        c, row = np.round(view.px(pose[k, 0, :2] - [0.07, 0.0])).astype(int)
        b, g, red = (int(v) for v in frames[k][row, c])
        assert red > 150 and g < 100 and b < 100
    assert frames[0][5:15, view.width - 15 : view.width - 5].mean() < 40  # top right: no time label


def test_display_mp4_frame_rate_and_count_follow_the_run(tmp_path):
    t, pose, r, color, _ = _scene(T=41)
    path = tmp_path / "display.mp4"
    n = write_video(path, Recording(t, pose, r, ARENA, color=color), fps=5, size_px=160)
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.average_rate == 5
        count = sum(1 for _ in container.decode(stream))
    assert n == count == len(frame_indices(t, fps=5)) == 21  # 4 s at 5 frames a second, both ends


def test_a_failed_encoder_leaves_no_video(tmp_path, monkeypatch):
    t, pose, r, color, goal = _scene(T=5)
    path = tmp_path / "display.mp4"
    monkeypatch.setattr(render, "H264_ENCODER", "no-such-encoder")
    with pytest.raises(RuntimeError, match="display.mp4"):
        write_video(path, Recording(t, pose, r, ARENA, goal=goal, color=color), size_px=160)
    assert not path.exists()


def test_a_run_without_an_encoder_keeps_everything_else(tmp_path, monkeypatch, capsys):
    scene = load_scene("swap", robots=3, duration=2.5)
    t, pose, _, color, goal = _scene(T=25, N=3)
    arrays = {"t": t, "pose": pose, "velocity": np.zeros((25, 3, 2)), "color": color, "goal": goal}
    monkeypatch.setattr(render, "H264_ENCODER", "no-such-encoder")
    out = write_run(RunDir(tmp_path / "run"), scene, RobotParams(), arrays, RunOutcome(1.0, []), video=True, plots=True)
    names = sorted(p.name for p in out.iterdir())
    assert "display.mp4" not in names
    assert {"metrics.json", "trajectory.npz", "scene.json", "clearance.png", "trajectories.png"} <= set(names)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no display.mp4" in err[0] and "no-such-encoder" in err[0]


# ------------------------------------------------------------------------------------------------
# foxglove.SceneUpdate
# ------------------------------------------------------------------------------------------------

# The fields Foxglove publishes for each schema (docs.foxglove.dev, Message schemas); in protobuf a
# time or duration is google.protobuf's Timestamp or Duration.
FOXGLOVE_FIELDS = {
    "foxglove.SceneUpdate": {"deletions", "entities"},
    "foxglove.SceneEntityDeletion": {"timestamp", "type", "id"},
    "foxglove.SceneEntity": {
        "timestamp",
        "frame_id",
        "id",
        "lifetime",
        "frame_locked",
        "metadata",
        "arrows",
        "cubes",
        "spheres",
        "cylinders",
        "lines",
        "triangles",
        "texts",
        "models",
    },
    "foxglove.KeyValuePair": {"key", "value"},
    "foxglove.ArrowPrimitive": {"pose", "shaft_length", "shaft_diameter", "head_length", "head_diameter", "color"},
    "foxglove.CubePrimitive": {"pose", "size", "color"},
    "foxglove.SpherePrimitive": {"pose", "size", "color"},
    "foxglove.CylinderPrimitive": {"pose", "size", "bottom_scale", "top_scale", "color"},
    "foxglove.LinePrimitive": {"type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"},
    "foxglove.TriangleListPrimitive": {"pose", "points", "color", "colors", "indices"},
    "foxglove.TextPrimitive": {"pose", "billboard", "font_size", "scale_invariant", "color", "text"},
    "foxglove.ModelPrimitive": {"pose", "scale", "color", "override_color", "url", "media_type", "data"},
    "foxglove.Pose": {"position", "orientation"},
    "foxglove.Vector3": {"x", "y", "z"},
    "foxglove.Point3": {"x", "y", "z"},
    "foxglove.Quaternion": {"x", "y", "z", "w"},
    "foxglove.Color": {"r", "g", "b", "a"},
    "google.protobuf.Timestamp": {"seconds", "nanos"},
    "google.protobuf.Duration": {"seconds", "nanos"},
}


def _messages_of(descriptors: FileDescriptorSet) -> dict[str, set[str]]:
    """Every message type of a protobuf schema (as an MCAP file stores it) -> its field names."""
    return {
        f"{file.package}.{message.name}": {field.name for field in message.field}
        for file in descriptors.file
        for message in file.message_type
    }


def _scene_channel(path: Path) -> dict:
    """The display's channel: Foxglove's SceneUpdate, protobuf, with the schema Foxglove publishes."""
    channel = mcap_channels(path)[SCENE_TOPIC]
    assert channel["schema_name"] == SCENE_UPDATE_SCHEMA_NAME
    assert (channel["schema_encoding"], channel["message_encoding"]) == ("protobuf", "protobuf")
    assert _messages_of(channel["schema"]) == FOXGLOVE_FIELDS
    return channel


def _decoded_by_foxglove(path: Path, topic: str) -> list[FoxgloveSceneUpdate]:
    """The topic's messages as Foxglove's own compiled schemas decode them (foxglove-schemas-protobuf),
    read with mcap's reader: a decoder that shares nothing with the writer."""
    with open(path, "rb") as fh:
        return [FoxgloveSceneUpdate.FromString(m.data) for _s, _c, m in make_reader(fh).iter_messages(topics=[topic])]


def test_scene_update_messages_read_back_with_foxgloves_schemas(tmp_path):
    path = tmp_path / "log.mcap"
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, np.pi / 2], [np.nan, np.nan, np.nan], [3.0, 1.0, 0.0]])
    color = np.array([RED, GREEN, OFF, (10, 20, 30)], np.uint8)
    goal = np.array([[0.5, 0.5], [np.nan, np.nan], [1.0, 1.0], [3.0, 2.0]])
    radius = np.array([0.045, 0.1, 0.045, np.nan])  # robot 3 has not announced its radius yet
    with McapLog(path) as log:
        cid = log.add_foxglove_channel(SCENE_TOPIC, SceneUpdate)
        assert log.add_foxglove_channel(SCENE_TOPIC, SceneUpdate) == cid
        with pytest.raises(ValueError, match="different schema"):
            log.add_channel(SCENE_TOPIC, SCENE_UPDATE_SCHEMA_NAME, {"type": "object"})
        log.write_bytes(cid, 2_250_000_000, scene_update(2_250_000_000, pose, radius, color, goal=goal))
    _scene_channel(path)

    (theirs,) = _decoded_by_foxglove(path, SCENE_TOPIC)
    assert [e.id for e in theirs.entities] == ["robot/0", "robot/1"]
    assert [(d.id, d.type) for d in theirs.deletions] == [("robot/2", 0), ("robot/3", 0)]  # MATCHING_ID
    first, second = theirs.entities
    assert (first.timestamp.seconds, first.timestamp.nanos) == (2, 250_000_000) and first.frame_id == DISPLAY_FRAME
    (disc,) = second.cylinders
    assert (disc.size.x, disc.size.y, disc.size.z) == pytest.approx((0.2, 0.2, 0.01), abs=QUANTUM)  # 0.1: no power of 2
    assert (disc.color.r, disc.color.g, disc.color.b, disc.color.a) == (0.0, 1.0, 0.0, 1.0)
    assert disc.pose.orientation.z == pytest.approx(np.sin(np.pi / 4), abs=1e-4)
    assert len(second.spheres) == 0 and len(second.metadata) == 0  # no goal
    (target,) = first.spheres
    assert (target.pose.position.x, target.pose.position.y) == (0.5, 0.5)
    assert target.color.r == 1.0 and target.color.a < 1.0
    assert [(kv.key, kv.value) for kv in first.metadata] == [("goal", "0.500, 0.500")]  # shown on hover

    (ours,) = read_mcap(path)[SCENE_TOPIC]  # the same, as dicts with Foxglove's field names
    assert ours["entities"][0]["timestamp"] == {"sec": 2, "nsec": 250_000_000}
    assert ours["entities"][1]["cylinders"][0]["color"] == {"r": 0.0, "g": 1.0, "b": 0.0, "a": 1.0}
    assert [d["id"] for d in ours["deletions"]] == ["robot/2", "robot/3"]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_run_shows_in_foxglove_and_in_a_browser(tmp_path):
    """The real command: four robots swap places for 3 s (one agent process); then log.mcap has the
    display at every recorded tick in the robots' LED colours, and display.mp4 is H.264."""
    out = tmp_path / "run"
    args = ("--robots", "4", "--duration", "3", "-k", "4", "--out", str(out), "-q", "--foxglove", "0")
    result = run_pixelswarm("run", "swap", *args)
    assert result.returncode == 0, result.stderr[-3000:]
    assert re.search(r"Foxglove live: ws://127\.0\.0\.1:\d+", result.stderr)  # said even with -q
    traj = np.load(out / "trajectory.npz")
    T = len(traj["t"])
    assert T >= 20

    _scene_channel(out / "log.mcap")
    assert len(_decoded_by_foxglove(out / "log.mcap", SCENE_TOPIC)) == T  # Foxglove's schemas decode each
    channels = mcap_channels(out / "log.mcap")
    kinds = {"/pose": "Poses", "/state": "States", "/cmd": "Commands", "/sim/truth": "Truth"}  # no auction in swap
    assert {t: channels[t]["schema_name"] for t in kinds} == {t: f"pixelswarm.{k}" for t, k in kinds.items()}
    assert all(channels[t]["message_encoding"] == "protobuf" for t in kinds)  # the per-tick kinds: protobuf
    assert all(c["schema_name"].startswith(("foxglove.", "pixelswarm.")) for c in channels.values())
    truth = [m["records"] for m in read_mcap(out / "log.mcap", ["/sim/truth"])["/sim/truth"]][:T]
    logged_xy = np.array([np.column_stack([r["x"], r["y"]]) for r in truth])
    np.testing.assert_array_equal(logged_xy, traj["pose"][: len(truth), :, :2].astype(np.float32))
    updates = read_mcap(out / "log.mcap", [SCENE_TOPIC])[SCENE_TOPIC]
    assert len(updates) == T  # one per recorded tick, in order
    for k, update in enumerate(updates):
        assert [e["id"] for e in update["entities"]] == [f"robot/{i}" for i in range(4)]
        discs = [e["cylinders"][0] for e in update["entities"]]
        rgb = np.array([[d["color"][c] for c in "rgb"] for d in discs])
        np.testing.assert_allclose(rgb * 255, traj["color"][k], atol=255 * QUANTUM / 2)  # to 1/32768 of full scale
        centres = np.array([[d["pose"]["position"]["x"], d["pose"]["position"]["y"]] for d in discs])
        np.testing.assert_allclose(centres, traj["pose"][k, :, :2], atol=QUANTUM / 2)  # to 0.03 mm
        np.testing.assert_allclose([d["size"]["x"] for d in discs], 2 * traj["radius"], atol=QUANTUM)

    codec, frames = _decode(out / "display.mp4")
    assert codec.name == "h264" and codec.pix_fmt == "yuv420p"
    formed = json.loads((out / "metrics.json").read_text())["time_to_converge_s"]
    assert len(frames) == len(held_frames(traj["t"], None if formed is None else traj["t"][0] + formed))


def _sdk_scene(t_ns, pose, radius, color, goal, heading) -> bytes:  # type: ignore[no-untyped-def]
    """The display as Foxglove's SDK builds it object by object: the reference for scene_update,
    which copies the SDK's encoding of one robot's primitives with each robot's numbers."""
    import foxglove.messages as fm

    def q(v: float) -> float:
        return float(np.round(v / QUANTUM) * QUANTUM)

    def at(x: float, y: float, z: float, qz: float = 0.0, qw: float = 1.0) -> fm.Pose:
        return fm.Pose(position=fm.Vector3(x=x, y=y, z=z), orientation=fm.Quaternion(x=0.0, y=0.0, z=qz, w=qw))

    stamp, entities, deletions = fm.Timestamp(sec=t_ns // 10**9, nsec=t_ns % 10**9), [], []
    for i, ((x, y, theta), r, rgb, (gx, gy)) in enumerate(zip(pose, radius, color, goal)):
        if not (np.isfinite([x, y, r]).all() and r > 0):
            gone = fm.SceneEntityDeletion(timestamp=stamp, type=fm.SceneEntityDeletionType.MatchingId, id=f"robot/{i}")
            deletions.append(gone)
            continue
        x, y, r, qz, qw = q(x), q(y), q(r), q(np.sin(theta / 2)), q(np.cos(theta / 2))
        red, green, blue = (q(c / 255.0) for c in rgb)
        scales = {"bottom_scale": 1.0, "top_scale": 1.0, "color": fm.Color(r=red, g=green, b=blue, a=1.0)}
        disc = fm.CylinderPrimitive(pose=at(x, y, 0.005, qz, qw), size=fm.Vector3(x=2 * r, y=2 * r, z=0.01), **scales)
        arrows = []
        if heading:
            shape = {"shaft_length": 0.6 * r, "shaft_diameter": 0.15 * r, "head_length": 0.35 * r}
            dark = fm.Color(r=0.1, g=0.1, b=0.1, a=1.0)
            arrows.append(fm.ArrowPrimitive(pose=at(x, y, 0.01, qz, qw), head_diameter=0.35 * r, color=dark, **shape))
        spheres, metadata = [], []
        if np.isfinite([gx, gy]).all():
            gx, gy, d = q(gx), q(gy), 2 * r * 0.4
            see_through = fm.Color(r=red, g=green, b=blue, a=0.5)
            spheres = [fm.SpherePrimitive(pose=at(gx, gy, d / 2), size=fm.Vector3(x=d, y=d, z=d), color=see_through)]
            metadata = [fm.KeyValuePair(key="goal", value=f"{gx:.3f}, {gy:.3f}")]
        head = {
            "timestamp": stamp,
            "frame_id": DISPLAY_FRAME,
            "id": f"robot/{i}",
            "lifetime": fm.Duration(sec=0, nsec=0),
        }
        entities.append(fm.SceneEntity(**head, metadata=metadata, cylinders=[disc], arrows=arrows, spheres=spheres))
    return SceneUpdate(deletions=deletions, entities=entities).encode()


@pytest.mark.parametrize("heading", [True, False])
def test_the_display_is_the_scene_foxgloves_sdk_builds_robot_by_robot(heading):
    rng = np.random.default_rng(5)
    n = 40
    pose = np.column_stack([rng.uniform(-2, 2, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    pose[0] = 0.0  # zeros: fields the SDK leaves out and scene_update writes; the same message
    pose[1, :2] = np.nan  # not drawn: deleted
    radius = rng.uniform(0.03, 0.1, n)
    radius[2] = np.nan
    color = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    goal = rng.uniform(-2, 2, (n, 2))
    goal[3:9] = np.nan  # no goal: no sphere, no metadata
    t_ns = 7_123_456_789
    ours = FoxgloveSceneUpdate.FromString(scene_update(t_ns, pose, radius, color, goal=goal, heading=heading))
    reference = FoxgloveSceneUpdate.FromString(_sdk_scene(t_ns, pose, radius, color, goal, heading))
    assert [d.id for d in ours.deletions] == ["robot/1", "robot/2"]
    assert len(ours.entities) == n - 2 and ours == reference


def test_the_log_streams_live_to_a_foxglove_websocket_client(tmp_path):
    """`pixelswarm run --foxglove`: the log's channels, served by Foxglove's SDK on 127.0.0.1, reach a
    client of Foxglove's WebSocket protocol (websockets, another implementation) as they are written."""
    pose = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, np.pi]])
    with McapLog(tmp_path / "log.mcap") as log:
        cid = log.add_foxglove_channel(SCENE_TOPIC, SceneUpdate)
        port = log.serve(0)
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[FOXGLOVE_WS], open_timeout=10) as ws:
            advertised = {}
            while SCENE_TOPIC not in advertised:
                frame = json.loads(ws.recv(timeout=10))
                if frame["op"] == "advertise":
                    advertised.update({c["topic"]: c for c in frame["channels"]})
            channel = advertised[SCENE_TOPIC]
            assert (channel["schemaName"], channel["encoding"]) == (SCENE_UPDATE_SCHEMA_NAME, "protobuf")
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channel["id"]}]}))
            time.sleep(0.2)  # the server takes the subscription on its own thread
            log.write_bytes(cid, 3_000_000_000, scene_update(3_000_000_000, pose, 0.05, [RED, GREEN]))
            while isinstance(frame := ws.recv(timeout=10), str):
                pass  # status and other text frames
        opcode, subscription, log_time = struct.unpack_from("<BIQ", frame)
        assert (opcode, subscription, log_time) == (1, 7, 3_000_000_000)  # a message data frame
        update = FoxgloveSceneUpdate.FromString(frame[13:])
        assert [e.id for e in update.entities] == ["robot/0", "robot/1"]
        assert update.entities[1].cylinders[0].pose.position.x == 2.0
