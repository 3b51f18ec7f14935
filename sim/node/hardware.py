"""The hardware process: real robots as the body node's bodies (sim/node/body.py), on the wall clock.

Agents cannot tell it from the simulated world. A robot whose pose has been lost longer than the command
timeout is not published and is stopped; every robot is stopped however the run ends. See docs/hardware.md.

    python -m sim.node.hardware --hardware hw.toml --scene paper-sequence -e tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from agent.core.params import DIFFDRIVE, RobotParams
from coordinator.resolved import add_scene_args, scene_of_args
from coordinator.scene import Scene, SceneError
from hardware.config import HardwareConfig, HardwareConfigError, load_hardware
from hardware.poses import STAMP_DROPS, PoseSample
from sim.args import format_ids, refuse
from sim.bodies.world import Contact
from sim.node.body import COMMAND_DROPS, STOP_REASONS, BodyNode, WallClock
from sim.outputs.metrics import clearance_at
from transport.bus import Bus
from transport.codec import Command, State
from transport.session import TransportError, ZenohSettings, add_zenoh_args, settings_from_args

STARTUP_TIMEOUT = 5.0  # s: every robot reached and every robot's pose seen, or the run is refused
POLL = 0.02  # s: how often, within a period, commands, liveliness and safety are looked at
PROG = "hardware"
ERROR = f"{PROG}: error: "  # how refuse's one line starts, which the launcher shows when the node refuses to start
# a robot driven at this share of v_max or more moves, and its measurement jitters: FROZEN_AFTER new poses
# the very same in a row are a stuck tracker (a held marker, a frozen stream), and the robot is stopped as lost
FROZEN_SPEED, FROZEN_AFTER = 0.25, 5
RUNNABLE_BACKENDS = ("epuck2", "ros2")


class HardwareError(Exception):
    """The hardware cannot be used for a run: one line for the user."""


class BackendDrive:
    """What the drives share: the backend starts and closes itself. A drive's where(robot) says where a robot
    is reached (an address, a topic)."""

    backend: Any

    def start(self) -> None:
        self.backend.start()

    def robot_stats(self, robot: int) -> dict[str, int]:
        return {"reconnects": 0}

    def close(self) -> list[int]:
        """Stop every robot; the robots the stop did not reach (a topic has no answer: none)."""
        return self.backend.close() or []


class WheelDrive(BackendDrive):
    """e-puck2 robots take wheel speeds; the backend clips them to `max_wheel_speed`, here at most v_max."""

    def __init__(self, backend_config: Any, params: RobotParams) -> None:
        from hardware.epuck2 import Epuck2Backend

        limit = min(backend_config.max_wheel_speed, params.v_max)
        self.backend = Epuck2Backend(replace(backend_config, max_wheel_speed=limit))

    def send(self, ids: list[int], left: np.ndarray, right: np.ndarray, colors: np.ndarray) -> None:
        self.backend.set_commands(ids, left.tolist(), right.tolist(), colors.tolist())

    def unreached(self) -> list[int]:
        # connected is not enough: whatever listens at the address must answer as an e-puck2
        return [rid for rid, s in self.backend.stats().items() if not s.answered]

    def where(self, robot: int) -> str:
        return self.backend.config.addresses[robot]

    def why_unreached(self, robot: int) -> str:
        if self.backend.stats()[robot].connections:  # e.g. a web server at a mistyped port
            return f"{self.where(robot)}: something listens there but does not answer as an e-puck2"
        return self.where(robot)

    def robot_stats(self, robot: int) -> dict[str, int]:
        s = self.backend.stats()[robot]
        return {
            "packets_sent": s.commands_sent,
            "backend_late_commands": s.late_commands,
            "reconnects": s.reconnects,
            "backend_watchdog_stops": s.watchdog_stops,
        }


class TwistDrive(BackendDrive):
    """ROS 2 robots take a body velocity: wheel speeds become v = (l + r) / 2, omega = (r - l) / wheel base."""

    def __init__(self, backend_config: Any, settings: ZenohSettings, params: RobotParams) -> None:
        from hardware.ros2 import Ros2Backend

        self.backend = Ros2Backend(backend_config, settings)
        self.wheel_base = params.wheel_base

    def send(self, ids: list[int], left: np.ndarray, right: np.ndarray, colors: np.ndarray) -> None:
        self.backend.set_commands(ids, (left + right) / 2, (right - left) / self.wheel_base, colors)

    def unreached(self) -> list[int]:
        return self.backend.unheard()  # a put has no answer: a subscription on the topic is what reaches a robot

    def where(self, robot: int) -> str:
        return self.backend.config.topic(robot, self.backend.config.cmd_topic)

    def why_unreached(self, robot: int) -> str:
        return f"nobody subscribes to {self.where(robot)}"


Drive = WheelDrive | TwistDrive  # start, send, unreached, why_unreached, where, robot_stats, close


def open_drive(config: HardwareConfig, settings: ZenohSettings, params: RobotParams) -> tuple[Drive, float]:
    """The drive and the hardware file's own command timeout (e-puck2 `command_timeout`, ROS 2 `watchdog`)."""
    backend = config.backend
    if config.backend_kind == "epuck2":
        return WheelDrive(backend, params), float(backend.command_timeout)
    return TwistDrive(backend, settings, params), float(backend.watchdog)


class PoseSource(Protocol):
    def start(self) -> Any: ...
    def latest(self) -> dict[int, PoseSample]: ...
    def stats(self) -> dict[str, int]: ...
    def robot_stats(self, robot: int) -> dict[str, int]: ...
    def close(self) -> None: ...


def open_pose_source(config: HardwareConfig, settings: ZenohSettings) -> tuple[PoseSource, str]:
    """The pose source and its name in messages."""
    assert config.poses is not None  # load_run() refuses a file without
    if config.poses_kind == "ros2":
        from hardware.ros2 import Ros2PoseSource

        return Ros2PoseSource(config.poses, settings), f"topic {config.poses.topic}"
    from hardware.camera import CameraPoseSource

    return CameraPoseSource(config.poses), f"camera {config.poses.source!r}"


class TrackedContacts:
    """The contacts a tracker sees: two tracked discs overlapping by more than tracking noise explains
    (noise_bound), the best evidence a run on real robots has; one event per pair while it lasts."""

    def __init__(self, params: RobotParams) -> None:
        self.diameter = 2.0 * params.radius
        self.reach = self.diameter - params.noise_bound  # centres nearer than this: a contact
        self.events: list[Contact] = []
        self._under_way: dict[tuple[int, int], Contact] = {}

    def update(self, pose: np.ndarray, tracked: np.ndarray, t: float) -> list[Contact]:
        """The contacts that began at display time ``t``; those no longer seen end there."""
        ids = np.flatnonzero(tracked)
        xy = pose[ids, :2]
        gap = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        pairs = zip(*np.nonzero(gap < self.reach))
        now = {(int(ids[a]), int(ids[b])): self.diameter - gap[a, b] for a, b in pairs if a < b}
        began = []
        for pair, depth in now.items():
            if pair not in self._under_way:
                self._under_way[pair] = Contact("robot", *pair, t, None, depth)
                began.append(self._under_way[pair])
            else:
                self._under_way[pair].max_depth = max(self._under_way[pair].max_depth, depth)
        for pair in [p for p in self._under_way if p not in now]:
            self._under_way.pop(pair).t_end = t
        self.events += began
        return began


class HardwareBodies:
    """Real robots as the node's bodies: a drive takes their commands, a pose source tells where they are.
    A command holds for the hardware's command timeout of wall time; a pose older than it is lost."""

    def __init__(self, drive: Drive, poses: PoseSource, params: RobotParams, n: int, timeout: float) -> None:
        self.drive, self.poses, self.params, self.timeout, self.n = drive, poses, params, timeout, n
        self.pose = np.zeros((n, 3))  # the last tracked pose of each robot
        self.stamp = np.full(n, -np.inf)  # and its stamp
        self.repeats = np.zeros(n, int)  # new poses the same as the one before while the robot was driven
        self.tracked = np.zeros(n, bool)  # its pose is fresh (not older than the timeout)
        self.wheels = np.zeros((n, 2))  # what each robot was last told (m/s)
        self.sent = np.zeros(n, int)  # commands handed to the drive, stops included
        self.touching = TrackedContacts(params)  # real robots report none (the lab's emulated bodies do, apart)
        self.began: list[Contact] = []  # the contacts the last poses sensed began, for the next step
        self.min_clearance = math.inf
        self.unreached: list[int] = []  # robots not told to stop when the run ended

    def sense(self, t: float) -> None:
        """Each robot's newest pose; a robot whose pose is older than the timeout, or whose tracker repeats
        the very same pose while the robot is driven (stuck), is not tracked now."""
        self.tracked[:] = False
        driven = np.abs(self.wheels).max(axis=1) >= FROZEN_SPEED * self.params.v_max
        for r, s in self.poses.latest().items():
            if 0 <= r < self.n and s.age <= self.timeout:
                if s.stamp != self.stamp[r]:  # a new measurement: the same pose, bit for bit, only if it stands
                    same = (s.x, s.y, s.theta) == tuple(self.pose[r])
                    self.repeats[r] = self.repeats[r] + driven[r] if same else 0  # stopped, a stuck one stays so
                self.pose[r], self.stamp[r] = (s.x, s.y, s.theta), s.stamp
                self.tracked[r] = self.repeats[r] < FROZEN_AFTER
        self.began += self.touching.update(self.pose, self.tracked, t)  # once a tick: the poses change only here

    def measure(self, t: float) -> np.ndarray:
        return self.pose

    def true_poses(self) -> np.ndarray:
        return self.pose

    def hold(self, cmd: Command) -> float | None:
        return time.monotonic() + self.timeout

    def horizon(self, span: float) -> float:
        return time.monotonic()

    def moving(self) -> np.ndarray:
        return np.any(self.wheels != 0, axis=1)

    def apply(self, ids: list[int], cmds: list[Command], colors: np.ndarray) -> None:
        v_max = self.params.v_max
        wheels = np.array([(c.a, c.b) for c in cmds], float)
        self._send(ids, np.clip(np.nan_to_num(wheels, nan=0.0, posinf=0.0, neginf=0.0), -v_max, v_max), colors)

    def stop(self, ids: list[int]) -> None:
        self._send(ids, np.zeros((len(ids), 2)), np.zeros((len(ids), 3), np.uint8))

    def _send(self, ids: list[int], wheels: np.ndarray, colors: np.ndarray) -> None:
        self.wheels[ids] = wheels
        self.sent[ids] += 1
        self.drive.send(ids, wheels[:, 0], wheels[:, 1], colors)

    @property
    def contacts(self) -> list[Contact]:
        return self.touching.events

    def step(self, span: float) -> list:
        """Real bodies move by themselves: the contacts that began are those the tracker saw last."""
        began, self.began = self.began, []
        return began

    def own_movers(self, tick: int, t: float) -> list[State]:
        return []

    def truth(self, tick: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        tracked = self.pose[self.tracked, :2]  # the smallest gap between their discs now (m)
        clearance = clearance_at(tracked, np.full(len(tracked), self.params.radius))
        self.min_clearance = min(self.min_clearance, clearance)
        speed = self.wheels.mean(axis=1)
        velocity = np.column_stack([speed * np.cos(self.pose[:, 2]), speed * np.sin(self.pose[:, 2])])
        return clearance, self.pose, velocity, self.sent

    def applied(self) -> np.ndarray:
        return self.sent

    def close(self) -> None:
        """Stop every robot, whatever ended the run."""
        self.unreached = self.drive.close()
        if self.unreached:
            print(f"{PROG}: robots {format_ids(self.unreached)} were not reached by the final stop", file=sys.stderr)
        self.poses.close()

    def report(self, node: BodyNode) -> dict[str, Any]:
        tally, robots = node.tally, []
        for i in range(self.n):
            stops = {reason: int(tally.stops[reason][i]) for reason in STOP_REASONS}
            poses = self.poses.robot_stats(i)
            robots.append(
                {
                    "robot": i,
                    "address": self.drive.where(i),
                    "commands_sent": int(self.sent[i]),
                    "missed_ticks": int(tally.missed[i]),
                    "late_commands": int(tally.late[i]),
                    "dropped_commands": {reason: int(tally.dropped[reason][i]) for reason in COMMAND_DROPS},
                    "dropped_poses": {reason: poses.get(reason, 0) for reason in (*STAMP_DROPS, "two_sources")},
                    "pose_restarts": poses["restarts"],
                    "watchdog_stops": sum(stops.values()),
                    "stops": stops,
                    **self.drive.robot_stats(i),
                }
            )
        return {
            "hardware": {
                "timeout_s": self.timeout,
                "robots": robots,
                "poses": self.poses.stats(),
                "not_stopped_at_end": self.unreached,
            }
        }


def hardware_node(
    bus: Bus,
    scene: Scene,
    drive: Drive,
    poses: PoseSource,
    *,
    timeout: float,
    pose_frames: bool = False,
) -> BodyNode:
    """The body node on real robots, on the wall clock (``timeout``: see HardwareBodies)."""
    bodies = HardwareBodies(drive, poses, RobotParams.from_dict(scene.robot), scene.robots, timeout)
    return BodyNode(bus, scene, bodies, WallClock(POLL, catch_up=False), pose_frames=pose_frames)


def wait_for_hardware(node: BodyNode, startup_timeout: float, poses_name: str = "the pose source") -> str | None:
    """Until every robot is reached and tracked; None, or what is missing as one line."""
    bodies = node.backend
    assert isinstance(bodies, HardwareBodies)
    end = time.monotonic() + startup_timeout
    while node.running:
        bodies.sense(0.0)
        unreached = bodies.drive.unreached()
        lost = np.flatnonzero(~bodies.tracked).tolist()
        if not unreached and not lost:
            return None
        if time.monotonic() >= end:
            where = ", ".join(f"{r} ({bodies.drive.why_unreached(r)})" for r in unreached)
            problems = [f"robots not reachable: {where}"] if unreached else []
            if lost:
                stats = bodies.poses.stats()
                future, two = stats.get("future", 0), stats.get("two_sources", 0)
                ahead = f"; {future} poses dropped as stamped in the future: is its clock ahead?" if future else ""
                ahead += f"; {two} poses dropped as two publishers sent them: is a second tracker on?" if two else ""
                problems.append(f"no pose for robots {', '.join(map(str, lost))} ({poses_name}{ahead})")
            return f"within {startup_timeout:g} s, " + "; ".join(problems)
        time.sleep(POLL)
    return "stopped during start-up"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sim.node.hardware")
    parser.add_argument("--hardware", required=True, help="the hardware file (needs [backend] and [poses])")
    add_scene_args(parser)  # its robots are the hardware file's, its clock the wall clock
    parser.add_argument("--startup-timeout", type=float, default=STARTUP_TIMEOUT, help="s to reach robots and poses")
    parser.add_argument("--pose-frames", action="store_true", help="send each tick's poses as one frame (agent hosts)")
    parser.add_argument("--exit-with-parent", action="store_true")
    add_zenoh_args(parser)
    return parser


def load_run(args: argparse.Namespace) -> tuple[HardwareConfig, Scene]:
    """The hardware file and the scene it runs, checked: HardwareError, HardwareConfigError or SceneError."""
    config = load_hardware(args.hardware)
    if config.backend_kind not in RUNNABLE_BACKENDS:
        raise HardwareError(
            f"{config.path} [backend]: kind {config.backend_kind!r} drives no robots; a run with --hardware needs "
            f"one of: {', '.join(RUNNABLE_BACKENDS)}"
        )
    if config.poses is None:
        raise HardwareError(f"{config.path}: a run needs a [poses] table (where the robots' poses come from)")
    robots = len(config.backend.robot_ids)
    # as `pixelswarm run --hardware` refuses them: given by hand, they would be silently overridden
    if args.robots is not None:
        raise HardwareError(f"--hardware takes the number of robots from the hardware file ({robots}): drop --robots")
    if args.clock not in (None, "realtime"):
        raise HardwareError(f"--hardware runs on the wall clock: drop --clock {args.clock}")
    scene = scene_of_args(args, robots=robots, clock="realtime")
    if scene.robots != robots:  # a run directory's scene
        raise HardwareError(f"the run's scene has {scene.robots} robots, the hardware file {robots}")
    # a scripted robot has no agent, so its real body would be on nobody's bus (others would drive into it); a
    # pursuer goes with it: the uncontrolled movers of paper Fig. 19 are the simulator's
    if scene.scripted or scene.pursuers or scene.events:
        what = "scripted or pursuing robots" if scene.scripted or scene.pursuers else "events (the simulator's)"
        raise HardwareError(f"scene {scene.name!r} has {what}, which real robots cannot run")
    if RobotParams.from_dict(scene.robot).kinematics != DIFFDRIVE:
        raise HardwareError(f"scene {scene.name!r} is for holonomic robots; real robots need kinematics = 'diffdrive'")
    return config, scene


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config, scene = load_run(args)
        settings = settings_from_args(args)
        bus = Bus(settings, args.display, seed=scene.seed, name="hardware")
    except (HardwareError, HardwareConfigError, SceneError, TransportError) as err:
        return refuse(PROG, err)
    with bus:
        drive, timeout = open_drive(config, settings, RobotParams.from_dict(scene.robot))
        poses, poses_name = open_pose_source(config, settings)
        node = hardware_node(bus, scene, drive, poses, timeout=timeout, pose_frames=args.pose_frames)
        node.end_on(args.exit_with_parent, signal.SIGTERM, signal.SIGINT)
        try:
            try:
                drive.start()
                poses.start()
            except (HardwareConfigError, TransportError, OSError, RuntimeError) as err:
                return refuse(PROG, f"{config.path}: cannot start: {err}")
            problem = wait_for_hardware(node, args.startup_timeout, poses_name)
            if problem is not None:
                return refuse(PROG, f"{config.path}: {problem}")
            node.run()  # it declares itself alive: the launcher starts the agents now
        finally:
            assert isinstance(node.backend, HardwareBodies)
            node.backend.close()  # stops every robot, whatever ended the run
        node.report()
    return 0


if __name__ == "__main__":
    sys.exit(main())
