"""The display as Foxglove's well-known ``foxglove.SceneUpdate``, so its 3D panel shows a run unconfigured.

Foxglove recognises a channel by its schema name (``foxglove.SceneUpdate``) when the message
encoding is ``json`` and the schema encoding ``jsonschema``.  :func:`scene_update_schema` is that
schema with the field names and types Foxglove publishes (docs.foxglove.dev, "Message schemas":
SceneUpdate, SceneEntity, SceneEntityDeletion, the primitives, Pose, Vector3, Quaternion, Color,
Point3, KeyValuePair, time, duration); like Foxglove's own it requires no field.

:func:`scene_update` builds one message: one entity per robot, ``robot/<id>``, holding its disc
(a flat cylinder, the robot's diameter, its LED colour), a heading arrow and, if it has one, its
goal as a small translucent sphere in the same colour.  Every entity is in the one frame
:data:`DISPLAY_FRAME`, so no transform is needed for the panel to draw them.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

__all__ = ["SCENE_UPDATE_SCHEMA_NAME", "DISPLAY_FRAME", "scene_update_schema", "scene_update"]

SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"
DISPLAY_FRAME = "display"  # the plane the robots move on, x right and y up as in the arena (metres)

DISC_HEIGHT = 0.01  # m: a flat disc, as a robot's LED top is seen from above
GOAL_SIZE = 0.4  # goal sphere diameter, as a fraction of the robot's diameter
GOAL_ALPHA = 0.5  # a goal is where the robot's colour will be, not a robot
NO_LED = (160, 160, 160)  # RGB of a robot whose LED colour is not known
MATCHING_ID = 0  # foxglove.SceneEntityDeletionType
DECIMALS = 4  # lengths to 0.1 mm and colours to 1e-4: far below what a viewer sees, and a shorter log


# ------------------------------------------------------------------------------------------------
# The schema
# ------------------------------------------------------------------------------------------------


def _number() -> dict:
    return {"type": "number"}


def _boolean() -> dict:
    return {"type": "boolean"}


def _string() -> dict:
    return {"type": "string"}


def _object(title: str, **properties: dict) -> dict:
    return {"title": title, "type": "object", "properties": properties}


def _array(items: dict) -> dict:
    return {"type": "array", "items": items}


def _enum(title: str, *names: str) -> dict:
    return {"title": title, "oneOf": [{"title": name, "const": value} for value, name in enumerate(names)]}


def _time() -> dict:
    nsec = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    return {"type": "object", "title": "time", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": nsec}}


def _duration() -> dict:
    nsec = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    return {"type": "object", "title": "duration", "properties": {"sec": {"type": "integer"}, "nsec": nsec}}


def _vector3() -> dict:
    return _object("foxglove.Vector3", x=_number(), y=_number(), z=_number())


def _point3() -> dict:
    return _object("foxglove.Point3", x=_number(), y=_number(), z=_number())


def _pose() -> dict:
    quaternion = _object("foxglove.Quaternion", x=_number(), y=_number(), z=_number(), w=_number())
    return _object("foxglove.Pose", position=_vector3(), orientation=quaternion)


def _color() -> dict:
    return _object("foxglove.Color", r=_number(), g=_number(), b=_number(), a=_number())


def _indices() -> dict:
    return _array({"type": "integer", "minimum": 0})


def _primitives() -> dict[str, dict]:
    """SceneEntity's eight primitive arrays, by field name."""
    arrow = _object(
        "foxglove.ArrowPrimitive",
        pose=_pose(),
        shaft_length=_number(),
        shaft_diameter=_number(),
        head_length=_number(),
        head_diameter=_number(),
        color=_color(),
    )
    cube = _object("foxglove.CubePrimitive", pose=_pose(), size=_vector3(), color=_color())
    sphere = _object("foxglove.SpherePrimitive", pose=_pose(), size=_vector3(), color=_color())
    cylinder = _object(
        "foxglove.CylinderPrimitive",
        pose=_pose(),
        size=_vector3(),
        bottom_scale=_number(),
        top_scale=_number(),
        color=_color(),
    )
    line = _object(
        "foxglove.LinePrimitive",
        type=_enum("foxglove.LineType", "LINE_STRIP", "LINE_LOOP", "LINE_LIST"),
        pose=_pose(),
        thickness=_number(),
        scale_invariant=_boolean(),
        points=_array(_point3()),
        color=_color(),
        colors=_array(_color()),
        indices=_indices(),
    )
    triangles = _object(
        "foxglove.TriangleListPrimitive",
        pose=_pose(),
        points=_array(_point3()),
        color=_color(),
        colors=_array(_color()),
        indices=_indices(),
    )
    text = _object(
        "foxglove.TextPrimitive",
        pose=_pose(),
        billboard=_boolean(),
        font_size=_number(),
        scale_invariant=_boolean(),
        color=_color(),
        text=_string(),
    )
    model = _object(
        "foxglove.ModelPrimitive",
        pose=_pose(),
        scale=_vector3(),
        color=_color(),
        override_color=_boolean(),
        url=_string(),
        media_type=_string(),
        data={"type": "string", "contentEncoding": "base64"},
    )
    return {
        "arrows": _array(arrow),
        "cubes": _array(cube),
        "spheres": _array(sphere),
        "cylinders": _array(cylinder),
        "lines": _array(line),
        "triangles": _array(triangles),
        "texts": _array(text),
        "models": _array(model),
    }


def scene_update_schema() -> dict:
    """The JSON schema of ``foxglove.SceneUpdate``."""
    deletion = _object(
        "foxglove.SceneEntityDeletion",
        timestamp=_time(),
        type=_enum("foxglove.SceneEntityDeletionType", "MATCHING_ID", "ALL"),
        id=_string(),
    )
    entity = _object(
        "foxglove.SceneEntity",
        timestamp=_time(),
        frame_id=_string(),
        id=_string(),
        lifetime=_duration(),
        frame_locked=_boolean(),
        metadata=_array(_object("foxglove.KeyValuePair", key=_string(), value=_string())),
        **_primitives(),
    )
    schema = _object(SCENE_UPDATE_SCHEMA_NAME, deletions=_array(deletion), entities=_array(entity))
    schema["description"] = "An update to the entities displayed in a 3D scene"
    return schema


# ------------------------------------------------------------------------------------------------
# Messages
# ------------------------------------------------------------------------------------------------


def _stamp(t_ns: int) -> dict:
    t_ns = int(t_ns)
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def _xyz(x: float, y: float, z: float) -> dict:
    return {"x": x, "y": y, "z": z}


def _rgba(rgb: list[float], a: float) -> dict:
    return {"r": rgb[0], "g": rgb[1], "b": rgb[2], "a": a}


def scene_update(
    t_ns: int,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None = None,
    *,
    goal: np.ndarray | None = None,
    ids: Iterable[Any] | None = None,
    frame_id: str = DISPLAY_FRAME,
    height: float = DISC_HEIGHT,
    heading: bool = True,
) -> dict:
    """A ``foxglove.SceneUpdate`` payload at time ``t_ns`` (ns) for N robots.

    ``pose`` (N,3) x, y, theta; ``radius`` (N,) or scalar, m; ``color`` (N,3) LED RGB uint8 (None:
    grey); ``goal`` (N,2) with NaN = no goal.  A robot whose position or radius is not finite is
    not drawn, and its earlier entity is deleted, so a robot that has left does not linger.
    Write it on a channel added with ``add_channel(topic, SCENE_UPDATE_SCHEMA_NAME, scene_update_schema())``.
    """
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    n = len(pose)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    rgb = np.broadcast_to(NO_LED, (n, 3)) if color is None else np.asarray(color).reshape(n, 3)
    rgb_unit = (np.asarray(rgb, dtype=float) / 255.0).round(DECIMALS).tolist()
    goal_xy = np.full((n, 2), np.nan) if goal is None else np.asarray(goal, dtype=float).reshape(n, 2)
    ids = [str(i) for i in (range(n) if ids is None else ids)]
    theta = np.where(np.isfinite(pose[:, 2]), pose[:, 2], 0.0)
    qz, qw = np.sin(theta / 2).round(DECIMALS).tolist(), np.cos(theta / 2).round(DECIMALS).tolist()
    drawn = np.isfinite(pose[:, :2]).all(axis=1) & np.isfinite(radius) & (radius > 0)
    has_goal = np.isfinite(goal_xy).all(axis=1).tolist()
    xy, r, gxy = (np.round(a, DECIMALS).tolist() for a in (pose[:, :2], radius, goal_xy))
    stamp = _stamp(t_ns)

    entities, deletions = [], []
    for i in range(n):
        if not drawn[i]:
            deletions.append({"timestamp": stamp, "type": MATCHING_ID, "id": f"robot/{ids[i]}"})
            continue
        x, y = xy[i]
        flat = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
        facing = {"x": 0.0, "y": 0.0, "z": qz[i], "w": qw[i]}
        entity: dict[str, Any] = {
            "timestamp": stamp,
            "frame_id": frame_id,
            "id": f"robot/{ids[i]}",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [],
            "cylinders": [
                {
                    "pose": {"position": _xyz(x, y, height / 2), "orientation": facing},
                    "size": _xyz(2 * r[i], 2 * r[i], height),
                    "bottom_scale": 1.0,
                    "top_scale": 1.0,
                    "color": _rgba(rgb_unit[i], 1.0),
                }
            ],
            "arrows": [],
            "spheres": [],
        }
        if heading:
            entity["arrows"].append(
                {
                    "pose": {"position": _xyz(x, y, height), "orientation": facing},
                    "shaft_length": round(0.6 * r[i], DECIMALS),
                    "shaft_diameter": round(0.15 * r[i], DECIMALS),
                    "head_length": round(0.35 * r[i], DECIMALS),
                    "head_diameter": round(0.35 * r[i], DECIMALS),
                    "color": {"r": 0.1, "g": 0.1, "b": 0.1, "a": 1.0},
                }
            )
        if has_goal[i]:
            d = round(2 * r[i] * GOAL_SIZE, DECIMALS)
            entity["spheres"].append(
                {
                    "pose": {"position": _xyz(gxy[i][0], gxy[i][1], d / 2), "orientation": flat},
                    "size": _xyz(d, d, d),
                    "color": _rgba(rgb_unit[i], GOAL_ALPHA),
                }
            )
        entities.append(entity)
    return {"deletions": deletions, "entities": entities}
