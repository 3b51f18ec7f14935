"""Peers that lie to one robot. Rival: a second controller on its key, as whoever holds its stolen credentials
would be: at each tick of the world's clock, before the robot's agent has answered it, a command of its own for
that tick driving the robot at full speed toward the arena's centre (where a circle's robots cross).
NextTick: at each tick of the world's clock, the next tick's clock message (naming another goal set, if asked) and
the robot's pose for it at its last place, before the world has moved it there: the robot would drive a tick
behind itself. FalseReports: the world's final report and agents' statistics, forged and malformed, every 0.2 s."""

from __future__ import annotations

import math
import threading

from transport.bus import Bus
from transport.codec import BEFORE_START, Command, Commands, Event, Pose, Poses, Tick
from transport.session import ZenohSettings


class Peer:
    """A session of its own on the run's router, its work (``_run``) on a thread until ``close``."""

    def __init__(self, endpoint: str, name: str) -> None:
        self.sent = 0
        self.bus = Bus(ZenohSettings(mode="client", connect=[endpoint]), name=name)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        self.stopping.set()
        self.thread.join(5)
        self.bus.close()


class Rival(Peer):
    def __init__(self, endpoint: str, robot: int, speed: float) -> None:
        super().__init__(endpoint, "rival")
        self.robot, self.speed = robot, speed
        self.clock = self.bus.subscribe(self.bus.keys.clock, Tick)
        self.pose = self.bus.subscribe(self.bus.keys.pose(robot), Pose)
        self.thread.start()

    def _run(self) -> None:
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


class NextTick(Peer):
    def __init__(self, endpoint: str, robot: int | None, goal_epoch: int | None = None) -> None:
        """``robot``: whose pose to forge (None: none); ``goal_epoch``: the goal set the forged clocks name."""
        super().__init__(endpoint, "forger")
        self.robot, self.goal_epoch = robot, goal_epoch
        self.watched = 0 if robot is None else robot  # whose poses say which tick the world is at
        self.clock = self.bus.subscribe(self.bus.keys.clock, Tick)
        self.pose = self.bus.subscribe(self.bus.keys.pose(self.watched), Pose)
        self.thread.start()

    def _run(self) -> None:
        where, forged = None, set()
        echoed: dict[str, set[int]] = {"clock": set(), "pose": set()}

        def honest(kind: str, tick: int) -> bool:  # the forger hears its own messages, and before the world's
            if tick in forged and tick not in echoed[kind]:
                echoed[kind].add(tick)
                return False
            return True

        while not self.stopping.is_set():
            got = self.clock.get(timeout=0.1)
            for _, pose in self.pose.drain():
                mine = pose.robot == self.watched and pose.tick != BEFORE_START and honest("pose", pose.tick)
                if mine and (where is None or pose.tick > where.tick):
                    where = pose
            if got is None or where is None or not honest("clock", got[1].tick) or got[1].tick < where.tick:
                continue
            now = got[1]
            dt = round(now.dt, 6)  # the period as the scene says it (the clock carries it as a float32)
            tick, stamp = now.tick + 1, (now.tick + 1) * dt
            forged.add(tick)
            epoch = now.goal_epoch if self.goal_epoch is None else self.goal_epoch
            self.bus.publish(self.bus.keys.clock, Tick(tick, stamp, dt, epoch))
            if self.robot is not None:
                forged_pose = Pose(self.robot, tick, stamp, where.x, where.y, where.theta)
                self.bus.publish(self.bus.keys.pose(self.robot), Poses.one(forged_pose))
            self.sent += 1


class FalseReports(Peer):
    REPORTS = (
        {
            "kind": "world-done",
            "reason": "duration",
            "ticks": 1,
            "missed_ticks": 0,
            "contacts": [],
            "min_clearance": 1.0,
        },
        {"kind": "world-done", "reason": "x", "missed_ticks": "many", "contacts": 5, "commands_applied": "x"},
        {"kind": "stats", "role": "agent", "robots": 7, "dropped": {"a": "b"}},
        {"kind": "stats", "role": "agent", "robots": [0, "x"], "dropped": {"stale": 10**9}},
        {"kind": "stats", "role": "agent", "robots": [0], "fallbacks": "x", "poses_held": [1], "auction": "x"},
        {
            "kind": "stats",
            "role": "agent",
            "robots": [1],
            "lockstep_gave_up": {"goal_sets": -7, "neighbour_states": 1.5},
        },
    )

    def __init__(self, endpoint: str) -> None:
        super().__init__(endpoint, "reports")
        self.thread.start()

    def _run(self) -> None:
        while not self.stopping.wait(0.2):
            for report in self.REPORTS:
                self.bus.publish(self.bus.keys.event, Event(report))
            self.sent += 1
