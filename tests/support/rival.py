"""A second controller on one robot's key, as whoever holds its stolen credentials would be: at each tick of
the world's clock, before the robot's agent has answered it, a command of its own for that tick driving the
robot at full speed toward the arena's centre (where a circle's robots cross)."""

from __future__ import annotations

import math
import threading

from transport.bus import Bus
from transport.codec import Command, Commands, Pose, Tick
from transport.session import ZenohSettings


class Rival:
    def __init__(self, endpoint: str, robot: int, speed: float) -> None:
        self.robot, self.speed, self.sent = robot, speed, 0
        self.bus = Bus(ZenohSettings(mode="client", connect=[endpoint]), name="rival")
        self.clock = self.bus.subscribe(self.bus.keys.clock, Tick)
        self.pose = self.bus.subscribe(self.bus.keys.pose(robot), Pose)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._drive, daemon=True)
        self.thread.start()

    def _drive(self) -> None:
        where = None
        while not self.stopping.is_set():
            got = self.clock.get(timeout=0.1)
            for _, pose in self.pose.drain():
                if pose.robot == self.robot:
                    where = pose
            if got is None or where is None:
                continue
            tick = got[1]
            away = math.hypot(where.x, where.y) or 1.0
            vx, vy = -self.speed * where.x / away, -self.speed * where.y / away
            command = Command(self.robot, tick.tick, tick.stamp, Command.HOLONOMIC, vx, vy, 255, 0, 0)
            self.bus.publish_frame(Commands, tick.tick, tick.stamp, [command], self.bus.keys.cmd(self.robot))
            self.sent += 1

    def close(self) -> None:
        self.stopping.set()
        self.thread.join(5)
        self.bus.close()
