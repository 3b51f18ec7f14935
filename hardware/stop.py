"""Stop every robot of a hardware file: for `pixelswarm stop --hardware FILE`, when a run died and left
robots moving (a real e-puck2 keeps its last wheel speeds until told otherwise)."""

from __future__ import annotations

from transport.session import ZenohSettings

from .config import HardwareConfig, load_object, need

# kind -> "module:function" taking the backend's config and returning the robot ids the stop did not reach
STOPPERS = {
    "epuck2": "hardware.epuck2:stop_robots",
    "ros2": "hardware.ros2:stop_robots",
    "sim": None,  # nothing real to stop
}


def stop_all(config: HardwareConfig, settings: ZenohSettings | None = None) -> list[int]:
    """Connect to every robot of the file and send it a stop; returns the robot ids that were not reached.
    ``settings``: the session to a router, for robots reached through one (ROS 2)."""
    kind = config.backend_kind
    need(kind in STOPPERS, f"{config.path} [backend]: kind {kind!r} has no stop")
    target = STOPPERS[kind]
    if target is None:
        return []
    return load_object(target, kind, f"{config.path} [backend]")(config.backend, settings)
