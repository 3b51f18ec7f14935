"""The hardware process: real bodies in place of the simulated world (the twin of sim/node/world.py).

On the wall clock, every control period, it reads each robot's newest pose from the pose source and
publishes Tick, the poses (a frame of one per robot, or one frame of all, exactly as the world node
does, so agents cannot tell the difference) and Truth holding the tracked poses (what the recorder writes as the
trajectory). Each robot's newest Command goes to the backend as soon as it arrives, wheel speeds clipped
to v_max. Safety: a robot is sent a stop when its last command is older than the command timeout, when
its agent's liveliness token disappears, or when its pose has been lost longer than the timeout (its pose
is then not published, so its agent waits). Every robot is stopped when the run ends, on SIGTERM or
SIGINT, on an error, and when the launcher is gone. What it cannot trust it drops and counts: a command
for a tick not yet published or whose stamp is not its tick's, and (the pose source's gate,
hardware/poses.py) a pose stamped older than one taken or in the future.

    python -m sim.node.hardware --hardware hw.toml --scene paper-sequence -e tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from agent.core.params import DIFFDRIVE, RobotParams
from coordinator.resolved import load_resolved
from coordinator.scene import Scene, SceneError, load_scene
from hardware.config import HardwareConfig, HardwareConfigError, load_hardware
from hardware.poses import STAMP_DROPS, PoseSample
from transport.bus import Bus
from transport.codec import BEFORE_START, Command, Event, Tick, Truth
from transport.plausible import FUTURE, INCONSISTENT, stamp_agrees
from transport.session import TransportError, ZenohSettings, add_zenoh_args, settings_from_args

STARTUP_TIMEOUT = 5.0  # s: every robot reached and every robot's pose seen, or the run is refused
AGENTS_TIMEOUT = 60.0  # s: the agents' start-up (as the world node waits)
BEFORE_START_EVERY = 0.2  # s: poses to robots whose agent is not live yet
POLL = 0.02  # s: how often, within a period, commands, liveliness and safety are looked at
ERROR = "hardware: error: "  # the one line the launcher shows when the node refuses to start
RUNNABLE_BACKENDS = ("epuck2", "ros2")
STOP_REASONS = ("command_timeout", "agent_lost", "pose_lost")
COMMAND_DROPS = (FUTURE, INCONSISTENT)  # commands no honest agent sends: for a tick not yet published
# (it answers the poses of a tick), or stamped other than at its tick's start


class HardwareError(Exception):
    """The hardware cannot be used for a run: one line for the user."""


# --- the hardware file, for a run ------------------------------------------------------------------
def backend_kind(config: HardwareConfig) -> str:
    return config.backend_kind


def poses_kind(config: HardwareConfig) -> str | None:
    return config.poses_kind


def check_runnable(config: HardwareConfig) -> int:
    """A hardware file a run can use (a backend with robots and a pose source); returns the robot count
    (robot ids are positions in the backend's list)."""
    kind = backend_kind(config)
    if kind not in RUNNABLE_BACKENDS:
        raise HardwareError(
            f"{config.path} [backend]: kind {kind!r} drives no robots; a run with --hardware needs one of: "
            f"{', '.join(RUNNABLE_BACKENDS)}"
        )
    if config.poses is None:
        raise HardwareError(f"{config.path}: a run needs a [poses] table (where the robots' poses come from)")
    return len(config.backend.addresses if kind == "epuck2" else config.backend.namespaces)


def command_timeout(config: HardwareConfig) -> float:
    """The hardware file's own command timeout (e-puck2 `command_timeout`, ROS 2 `watchdog`)."""
    backend = config.backend
    return float(backend.command_timeout if backend_kind(config) == "epuck2" else backend.watchdog)


def describe_poses(config: HardwareConfig) -> str:
    poses = config.poses
    assert poses is not None
    return f"topic {poses.topic}" if poses_kind(config) == "ros2" else f"camera {poses.source!r}"


# --- drives: the backends behind one small interface ---------------------------------------------
class Drive(Protocol):
    def start(self) -> None: ...
    def send(self, ids: list[int], left: np.ndarray, right: np.ndarray, colors: np.ndarray) -> None: ...
    def unreached(self) -> list[int]: ...
    def where(self, robot: int) -> str: ...
    def robot_stats(self, robot: int) -> dict[str, int]: ...
    def close(self) -> list[int]: ...


class WheelDrive:
    """e-puck2 robots take wheel speeds; the backend clips them to `max_wheel_speed`, set here to v_max."""

    def __init__(self, backend_config: Any, params: RobotParams) -> None:
        from hardware.epuck2 import Epuck2Backend

        limit = min(backend_config.max_wheel_speed, params.v_max)
        self.backend = Epuck2Backend(replace(backend_config, max_wheel_speed=limit))

    def start(self) -> None:
        self.backend.start()

    def send(self, ids: list[int], left: np.ndarray, right: np.ndarray, colors: np.ndarray) -> None:
        self.backend.set_commands(ids, left.tolist(), right.tolist(), colors.tolist())

    def unreached(self) -> list[int]:
        return [rid for rid, s in self.backend.stats().items() if not s.connected]

    def where(self, robot: int) -> str:
        return self.backend.config.addresses[robot]

    def robot_stats(self, robot: int) -> dict[str, int]:
        s = self.backend.stats()[robot]
        return {
            "packets_sent": s.commands_sent,
            "backend_late_commands": s.late_commands,
            "reconnects": s.reconnects,
            "backend_watchdog_stops": s.watchdog_stops,
        }

    def close(self) -> list[int]:
        return self.backend.close()


class TwistDrive:
    """ROS 2 robots take a body velocity: wheel speeds become v = (l + r) / 2, omega = (r - l) / wheel base."""

    def __init__(self, backend_config: Any, settings: ZenohSettings, params: RobotParams) -> None:
        from hardware.ros2 import Ros2Backend

        self.backend = Ros2Backend(backend_config, settings)
        self.wheel_base = params.wheel_base

    def start(self) -> None:
        self.backend.start()

    def send(self, ids: list[int], left: np.ndarray, right: np.ndarray, colors: np.ndarray) -> None:
        self.backend.set_commands(ids, (left + right) / 2, (right - left) / self.wheel_base, colors)

    def unreached(self) -> list[int]:
        return []  # a topic has no connection to check

    def where(self, robot: int) -> str:
        return self.backend.config.topic(robot, self.backend.config.cmd_topic)

    def robot_stats(self, robot: int) -> dict[str, int]:
        return {"reconnects": 0}

    def close(self) -> list[int]:
        self.backend.close()
        return []


def open_drive(config: HardwareConfig, settings: ZenohSettings, params: RobotParams) -> Drive:
    if backend_kind(config) == "epuck2":
        return WheelDrive(config.backend, params)
    return TwistDrive(config.backend, settings, params)


class PoseSource(Protocol):
    def start(self) -> Any: ...
    def latest(self) -> dict[int, PoseSample]: ...
    def stats(self) -> dict[str, int]: ...
    def robot_stats(self, robot: int) -> dict[str, int]: ...
    def close(self) -> None: ...


def open_pose_source(config: HardwareConfig, settings: ZenohSettings) -> PoseSource:
    assert config.poses is not None  # check_runnable() refuses a file without
    if poses_kind(config) == "ros2":
        from hardware.ros2 import Ros2PoseSource

        return Ros2PoseSource(config.poses, settings)
    from hardware.camera import CameraPoseSource

    return CameraPoseSource(config.poses)


# --- the node ------------------------------------------------------------------------------------
class HardwareNode:
    def __init__(
        self,
        bus: Bus,
        scene: Scene,
        drive: Drive,
        poses: PoseSource,
        *,
        timeout: float,
        pose_frames: bool = False,
        poses_name: str = "the pose source",
    ) -> None:
        """``timeout``: a robot whose command is older, or whose pose was lost longer, is stopped;
        ``poses_name`` names the pose source in messages."""
        self.bus, self.scene, self.keys = bus, scene, bus.keys
        self.poses_name = poses_name
        self.drive, self.poses, self.timeout, self.pose_frames = drive, poses, timeout, pose_frames
        self.params = RobotParams.from_dict(scene.robot)
        self.dt = self.params.dt
        n = self.n = scene.robots
        self.pose = np.zeros((n, 3))  # the last tracked pose of each robot
        self.tracked = np.zeros(n, bool)  # its pose is fresh (not older than the timeout)
        self.wheels = np.zeros((n, 2))  # what each robot was last told (m/s)
        self.color = np.zeros((n, 3), np.uint8)
        self.last_cmd_tick = np.full(n, -1)
        self.last_cmd_time = np.full(n, -np.inf)  # time.monotonic() of each robot's newest command
        self.live = np.zeros(n, bool)
        self.ever_live = np.zeros(n, bool)
        self.sent = np.zeros(n, int)  # commands handed to the backend, stops included
        self.late = np.zeros(n, int)
        self.dropped = {reason: np.zeros(n, int) for reason in COMMAND_DROPS}
        self.stops = {reason: np.zeros(n, int) for reason in STOP_REASONS}
        self.min_clearance = np.inf
        self.missed_ticks = 0
        self.tick = 0
        self.cmd_inbox = bus.commands_inbox()
        self.control_inbox = bus.subscribe(self.keys.event, Event)
        self.alive = bus.watch_alive("agent")
        self.running = True
        self.end_reason = ""
        self.parent_pid: int | None = None

    # --- inputs -------------------------------------------------------------------------------
    def _read_poses(self) -> None:
        """Each robot's newest pose; a robot whose pose is older than the timeout is not tracked now."""
        self.tracked[:] = False
        for r, s in self.poses.latest().items():
            if 0 <= r < self.n and s.age <= self.timeout:
                self.pose[r] = (s.x, s.y, s.theta)
                self.tracked[r] = True

    def _update_liveness(self) -> None:
        for _, ident, alive, _, _ in self.alive.drain():
            if ident.isdigit() and int(ident) < self.n:
                i = int(ident)
                self.live[i] = alive
                self.ever_live[i] |= alive

    def _apply_commands(self, first: tuple | None = None) -> None:
        """Every robot's newest command, to the backend at once (wheels clipped to v_max)."""
        newest: dict[int, Command] = {}
        for _, cmd in ([first] if first is not None else []) + self.cmd_inbox.drain():
            i = cmd.robot
            if i >= self.n or not self.live[i]:
                continue
            # taken, a command of a later tick would be the newest and shut out every honest one after it
            why = (
                FUTURE if cmd.tick > self.tick else None if stamp_agrees(cmd.tick, cmd.stamp, self.dt) else INCONSISTENT
            )
            if why is not None:
                self.dropped[why][i] += 1
                self.cmd_inbox.drops[why] += 1  # with the decoder's drops: the run's dropped_messages
                continue
            if cmd.tick <= self.last_cmd_tick[i]:
                self.late[i] += 1  # older than one already applied
                continue
            if cmd.tick < self.tick:
                self.late[i] += 1  # for a tick already over: still the newest, so it is applied
            self.last_cmd_tick[i] = cmd.tick
            self.last_cmd_time[i] = time.monotonic()
            self.color[i] = (cmd.r, cmd.g, cmd.bl)
            newest[i] = cmd
        drive = [i for i in newest if self.tracked[i]]  # a robot out of sight is not driven blind
        if drive:
            v_max = self.params.v_max
            wheels = np.array([(newest[i].a, newest[i].b) for i in drive], float)
            self._send(drive, np.clip(np.nan_to_num(wheels, nan=0.0, posinf=0.0, neginf=0.0), -v_max, v_max))

    def _send(self, ids: list[int], wheels: np.ndarray) -> None:
        self.wheels[ids] = wheels
        self.sent[ids] += 1
        self.drive.send(ids, wheels[:, 0], wheels[:, 1], self.color[ids])

    def _enforce_safety(self) -> None:
        """A stop to every moving robot whose agent is gone, whose command is stale or whose pose is lost."""
        moving = np.any(self.wheels != 0, axis=1)
        if not moving.any():
            return
        stale = time.monotonic() - self.last_cmd_time > self.timeout
        causes = {"agent_lost": ~self.live, "pose_lost": ~self.tracked, "command_timeout": stale}
        stop = np.zeros(self.n, bool)
        for reason, cause in causes.items():
            hit = moving & cause & ~stop
            self.stops[reason] += hit
            stop |= hit
        if stop.any():
            ids = np.flatnonzero(stop).tolist()
            self._send(ids, np.zeros((len(ids), 2)))

    def _check_control(self) -> None:
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.running = False  # orphaned: the launcher died without stopping us
            self.end_reason = "launcher gone"
        for _, ev in self.control_inbox.drain():
            if isinstance(ev, Event) and ev.data.get("kind") == "end":
                self.running = False
                self.end_reason = str(ev.data.get("reason", "end"))

    # --- outputs ------------------------------------------------------------------------------
    def _publish_tick(self) -> None:
        t = self.tick * self.dt
        self.bus.publish(self.keys.clock, Tick(self.tick, t, self.dt))
        self._publish_truth()
        # As the world node: the tracker sees bodies, not agents (a dead agent's body is still
        # published, so the coordinator keeps goals clear of it); a robot out of sight is not.
        shown = np.flatnonzero(self.ever_live & self.tracked)
        self.bus.publish_poses(self.tick, t, shown, self.pose[shown], self.pose_frames)
        self._publish_before_start()

    def _publish_before_start(self) -> None:
        waiting = np.flatnonzero(~self.live & self.tracked)
        self.bus.publish_poses(BEFORE_START, self.tick * self.dt, waiting, self.pose[waiting], frame=False)

    def _publish_truth(self) -> None:
        clearance = self._clearance()
        self.min_clearance = min(self.min_clearance, clearance)
        speed = self.wheels.mean(axis=1)
        velocity = np.column_stack([speed * np.cos(self.pose[:, 2]), speed * np.sin(self.pose[:, 2])])
        self.bus.publish(
            self.keys.truth,
            Truth(self.tick, self.tick * self.dt, clearance, self.n, self.pose, velocity, self.color, self.sent),
        )

    def _clearance(self) -> float:
        """Smallest gap between the tracked robots' discs now (m)."""
        xy = self.pose[self.tracked, :2]
        if len(xy) < 2:
            return math.inf
        gaps = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        return float(gaps[np.triu_indices(len(xy), 1)].min() - 2 * self.params.radius)

    # --- loops --------------------------------------------------------------------------------
    def wait_for_hardware(self, startup_timeout: float) -> str | None:
        """Until every robot is reached and tracked; None, or what is missing as one line."""
        end = time.monotonic() + startup_timeout
        while self.running:
            self._read_poses()
            unreached = self.drive.unreached()
            lost = np.flatnonzero(~self.tracked).tolist()
            if not unreached and not lost:
                return None
            if time.monotonic() >= end:
                where = ", ".join(f"{r} ({self.drive.where(r)})" for r in unreached)
                problems = [f"robots not reachable: {where}"] if unreached else []
                if lost:
                    future = self.poses.stats().get("future", 0)
                    ahead = f"; {future} poses dropped as stamped in the future: is its clock ahead?" if future else ""
                    problems.append(f"no pose for robots {', '.join(map(str, lost))} ({self.poses_name}{ahead})")
                return f"within {startup_timeout:g} s, " + "; ".join(problems)
            time.sleep(POLL)
        return "stopped during start-up"

    def wait_for_agents(self, timeout: float = AGENTS_TIMEOUT) -> bool:
        start, last_sent = time.monotonic(), -math.inf
        while self.running and time.monotonic() - start < timeout:
            self._update_liveness()
            self._check_control()
            if self.live.all():
                return True
            if time.monotonic() - last_sent >= BEFORE_START_EVERY:
                self._read_poses()
                self._publish_before_start()
                last_sent = time.monotonic()
            time.sleep(POLL)
        return bool(self.live.any())

    def run(self) -> None:
        if not self.wait_for_agents():
            self.end_reason = self.end_reason or "no agent came alive"
            return
        steps = round(self.scene.duration / self.dt)
        next_tick = time.monotonic()
        while self.running and self.tick < steps:
            self._read_poses()
            self._update_liveness()
            self._publish_tick()
            self._enforce_safety()
            next_tick = max(next_tick + self.dt, time.monotonic())  # after a stall, do not rush to catch up
            while self.running and (left := next_tick - time.monotonic()) > 0:
                got = self.cmd_inbox.get(timeout=min(POLL, left))
                self._update_liveness()
                self._apply_commands(got)
                self._enforce_safety()
                self._check_control()
            self.missed_ticks += int((self.live & (self.last_cmd_tick < self.tick)).sum())
            self.tick += 1
            self._check_control()
        self._read_poses()
        self._publish_truth()  # where the robots are at the end
        self.end_reason = self.end_reason or "duration"

    def stats(self, unreached: list[int]) -> dict:
        robots = []
        for i in range(self.n):
            stops = {reason: int(self.stops[reason][i]) for reason in STOP_REASONS}
            poses = self.poses.robot_stats(i)
            robots.append(
                {
                    "robot": i,
                    "address": self.drive.where(i),
                    "commands_sent": int(self.sent[i]),
                    "late_commands": int(self.late[i]),
                    "dropped_commands": {reason: int(self.dropped[reason][i]) for reason in COMMAND_DROPS},
                    "dropped_poses": {reason: poses[reason] for reason in STAMP_DROPS},
                    "pose_restarts": poses["restarts"],
                    "watchdog_stops": sum(stops.values()),
                    "stops": stops,
                    **self.drive.robot_stats(i),
                }
            )
        return {
            "kind": "world-done",
            "reason": self.end_reason,
            "ticks": self.tick,
            "missed_ticks": self.missed_ticks,
            "late_commands": int(self.late.sum()),
            "commands_applied": self.sent.tolist(),
            "min_clearance": self.min_clearance if math.isfinite(self.min_clearance) else None,
            "dropped": dict(self.cmd_inbox.drops + self.control_inbox.drops),
            "contacts": [],  # measured by the bodies themselves (sim/emulators/lab.py), not from the tracker
            "hardware": {
                "timeout_s": self.timeout,
                "robots": robots,
                "poses": self.poses.stats(),
                "not_stopped_at_end": unreached,
            },
        }


# --- the process ---------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sim.node.hardware")
    parser.add_argument("--hardware", required=True, help="the hardware file (needs [backend] and [poses])")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--run-dir", help="a run directory holding the resolved scene")
    where.add_argument("--scene", help="a scene to load")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--duration", type=float)
    parser.add_argument("--display", default="default")
    parser.add_argument("--startup-timeout", type=float, default=STARTUP_TIMEOUT, help="s to reach robots and poses")
    parser.add_argument("--pose-frames", action="store_true", help="send each tick's poses as one frame (agent hosts)")
    parser.add_argument("--exit-with-parent", action="store_true")
    parser.add_argument("--robots", type=int, help="ignored: the hardware file says how many")
    parser.add_argument("--clock", help="ignored: hardware runs on the wall clock")
    add_zenoh_args(parser)
    return parser


def load_run(
    hardware: str, scene_name: str, seed: int | None, duration: float | None, run_dir: str | None = None
) -> tuple[HardwareConfig, Scene]:
    """The hardware file and the scene it runs (from ``run_dir``, resolved, if given), checked:
    HardwareError, HardwareConfigError or SceneError."""
    config = load_hardware(hardware)
    robots = check_runnable(config)
    if run_dir is not None:
        scene = load_resolved(run_dir, clock="realtime", duration=duration)
        if scene.robots != robots:
            raise HardwareError(f"the run's scene has {scene.robots} robots, the hardware file {robots}")
    else:
        scene = load_scene(scene_name, robots=robots, seed=seed, clock="realtime", duration=duration)
    if RobotParams.from_dict(scene.robot).kinematics != DIFFDRIVE:
        raise HardwareError(f"scene {scene.name!r} is for holonomic robots; real robots need kinematics = 'diffdrive'")
    return config, scene


def _fail(message: str) -> int:
    print(ERROR + message, file=sys.stderr, flush=True)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config, scene = load_run(args.hardware, args.scene, args.seed, args.duration, args.run_dir)
        settings = settings_from_args(args)
        bus = Bus(settings, args.display, seed=scene.seed, name="hardware")
    except (HardwareError, HardwareConfigError, SceneError, TransportError) as err:
        return _fail(str(err))
    with bus:
        drive = open_drive(config, settings, RobotParams.from_dict(scene.robot))
        poses = open_pose_source(config, settings)
        node = HardwareNode(
            bus,
            scene,
            drive,
            poses,
            timeout=command_timeout(config),
            pose_frames=args.pose_frames,
            poses_name=describe_poses(config),
        )
        if args.exit_with_parent:
            node.parent_pid = os.getppid()

        def stop(signum: int, frame: object) -> None:
            node.running = False
            node.end_reason = node.end_reason or "stopped"

        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, stop)
        unreached: list[int] = []
        try:
            try:
                drive.start()
                poses.start()
            except (HardwareConfigError, TransportError, OSError, RuntimeError) as err:
                return _fail(f"{config.path}: cannot start: {err}")
            problem = node.wait_for_hardware(args.startup_timeout)
            if problem is not None:
                return _fail(f"{config.path}: {problem}")
            bus.declare_alive("world", 0)  # the launcher starts the agents now
            node.run()
        finally:
            unreached = drive.close()  # stops every robot, whatever ended the run
            poses.close()
        stats = node.stats(unreached)
        bus.publish(bus.keys.event, Event(stats))
        print("WORLD-DONE " + json.dumps(stats), flush=True)  # as the world node: the launcher's fallback
        bus.linger()
    return 0


if __name__ == "__main__":
    sys.exit(main())
