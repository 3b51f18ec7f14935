"""The display as Foxglove's ``foxglove.SceneUpdate``, built with Foxglove's own SDK (``foxglove-sdk``).

The SDK's message types (:mod:`foxglove.messages`) are encoded as protobuf with the schema Foxglove publishes,
so Foxglove's 3D panel shows a run with no configuration. :func:`scene_update` makes one entity per robot,
``robot/<id>``: its disc in its LED colour, a heading arrow, its goal as a translucent sphere, and the goal in
its metadata (hover in the 3D panel). A swarm of thousands is drawn by :func:`swarm_scene` as one entity,
:data:`SWARM_ENTITY` (a disc per robot), and its goals by :func:`goal_markers`, written when the goal set
changes. Every entity is in the one frame :data:`DISPLAY_FRAME`, so the panel needs no transform.
"""

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
FLAT = (0.0, 0.0, 0.0, 1.0)  # the identity rotation
QUANTUM = 2.0**-14  # lengths to 1/16384 m, colours and rotations to 1/16384: far below what a viewer sees.
# A power of two, so each double's low mantissa bytes are zeros and a robot at rest repeats the same bytes
# tick after tick: the log's compression stores both once


def _timestamp(t_ns: int) -> Timestamp:
    t_ns = int(t_ns)
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


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
    return SpherePrimitive(pose=_pose(x, y, half, *FLAT[2:]), size=Vector3(x=d, y=d, z=d), color=color)


def scene_update(
    t_ns: int,
    pose: np.ndarray,
    radius: np.ndarray,
    color: np.ndarray | None = None,
    *,
    goal: np.ndarray | None = None,
    heading: bool = True,
) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` at time ``t_ns`` (ns) for N robots.

    ``pose`` (N,3) x, y, theta; ``radius`` (N,) or scalar, m; ``color`` (N,3) LED RGB uint8 (None:
    grey); ``goal`` (N,2) with NaN = no goal.  A robot whose position or radius is not finite is
    not drawn, and its earlier entity is deleted, so a robot that has left does not linger.
    Write it on a channel added with ``McapLog.add_foxglove_channel(topic, SceneUpdate)``.

    Each robot's disc, arrow and goal sphere are the SDK's encoding of one, copied with the robot's
    numbers (:func:`_records`); the SDK builds each entity's head (its id and metadata).
    """
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    n = len(pose)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    rgb = np.broadcast_to(NO_LED, (n, 3)) if color is None else np.asarray(color).reshape(n, 3)
    goal_xy = np.full((n, 2), np.nan) if goal is None else np.asarray(goal, dtype=float).reshape(n, 2)
    theta = np.where(np.isfinite(pose[:, 2]), pose[:, 2], 0.0)
    drawn = np.isfinite(pose[:, :2]).all(axis=1) & np.isfinite(radius) & (radius > 0)
    has_goal = np.isfinite(goal_xy).all(axis=1)
    x, y, r, qz, qw, red, green, blue, gx, gy = _columns(
        pose[:, :2], radius, np.sin(theta / 2), np.cos(theta / 2), np.asarray(rgb, dtype=float) / 255.0, goal_xy
    ).T
    d = 2 * r * GOAL_SIZE
    parts = [_records(CYLINDERS, _robot_disc, np.column_stack([x, y, qz, qw, 2 * r, red, green, blue]))]
    if heading:
        parts.append(_records(ARROWS, _heading_arrow, np.column_stack([x, y, qz, qw, 0.6 * r, 0.15 * r, 0.35 * r])))
    robots = np.hstack(parts)  # a robot's disc (and arrow), a row each
    spheres = _records(SPHERES, _goal_sphere, np.column_stack([gx, gy, d / 2, d, red, green, blue]))
    stamp, forever = _timestamp(t_ns), Duration(sec=0, nsec=0)
    entities, deletions = [], []
    for i in range(n):
        if not drawn[i]:
            deletions.append(
                SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=f"robot/{i}")
            )
            continue
        metadata = [KeyValuePair(key="goal", value=f"{gx[i]:.3f}, {gy[i]:.3f}")] if has_goal[i] else []
        head = SceneEntity(
            timestamp=stamp, frame_id=DISPLAY_FRAME, id=f"robot/{i}", lifetime=forever, metadata=metadata
        )
        body = robots[i].tobytes() + (spheres[i].tobytes() if has_goal[i] else b"")
        entities.append(length_delimited(ENTITIES, head.encode() + body))
    return SceneUpdate(deletions=deletions, entities=[]).encode() + b"".join(entities)


# SceneUpdate's and SceneEntity's field numbers in Foxglove's schema (foxglove/SceneUpdate.proto,
# foxglove/SceneEntity.proto)
ENTITIES = 2
ARROWS, SPHERES, CYLINDERS = 7, 9, 10


def _places(record: bytes, value: float) -> list[int]:
    """Where a double ``value`` is in ``record``."""
    packed, places = struct.pack("<d", value), list[int]()
    while (k := record.find(packed, places[-1] + 1 if places else 0)) >= 0:
        places.append(k)
    return places


@functools.lru_cache(maxsize=16)  # the per-robot primitives' templates, the same every tick
def _template(number: int, one: Callable[..., Any], values: int) -> tuple[bytes, list[list[int]]]:
    """The field ``number`` holding ``one`` primitive of stand-in values, and where each value is."""
    stand_ins = [1000.0 + j + 2.0**-30 for j in range(values)]  # a value no primitive holds
    record = length_delimited(number, one(*stand_ins).encode())
    places = [_places(record, v) for v in stand_ins]
    if not all(places):
        raise ValueError("a primitive holds each of its values as a double")
    return record, places


def _records(number: int, one: Callable[..., Any], columns: np.ndarray) -> np.ndarray:
    """A repeated message field's records, a row of bytes per row of ``columns`` (n, k): the SDK's
    encoding of one primitive, ``one(*k values)``, made with k distinct stand-in values, then copied n
    times with each row's doubles in their places: the SDK building objects one by one is too slow for a
    large swarm."""
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
        deleted = SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=entity)
        return SceneUpdate(deletions=[deleted], entities=[]).encode()
    head = SceneEntity(timestamp=stamp, frame_id=DISPLAY_FRAME, id=entity, lifetime=Duration(sec=0, nsec=0))
    return length_delimited(ENTITIES, head.encode() + primitives)


def _swarm_disc(x: float, y: float, d: float, red: float, green: float, blue: float) -> CylinderPrimitive:
    return _robot_disc(x, y, *FLAT[2:], d, red, green, blue)  # unturned: the same at any heading


def _columns(*parts: np.ndarray) -> np.ndarray:
    """The parts side by side (e.g. x, y, diameter, r, g, b), quantised (:data:`QUANTUM`)."""
    columns = np.column_stack(parts)
    return np.round(columns / QUANTUM) * QUANTUM


def swarm_scene(t_ns: int, pose: np.ndarray, radius: np.ndarray, color: np.ndarray | None = None) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` of N robots as one entity, :data:`SWARM_ENTITY`: a disc per
    robot with a finite position and radius, in its LED colour (None: grey), in robot order; no
    such robot deletes the entity.

    Every message holds the whole swarm, so the panel needs only the newest one (all it reads
    back when the player seeks). A disc has the identity rotation: it looks the same at any heading."""
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    n = len(pose)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    rgb = np.broadcast_to(NO_LED, (n, 3)) if color is None else np.asarray(color).reshape(n, 3)
    drawn = np.isfinite(pose[:, :2]).all(axis=1) & np.isfinite(radius) & (radius > 0)
    columns = _columns(pose[drawn, :2], 2 * radius[drawn], np.asarray(rgb, dtype=float)[drawn] / 255.0)
    return _one_entity(t_ns, SWARM_ENTITY, _records(CYLINDERS, _swarm_disc, columns).tobytes() if drawn.any() else b"")


def goal_markers(t_ns: int, goals: np.ndarray, color: np.ndarray | None, diameter: float) -> bytes:
    """An encoded ``foxglove.SceneUpdate`` of a goal set as one entity, :data:`GOALS_ENTITY`: a
    translucent sphere of ``diameter`` (m) per finite goal of ``goals`` (G,2) in its colour
    ``color`` (G,3) RGB uint8 (None: grey); no finite goal deletes the entity."""
    goals = np.asarray(goals, dtype=float).reshape(-1, 2)
    rgb = np.broadcast_to(NO_LED, (len(goals), 3)) if color is None else np.asarray(color).reshape(-1, 3)
    keep = np.isfinite(goals).all(axis=1)
    d = float(np.round(diameter / QUANTUM) * QUANTUM)
    sizes = np.broadcast_to([d / 2, d], (int(keep.sum()), 2))  # a sphere's centre height and diameter
    columns = np.column_stack([_columns(goals[keep]), sizes, _columns(np.asarray(rgb, dtype=float)[keep] / 255.0)])
    return _one_entity(t_ns, GOALS_ENTITY, _records(SPHERES, _goal_sphere, columns).tobytes() if keep.any() else b"")
