"""Stop every robot of a hardware file: for `pixelswarm stop --hardware FILE`, when a run died and left
robots moving (a real e-puck2 keeps its last wheel speeds until told otherwise)."""

from __future__ import annotations

from transport.session import ZenohSettings

from .config import HardwareConfig, need


def stop_all(config: HardwareConfig, settings: ZenohSettings | None = None) -> list[int]:
    """Send every robot of the file a stop; returns the robot ids not reached. ``settings``: the session to
    a router, for robots reached through one (ROS 2)."""
    need(hasattr(config.backend, "stop_robots"), f"{config.path} [backend]: kind {config.backend_kind!r} has no stop")
    return config.backend.stop_robots(settings)
