"""The display as Foxglove's ``foxglove.SceneUpdate`` (protobuf, built with ``foxglove-sdk``), which Foxglove's 3D
panel shows with no configuration: an entity a robot (:func:`scene_update`), or a large swarm as one entity
(:func:`swarm_scene`) and its goals as another (:func:`goal_markers`), all in the frame :data:`DISPLAY_FRAME`."""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable
from typing import Any

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CylinderPrimitive,
    Duration,
    KeyValuePair,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from sim.outputs.logschema import length_delimited

SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"
DISPLAY_FRAME = "display"  # the plane the robots move on, x right and y up as in the arena (metres)

DISC_HEIGHT = 0.01  # m: a flat disc, as a robot's LED top is seen from above
GOAL_SIZE = 0.4  # goal sphere diameter, as a fraction of the robot's diameter
GOAL_ALPHA = 0.5  # a goal is where the robot's colour will be, not a robot
SWARM_ENTITY = "robots"  # swarm_scene's one entity
GOALS_ENTITY = "goals"  # goal_markers' one entity
NO_LED = (160, 160, 160)  # RGB of a robot whose LED colour is not known
HEADING_COLOR = (0.1, 0.1, 0.1)
UNTURNED = (0.0, 1.0)  # qz, qw of the identity rotation
# lengths, colours and rotations to 1/16384, far below what a viewer sees: a power of two zeroes each
# double's low bytes, and a robot at rest repeats the same bytes tick after tick for compression to store once
QUANTUM = 2.0**-14


def _timestamp(t_ns: int) -> Timestamp:
    return Timestamp(sec=int(t_ns) // 1_000_000_000, nsec=int(t_ns) % 1_000_000_000)


def _head(stamp: Timestamp, entity: str, metadata: list[KeyValuePair] | None = None) -> bytes:
    """An entity's encoded head, without its primitives: it lasts until replaced."""
    return SceneEntity(
        timestamp=stamp, frame_id=DISPLAY_FRAME, id=entity, lifetime=Duration(sec=0, nsec=0), metadata=metadata
    ).encode()


def _deleted(stamp: Timestamp, entity: str) -> SceneEntityDeletion:
    return SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=entity)


def _robots(pose: np.ndarray, radius: np.ndarray, color: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """Poses (N,3), radii (N,), colours in 0..1 and whether each robot is drawn (finite, radius > 0)."""
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (len(pose),))
    drawn = np.isfinite(pose[:, :2]).all(axis=1) & np.isfinite(radius) & (radius > 0)
    return pose, radius, _rgb(color, len(pose)), drawn


def _rgb(color: np.ndarray | None, n: int) -> np.ndarray:
    """(n, 3) RGB uint8 colours (None: :data:`NO_LED`) as 0..1."""
    rgb = np.broadcast_to(NO_LED, (n, 3)) if color is None else np.asarray(color).reshape(n, 3)
    return np.asarray(rgb, dtype=float) / 255.0


def _pose(x: float, y: float, z: float, qz: float, qw: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=qz, w=qw))


def _robot_disc(x: float, y: float, qz: float, qw: float, d: float, red: float, green: float, blue: float) -> Any:
    return CylinderPrimitive(
        pose=_pose(x, y, DISC_HEIGHT / 2, qz, qw),
        size=Vector3(x=d, y=d, z=DISC_HEIGHT),
        bottom_scale=1.0,
        top_scale=1.0,
        color=Color(r=red, g=green, b=blue, a=1.0),
    )


def _heading_arrow(x: float, y: float, qz: float, qw: float, shaft: float, width: float, head: float) -> Any:
    return ArrowPrimitive(
        pose=_pose(x, y, DISC_HEIGHT, qz, qw),
        shaft_length=shaft,
        shaft_diameter=width,
        head_length=head,
        head_diameter=head,
        color=Color(r=HEADING_COLOR[0], g=HEADING_COLOR[1], b=HEADING_COLOR[2], a=1.0),
    )


def _goal_sphere(x: float, y: float, half: float, d: float, red: float, green: float, blue: float) -> Any:
    color = Color(r=red, g=green, b=blue, a=GOAL_ALPHA)
    return SpherePrimitive(pose=_pose(x, y, half, *UNTURNED), size=Vector3(x=d, y=d, z=d), color=color)


def scene_update(
    t_ns: int,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None = None,
    *,
    goal: np.ndarray | None = None,
    heading: bool = True,
) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` at ``t_ns`` of an entity ``robot/<id>`` a robot: its disc in its LED
    colour (None: grey), heading arrow, and goal (NaN: none) as a sphere and in its metadata. A robot whose
    position or radius is not finite is deleted, so a robot that has left does not linger."""
    pose, radius, rgb, drawn = _robots(pose, radius, color)
    n = len(pose)
    goal_xy = np.full((n, 2), np.nan) if goal is None else np.asarray(goal, dtype=float).reshape(n, 2)
    theta = np.where(np.isfinite(pose[:, 2]), pose[:, 2], 0.0)
    has_goal = np.isfinite(goal_xy).all(axis=1)
    x, y, r, qz, qw, red, green, blue, gx, gy = _columns(
        pose[:, :2], radius, np.sin(theta / 2), np.cos(theta / 2), rgb, goal_xy
    ).T
    d = 2 * r * GOAL_SIZE
    parts = [_records(CYLINDERS, _robot_disc, np.column_stack([x, y, qz, qw, 2 * r, red, green, blue]))]
    if heading:
        parts.append(_records(ARROWS, _heading_arrow, np.column_stack([x, y, qz, qw, 0.6 * r, 0.15 * r, 0.35 * r])))
    robots = np.hstack(parts)  # a robot's disc (and arrow), a row each
    spheres = _records(SPHERES, _goal_sphere, np.column_stack([gx, gy, d / 2, d, red, green, blue]))
    stamp = _timestamp(t_ns)
    deletions = [_deleted(stamp, f"robot/{i}") for i in np.flatnonzero(~drawn).tolist()]
    entities = []
    for i in np.flatnonzero(drawn).tolist():
        metadata = [KeyValuePair(key="goal", value=f"{gx[i]:.3f}, {gy[i]:.3f}")] if has_goal[i] else []
        body = robots[i].tobytes() + (spheres[i].tobytes() if has_goal[i] else b"")
        entities.append(length_delimited(ENTITIES, _head(stamp, f"robot/{i}", metadata) + body))
    return SceneUpdate(deletions=deletions, entities=[]).encode() + b"".join(entities)


# field numbers in Foxglove's schemas (foxglove/SceneUpdate.proto, foxglove/SceneEntity.proto)
ENTITIES = 2
ARROWS, SPHERES, CYLINDERS = 7, 9, 10


@functools.lru_cache(maxsize=16)  # the per-robot primitives' templates, the same every tick
def _template(number: int, one: Callable[..., Any], values: int) -> tuple[bytes, list[list[int]]]:
    """The field ``number`` holding ``one`` primitive of stand-in values, and where each value is."""
    stand_ins = [1000.0 + j + 2.0**-30 for j in range(values)]  # a value no primitive holds
    record = length_delimited(number, one(*stand_ins).encode())
    doubles = [struct.pack("<d", v) for v in stand_ins]
    places = [[k for k in range(len(record)) if record[k : k + 8] == d] for d in doubles]  # where each value is
    if not all(places):
        raise ValueError("a primitive holds each of its values as a double")
    return record, places


def _records(number: int, one: Callable[..., Any], columns: np.ndarray) -> np.ndarray:
    """A repeated field's records, a row of bytes per row of ``columns`` (n, k): the SDK's encoding of one
    primitive copied n times with each row's doubles in their places (object by object is too slow)."""
    record, places = _template(number, one, columns.shape[1])
    out = np.tile(np.frombuffer(record, np.uint8), (len(columns), 1))
    doubles = np.ascontiguousarray(columns, "<f8").view(np.uint8).reshape(len(columns), -1, 8)
    for j, at in enumerate(places):
        for k in at:  # a disc's diameter is its size's x and y
            out[:, k : k + 8] = doubles[:, j]
    return out


def _one_entity(t_ns: int, entity: str, primitives: bytes) -> bytes:
    """A SceneUpdate of one entity holding ``primitives`` (encoded fields), or deleting it if none."""
    stamp = _timestamp(t_ns)
    if not primitives:
        return SceneUpdate(deletions=[_deleted(stamp, entity)], entities=[]).encode()
    return length_delimited(ENTITIES, _head(stamp, entity) + primitives)


def _swarm_disc(x: float, y: float, d: float, red: float, green: float, blue: float) -> CylinderPrimitive:
    return _robot_disc(x, y, *UNTURNED, d, red, green, blue)  # unturned: the same at any heading


def _columns(*parts: np.ndarray) -> np.ndarray:
    """The parts side by side (e.g. x, y, diameter, r, g, b), quantised (:data:`QUANTUM`)."""
    return np.round(np.column_stack(parts) / QUANTUM) * QUANTUM


def swarm_scene(t_ns: int, pose: np.ndarray, radius: np.ndarray, color: np.ndarray | None = None) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` of the whole swarm as one entity, :data:`SWARM_ENTITY` (so the panel
    needs only the newest message): a disc a drawn robot in its LED colour (None: grey); none deletes it."""
    pose, radius, rgb, drawn = _robots(pose, radius, color)
    columns = _columns(pose[drawn, :2], 2 * radius[drawn], rgb[drawn])
    return _one_entity(t_ns, SWARM_ENTITY, _records(CYLINDERS, _swarm_disc, columns).tobytes() if drawn.any() else b"")


def goal_markers(t_ns: int, goals: np.ndarray, color: np.ndarray | None, diameter: float) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` of a goal set as one entity, :data:`GOALS_ENTITY`: a translucent
    sphere of ``diameter`` (m) a finite goal (G,2) in its RGB colour (None: grey); none deletes it."""
    goals = np.asarray(goals, dtype=float).reshape(-1, 2)
    rgb = _rgb(color, len(goals))
    keep = np.isfinite(goals).all(axis=1)
    d = float(np.round(diameter / QUANTUM) * QUANTUM)
    sizes = np.broadcast_to([d / 2, d], (int(keep.sum()), 2))  # a sphere's centre height and diameter
    columns = np.column_stack([_columns(goals[keep]), sizes, _columns(rgb[keep])])
    return _one_entity(t_ns, GOALS_ENTITY, _records(SPHERES, _goal_sphere, columns).tobytes() if keep.any() else b"")
