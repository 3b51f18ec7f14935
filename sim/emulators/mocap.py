"""A motion-capture driver node as ROS 2 sees it: PoseStamped per robot over rmw_zenoh at a fixed rate.

python -m sim.emulators.mocap --robots 4 --rate 100 -e tcp/127.0.0.1:7447
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from hardware.config import HardwareConfigError, every
from hardware.ros2 import POSE_STAMPED, Ros2Messages, Ros2Node, Ros2PosesConfig
from sim.args import OneLineParser, positive_int, positive_number, positive_seconds, refuse
from sim.processes import stopped_by_signals
from transport.rmw_zenoh import RosPublisher
from transport.session import TransportError, ZenohSettings, add_zenoh_args, settings_from_args

RMW_ZENOHD = "tcp/127.0.0.1:7447"  # where rmw_zenohd listens by default

PoseFunction = Callable[[float], np.ndarray]  # s since start -> (N, 3) rows of x (m), y (m), theta (rad)


class MocapEmulator(Ros2Node):
    """Publishes ``poses(t)`` (row i: robot i) as PoseStamped on ``topic`` (with {id}) at ``rate`` Hz,
    stamped by ``clock`` (the motion-capture machine's wall clock; a test may set it back or ahead)."""

    NODE_NAME = "mocap_emulator"

    def __init__(
        self,
        poses: PoseFunction,
        session_config: ZenohSettings,
        topic: str = Ros2PosesConfig.topic,
        domain: int = 0,
        rate: float = 100.0,
        frame_id: str = "world",
        clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(session_config)
        self.config = Ros2PosesConfig(topic=topic, domain=domain, rate=rate)  # the same checks as a reader's
        self.poses = poses
        self.frame_id = frame_id
        self.clock = clock
        self.messages = Ros2Messages()
        self.published = 0
        self.last_sent = -math.inf  # monotonic s when the last poses were handed to zenoh
        self.error: Exception | None = None  # what stopped the publishing thread, if anything did
        self._publishers: list[RosPublisher] = []

    def start(self) -> None:
        """Open the session and publish; after close(), start() again publishes anew (a mocap restarted)."""
        self._halt.clear()
        self._publishers = []
        self._node = self._open(self.config.domain or 0)
        self._start = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="mocap", daemon=True)
        self._thread.start()

    def publish_once(self, t: float) -> None:
        rows = np.asarray(self.poses(t), float).reshape(-1, 3)
        stamp = self.clock()
        pose_hash = self.messages.type_hash(POSE_STAMPED)
        while len(self._publishers) < len(rows):
            topic = self.config.topic_of(len(self._publishers))
            self._publishers.append(self._node.publisher(topic, POSE_STAMPED, pose_hash))
        for pub, (x, y, theta) in zip(self._publishers, rows):
            pub.publish(self.messages.pose_stamped(x, y, theta, stamp, self.frame_id))
        self.published += len(rows)
        self.last_sent = time.monotonic()

    def _run(self) -> None:
        self.error = every(1.0 / self.config.rate, self._start, self._halt, self.publish_once)


def circle(robots: int, radius: float, speed: float) -> PoseFunction:
    """Robots evenly spaced on a circle about the origin, driving round it at ``speed`` m/s (> 0: anticlockwise)."""
    phase = 2 * math.pi * np.arange(robots) / robots
    travel = math.copysign(math.pi / 2, speed)  # heading relative to the robot's bearing from the centre

    def poses(t: float) -> np.ndarray:
        angle = phase + speed / radius * t
        heading = np.arctan2(np.sin(angle + travel), np.cos(angle + travel))
        return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), heading])

    return poses


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m sim.emulators.mocap",
        description="Publish motion-capture poses (geometry_msgs/PoseStamped) over rmw_zenoh: robots on a circle.",
    )
    parser.add_argument("--robots", type=positive_int, default=4, help="number of robots (default 4)")
    parser.add_argument("--rate", type=positive_number, default=100.0, help="Hz (default 100)")
    parser.add_argument("--radius", type=positive_number, default=0.5, help="circle radius in m (default 0.5)")
    parser.add_argument(
        "--speed", type=float, default=0.1, help="speed along the circle in m/s, negative for clockwise (default 0.1)"
    )
    parser.add_argument("--topic", default=Ros2PosesConfig.topic, help="topic with {id} (default %(default)s)")
    parser.add_argument("--domain", type=int, default=0, help="ROS domain id (default 0)")
    parser.add_argument("--frame", default="world", help="header frame_id (default world)")
    parser.add_argument("--duration", type=positive_seconds, help="stop after this many s (default: run until Ctrl-C)")
    add_zenoh_args(parser, default_mode="client")
    args = parser.parse_args(argv)
    settings = settings_from_args(args)
    if not settings.connect and settings.mode != "router":
        settings.connect = [RMW_ZENOHD]
    poses = circle(args.robots, args.radius, args.speed)
    try:
        emulator = MocapEmulator(poses, settings, args.topic, args.domain, args.rate, args.frame)
        with stopped_by_signals() as stop, emulator:
            print(f"mocap: {args.robots} robots on {emulator.config.topic} at {args.rate:g} Hz", flush=True)
            stop.wait(args.duration)
            if emulator.error is not None:
                print(f"{parser.prog}: error: the pose function failed: {emulator.error}", file=sys.stderr)
                return 1
    except (HardwareConfigError, TransportError) as err:
        return refuse(parser.prog, err)
    return 0


if __name__ == "__main__":
    sys.exit(main())
