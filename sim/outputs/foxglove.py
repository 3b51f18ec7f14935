"""The display as Foxglove's ``foxglove.SceneUpdate``, built with Foxglove's own SDK (``foxglove-sdk``).

The message types are the SDK's (:mod:`foxglove.messages`): typed, and encoded as protobuf with
the schema Foxglove publishes, so Foxglove's 3D panel shows a run with no configuration and the
file is several times smaller than the JSON it replaces.

:func:`scene_update` builds one message: one entity per robot, ``robot/<id>``, holding its disc
(a flat cylinder, the robot's diameter, its LED colour), a heading arrow and, if it has one, its
goal as a small translucent sphere in the same colour; the entity's metadata says the robot's goal
(hover over it in the 3D panel).  Every entity is in the one frame :data:`DISPLAY_FRAME`, so no
transform is needed for the panel to draw them.
"""

from __future__ import annotations

from collections.abc import Iterable
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

__all__ = ["SCENE_UPDATE_SCHEMA_NAME", "DISPLAY_FRAME", "SceneUpdate", "scene_update"]

SCENE_UPDATE_SCHEMA_NAME = "foxglove.SceneUpdate"
DISPLAY_FRAME = "display"  # the plane the robots move on, x right and y up as in the arena (metres)

DISC_HEIGHT = 0.01  # m: a flat disc, as a robot's LED top is seen from above
GOAL_SIZE = 0.4  # goal sphere diameter, as a fraction of the robot's diameter
GOAL_ALPHA = 0.5  # a goal is where the robot's colour will be, not a robot
NO_LED = (160, 160, 160)  # RGB of a robot whose LED colour is not known
HEADING_COLOR = (0.1, 0.1, 0.1)
FLAT = (0.0, 0.0, 0.0, 1.0)  # the identity rotation
QUANTUM = 2.0**-14  # lengths to 1/16384 m (0.06 mm), colours and rotations to 1/16384: far below what a
# viewer sees. A power of two, so each double's low mantissa bytes are zeros (decimal rounding left them
# noise), and a robot at rest repeats the same bytes tick after tick: the log's compression stores both once


def _quantised(a: Any) -> list:
    return (np.round(np.asarray(a, dtype=float) / QUANTUM) * QUANTUM).tolist()


def _timestamp(t_ns: int) -> Timestamp:
    t_ns = int(t_ns)
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def _pose(x: float, y: float, z: float, qz: float, qw: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=qz, w=qw))


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
) -> SceneUpdate:
    """A ``foxglove.SceneUpdate`` at time ``t_ns`` (ns) for N robots.

    ``pose`` (N,3) x, y, theta; ``radius`` (N,) or scalar, m; ``color`` (N,3) LED RGB uint8 (None:
    grey); ``goal`` (N,2) with NaN = no goal.  A robot whose position or radius is not finite is
    not drawn, and its earlier entity is deleted, so a robot that has left does not linger.
    Write it on a channel added with ``McapLog.add_foxglove_channel(topic, SceneUpdate)``.
    """
    pose = np.asarray(pose, dtype=float).reshape(-1, 3)
    n = len(pose)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    rgb = np.broadcast_to(NO_LED, (n, 3)) if color is None else np.asarray(color).reshape(n, 3)
    rgb_unit = _quantised(np.asarray(rgb, dtype=float) / 255.0)
    goal_xy = np.full((n, 2), np.nan) if goal is None else np.asarray(goal, dtype=float).reshape(n, 2)
    ids = [str(i) for i in (range(n) if ids is None else ids)]
    theta = np.where(np.isfinite(pose[:, 2]), pose[:, 2], 0.0)
    qz, qw = _quantised(np.sin(theta / 2)), _quantised(np.cos(theta / 2))
    drawn = (np.isfinite(pose[:, :2]).all(axis=1) & np.isfinite(radius) & (radius > 0)).tolist()
    has_goal = np.isfinite(goal_xy).all(axis=1).tolist()
    xy, r, gxy = (_quantised(a) for a in (pose[:, :2], radius, goal_xy))
    stamp = _timestamp(t_ns)
    forever = Duration(sec=0, nsec=0)
    dark = Color(r=HEADING_COLOR[0], g=HEADING_COLOR[1], b=HEADING_COLOR[2], a=1.0)

    entities, deletions = [], []
    for i in range(n):
        if not drawn[i]:
            deletions.append(
                SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id=f"robot/{ids[i]}")
            )
            continue
        x, y = xy[i]
        red, green, blue = rgb_unit[i]
        cylinders = [
            CylinderPrimitive(
                pose=_pose(x, y, height / 2, qz[i], qw[i]),
                size=Vector3(x=2 * r[i], y=2 * r[i], z=height),
                bottom_scale=1.0,
                top_scale=1.0,
                color=Color(r=red, g=green, b=blue, a=1.0),
            )
        ]
        arrows = []
        if heading:
            arrows.append(
                ArrowPrimitive(
                    pose=_pose(x, y, height, qz[i], qw[i]),
                    shaft_length=0.6 * r[i],
                    shaft_diameter=0.15 * r[i],
                    head_length=0.35 * r[i],
                    head_diameter=0.35 * r[i],
                    color=dark,
                )
            )
        spheres, metadata = [], []
        if has_goal[i]:
            d = 2 * r[i] * GOAL_SIZE
            gx, gy = gxy[i]
            spheres.append(
                SpherePrimitive(
                    pose=_pose(gx, gy, d / 2, *FLAT[2:]),
                    size=Vector3(x=d, y=d, z=d),
                    color=Color(r=red, g=green, b=blue, a=GOAL_ALPHA),
                )
            )
            metadata.append(KeyValuePair(key="goal", value=f"{gx:.3f}, {gy:.3f}"))
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=frame_id,
                id=f"robot/{ids[i]}",
                lifetime=forever,
                frame_locked=False,
                metadata=metadata,
                cylinders=cylinders,
                arrows=arrows,
                spheres=spheres,
            )
        )
    return SceneUpdate(deletions=deletions, entities=entities)
