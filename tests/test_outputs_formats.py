"""Run outputs people open without a converter: display.mp4 is H.264 (browsers play it) and log.mcap
has the display as a foxglove.SceneUpdate (Foxglove's 3D panel shows it unconfigured)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import av
import numpy as np
import pytest

from agent.core.params import RobotParams
from coordinator.scene import load_scene
from sim import render
from sim.foxglove import DISPLAY_FRAME, SCENE_UPDATE_SCHEMA_NAME, scene_update, scene_update_schema
from sim.mcaplog import McapLog, mcap_channels, read_mcap
from sim.output import write_run
from sim.recorder import SCENE_TOPIC
from sim.render import _View, frame_indices, write_video
from sim.rundir import RunDir

from .conftest import run_pixelswarm

ARENA = (0.0, 0.0, 4.0, 3.0)
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
    n = write_video(path, t, pose, r, color, ARENA, [], goal, fps=10, size_px=320)
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
    n = write_video(path, t, pose, r, color, ARENA, fps=5, size_px=160)
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
        write_video(path, t, pose, r, color, ARENA, [], goal, size_px=160)
    assert not path.exists()


def test_a_run_without_an_encoder_keeps_everything_else(tmp_path, monkeypatch, capsys):
    scene = load_scene("swap", robots=3, duration=2.5)
    t, pose, _, color, goal = _scene(T=25, N=3)
    arrays = {"t": t, "pose": pose, "velocity": np.zeros((25, 3, 2)), "color": color, "goal": goal}
    monkeypatch.setattr(render, "H264_ENCODER", "no-such-encoder")
    out = write_run(
        RunDir(tmp_path / "run"), scene, RobotParams(), arrays, wall_s=1.0, contacts=[], video=True, plots=True
    )
    names = sorted(p.name for p in out.iterdir())
    assert "display.mp4" not in names
    assert {"metrics.json", "trajectory.npz", "scene.json", "clearance.png", "trajectories.png"} <= set(names)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no display.mp4" in err[0] and "no-such-encoder" in err[0]


# ------------------------------------------------------------------------------------------------
# foxglove.SceneUpdate
# ------------------------------------------------------------------------------------------------

# The fields Foxglove publishes for each schema (docs.foxglove.dev, Message schemas).
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
    "time": {"sec", "nsec"},
    "duration": {"sec", "nsec"},
}


def _titled(schema: dict, found: dict[str, set[str]]) -> dict[str, set[str]]:
    """Every titled object in a schema -> its property names."""
    if "properties" in schema:
        found.setdefault(schema["title"], set(schema["properties"]))
        assert found[schema["title"]] == set(schema["properties"]), schema["title"]
        for sub in schema["properties"].values():
            _titled(sub, found)
    if "items" in schema:
        _titled(schema["items"], found)
    return found


_JSON_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool}


def _validate(value, schema: dict, where: str = "$") -> None:
    """The part of JSON Schema Foxglove's schemas use: type, properties, items, oneOf const, bounds.
    Stricter than JSON Schema in one way: an object may hold only the properties its schema names."""
    if "oneOf" in schema:
        assert value in [choice["const"] for choice in schema["oneOf"]], where
        return
    kind = schema["type"]
    if kind in ("number", "integer"):
        assert isinstance(value, int if kind == "integer" else (int, float)) and not isinstance(value, bool), where
        assert schema.get("minimum", value) <= value <= schema.get("maximum", value), where
        return
    assert isinstance(value, _JSON_TYPES[kind]), where
    if kind == "object":
        assert set(value) <= set(schema["properties"]), where
        for name, item in value.items():
            _validate(item, schema["properties"][name], f"{where}.{name}")
    elif kind == "array":
        for k, item in enumerate(value):
            _validate(item, schema["items"], f"{where}[{k}]")


def test_scene_update_schema_has_foxgloves_fields():
    schema = scene_update_schema()
    assert schema["title"] == SCENE_UPDATE_SCHEMA_NAME
    assert _titled(schema, {}) == FOXGLOVE_FIELDS
    entity = schema["properties"]["entities"]["items"]["properties"]
    assert entity["timestamp"]["properties"]["nsec"] == {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    assert [c["const"] for c in schema["properties"]["deletions"]["items"]["properties"]["type"]["oneOf"]] == [0, 1]
    for wrong in ({"entities": [{"frame_id": 3}]}, {"entities": [{"colour": {}}]}, {"deletions": [{"type": 2}]}):
        with pytest.raises(AssertionError):
            _validate(wrong, schema)  # the checker below can fail


def test_scene_update_messages_validate_and_read_back(tmp_path):
    path = tmp_path / "log.mcap"
    pose = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, np.pi / 2], [np.nan, np.nan, np.nan], [3.0, 1.0, 0.0]])
    color = np.array([RED, GREEN, OFF, (10, 20, 30)], np.uint8)
    goal = np.array([[0.5, 0.5], [np.nan, np.nan], [1.0, 1.0], [3.0, 2.0]])
    radius = np.array([0.045, 0.1, 0.045, np.nan])  # robot 3 has not announced its radius yet
    with McapLog(path) as log:
        cid = log.add_channel(SCENE_TOPIC, SCENE_UPDATE_SCHEMA_NAME, scene_update_schema())
        log.write(cid, 2_250_000_000, scene_update(2_250_000_000, pose, radius, color, goal=goal))
    channel = mcap_channels(path)[SCENE_TOPIC]
    assert channel["schema_name"] == "foxglove.SceneUpdate"
    assert (channel["schema_encoding"], channel["message_encoding"]) == ("jsonschema", "json")
    (msg,) = read_mcap(path)[SCENE_TOPIC]
    _validate(msg, channel["schema"])
    assert [e["id"] for e in msg["entities"]] == ["robot/0", "robot/1"]
    assert [(d["id"], d["type"]) for d in msg["deletions"]] == [("robot/2", 0), ("robot/3", 0)]
    first, second = msg["entities"]
    assert first["timestamp"] == {"sec": 2, "nsec": 250_000_000} and first["frame_id"] == DISPLAY_FRAME
    (disc,) = second["cylinders"]
    assert disc["size"] == {"x": pytest.approx(0.2), "y": pytest.approx(0.2), "z": pytest.approx(0.01)}
    assert disc["color"] == {"r": 0.0, "g": 1.0, "b": 0.0, "a": 1.0}
    assert disc["pose"]["orientation"]["z"] == pytest.approx(np.sin(np.pi / 4), abs=1e-4)
    assert second["spheres"] == []  # no goal
    (target,) = first["spheres"]
    assert target["pose"]["position"]["x"] == 0.5 and target["pose"]["position"]["y"] == 0.5
    assert target["color"]["r"] == 1.0 and target["color"]["a"] < 1.0


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_run_shows_in_foxglove_and_in_a_browser(tmp_path):
    """The real command: four robots swap places for 3 s (one agent process); then log.mcap has the
    display at every recorded tick in the robots' LED colours, and display.mp4 is H.264."""
    out = tmp_path / "run"
    result = run_pixelswarm("run", "swap", "--robots", "4", "--duration", "3", "-k", "4", "--out", str(out), "-q")
    assert result.returncode == 0, result.stderr[-3000:]
    traj = np.load(out / "trajectory.npz")
    T = len(traj["t"])
    assert T >= 20

    channel = mcap_channels(out / "log.mcap")[SCENE_TOPIC]
    assert (channel["schema_name"], channel["schema_encoding"]) == ("foxglove.SceneUpdate", "jsonschema")
    assert json.dumps(channel["schema"], sort_keys=True) == json.dumps(scene_update_schema(), sort_keys=True)
    updates = read_mcap(out / "log.mcap", [SCENE_TOPIC])[SCENE_TOPIC]
    assert len(updates) == T  # one per recorded tick, in order
    for k, update in enumerate(updates):
        _validate(update, channel["schema"])
        assert [e["id"] for e in update["entities"]] == [f"robot/{i}" for i in range(4)]
        discs = [e["cylinders"][0] for e in update["entities"]]
        rgb = np.array([[d["color"][c] for c in "rgb"] for d in discs])
        np.testing.assert_allclose(rgb * 255, traj["color"][k], atol=0.02)  # to 1e-4 of full scale
        centres = np.array([[d["pose"]["position"]["x"], d["pose"]["position"]["y"]] for d in discs])
        np.testing.assert_allclose(centres, traj["pose"][k, :, :2], atol=0.5e-4)  # to 0.1 mm
        np.testing.assert_allclose([d["size"]["x"] for d in discs], 2 * traj["radius"], atol=1e-4)

    codec, frames = _decode(out / "display.mp4")
    assert codec.name == "h264" and codec.pix_fmt == "yuv420p"
    assert len(frames) == len(frame_indices(traj["t"], fps=10))
