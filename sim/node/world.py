"""The world process: the simulated bodies, the central tracker and the clock, on the bus.

Real time: physics at 100 Hz on the wall clock; every control period (10 Hz) the tracker publishes
each robot's pose (with seeded noise, paper 7.1: 2 mm / 3 deg) and commands are applied as they
arrive, as on hardware. Lock-step: the world publishes tick k, waits until every live agent has
answered with its command for tick k or a deadline passes (a missed tick), then advances one
period. Lock-step runs are reproducible from the seed. The deadline runs from the last auction
message heard: agents that still trade a tick's auction rounds
(agent.assignment.AuctionLink.settle_block) are at work, not late.

A command is valid for its control period and a margin (RobotParams.command_margin): a body whose
agent is late, blind or cut off stops rather than drive on an old command, since ORCA's guarantee
holds only for commands computed from the current poses.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time

import numpy as np

from coordinator.resolved import load_resolved
from coordinator.scene import Scene, SceneError, load_scene
from sim.args import format_ids, positive_seconds
from sim.bodies.movers import scripted_velocity
from sim.bodies.tracker import tracker_of, world_of
from transport.bus import Bus
from transport.codec import BEFORE_START, Event, Goals, State, States, Tick, Truth
from transport.codec import Contact as ContactMsg
from transport.faults import parse_faults
from transport.keys import cell_of
from transport.plausible import FUTURE, INCONSISTENT, GoalSets, stamp_agrees
from transport.session import TransportError, add_zenoh_args, settings_from_args

CONTACT_KINDS = {"robot": 0, "obstacle": 1, "wall": 2}
# s a lock-step tick waits at most while auction messages keep coming: twice the longest an agent waits
# for a round (agent.assignment.ROUND_CAP); a peer that repeats auction messages held the world (and the
# end of the run) for ever
AUCTION_PATIENCE = 60.0
STARTUP_TIMEOUT = 60.0  # s the world waits for every agent by default (`pixelswarm run` says how long)


class WorldNode:
    def __init__(
        self,
        bus: Bus,
        scene: Scene,
        *,
        deadline: float = 2.0,
        startup_timeout: float = STARTUP_TIMEOUT,
        pose_frames: bool = False,
    ) -> None:
        """``pose_frames``: the tracker sends each tick's poses as one frame of every robot, for agent
        hosts of several robots, instead of a frame of one per robot."""
        self.bus, self.scene, self.keys = bus, scene, bus.keys
        self.params, self.world = world_of(scene)
        self.dt = self.params.dt
        self.tracker = tracker_of(scene)
        self.deadline = deadline
        self.startup_timeout = startup_timeout
        n = scene.robots
        self.color = np.zeros((n, 3), np.uint8)
        self.last_cmd_tick = np.full(n, -1)
        # world time until which each robot's command holds (-inf: none yet); then the body stops
        self.valid_until = np.full(n, -np.inf)
        self.expired_commands = 0  # commands that arrived too late to drive anything
        self.stopped_ticks = 0  # robot-ticks in which a live robot was stopped for want of a valid command
        self.live = np.zeros(n, bool)
        self.agent_robot = np.array([i not in scene.scripted for i in range(n)])  # scripted: no agent
        self.color[~self.agent_robot] = 255
        self.ever_live = np.zeros(n, bool)
        self.missed_ticks = 0
        self.late_commands = 0
        self.tick = 0
        self.events = sorted((e for e in scene.events if e["kind"] == "teleport"), key=lambda e: e["t"])
        # the scene's tracker outages: display time windows [t, t + duration) in which no pose is sent
        self.outages = [(e["t"], e["t"] + e["duration"]) for e in scene.events if e["kind"] == "tracker-outage"]
        self.withheld_ticks = 0  # ticks whose poses the tracker withheld (an outage)
        # the scene's tracker glitches: display time -> [(robot, offset)] reported off for that tick
        self.glitches = [(e["t"], e["robot"], e["offset"]) for e in scene.events if e["kind"] == "tracker-glitch"]
        self.pose_frames = pose_frames
        self.cmd_inbox = bus.commands_inbox()
        # lock-step: agents at work in the auction (either kind) are not late
        self.auction_traffic = [bus.subscribe_raw(self.keys.all_of(kind)) for kind in ("auction", "boards")]
        self.control_inbox = bus.subscribe(self.keys.event, Event)
        # the newest goal set heard, named in each tick (lock-step agents take goal sets up by it)
        self.goal_inbox = bus.subscribe(self.keys.all_of("goals"), Goals)
        self.goal_epoch = 0
        self.believed = GoalSets(scene.arena)  # which goal sets can be the coordinator's (as the agents judge)
        self.alive = bus.watch_alive("agent")
        self.running = True
        self.end_reason = ""
        self.parent_pid: int | None = None

    # --- inputs -------------------------------------------------------------------------------
    def _update_liveness(self) -> None:
        for _, ident, alive, _, _ in self.alive.drain():
            if not ident.isdigit() or int(ident) >= self.scene.robots:
                continue
            i = int(ident)
            if alive:
                self.live[i] = self.ever_live[i] = True
            elif self.live[i]:
                self.live[i] = False
                self.world.stop(i)  # a dead agent's robot stays in the world, stopped

    def _apply_commands(self, first: tuple | None = None) -> None:
        arrived = ([first] if first is not None else []) + self.cmd_inbox.drain()
        if any(not self.live[cmd.robot] for _, cmd in arrived if cmd.robot < self.scene.robots):
            self._update_liveness()  # an agent's first command may overtake the news that it is alive
        for _, cmd in arrived:
            i = cmd.robot
            if i >= self.scene.robots or not self.live[i]:
                continue
            # An honest agent answers a tick the world has published: a command of a later tick,
            # taken as the newest, would drive the body on and shut out every honest one after it.
            why = (
                FUTURE if cmd.tick > self.tick else None if stamp_agrees(cmd.tick, cmd.stamp, self.dt) else INCONSISTENT
            )
            if why is not None:
                self.cmd_inbox.drops[why] += 1
                continue
            if cmd.tick <= self.last_cmd_tick[i]:
                self.late_commands += 1
                continue
            self.last_cmd_tick[i] = cmd.tick
            self.color[i] = (cmd.r, cmd.g, cmd.bl)
            valid_until = (cmd.tick + 1) * self.dt + self.params.command_margin
            if valid_until <= self.world.time:
                self.expired_commands += 1
                continue
            self.valid_until[i] = valid_until
            self.world.set_command(i, cmd.a, cmd.b)

    def _stop_expired(self, step: float) -> int:
        """Stop every agent-driven body whose command runs out before the next ``step`` seconds of
        physics begin to count (lock-step steps a whole period at once); how many are stopped now."""
        expired = self.agent_robot & (self.valid_until <= self.world.time + step - self.world.substep + 1e-9)
        for i in np.flatnonzero(expired & np.isfinite(self.valid_until)).tolist():
            self.world.stop(i)
            self.valid_until[i] = -np.inf  # stopped: nothing to expire until the next command
        return int((expired & self.live).sum())

    def _check_control(self) -> None:
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.running = False  # orphaned: the launcher died without stopping us
            self.end_reason = "launcher gone"
        for _, ev in self.control_inbox.drain():
            if ev.data.get("kind") == "end":
                self.running = False
                self.end_reason = str(ev.data.get("reason", "end"))

    # --- outputs ------------------------------------------------------------------------------
    @property
    def tracker_out(self) -> bool:
        """Within a scene's tracker outage: the agents hear no pose, so none can answer this tick."""
        t = self.tick * self.dt
        return any(start - 1e-9 <= t < end - 1e-9 for start, end in self.outages)

    def _publish_tick(self) -> None:
        t = self.tick * self.dt
        for _, goals in self.goal_inbox.drain():  # as the agents do, refusing epochs and stamps from the future
            why = self.believed.admit(goals, t)
            if why is None:
                self.goal_epoch = max(self.goal_epoch, goals.epoch)
            else:
                self.goal_inbox.drops[why] += 1
        self.bus.publish(self.keys.clock, Tick(self.tick, t, self.dt, self.goal_epoch))
        self._publish_truth()
        if self.tracker_out:
            self.withheld_ticks += 1
            self._drive_scripted()
            return
        measured = self.tracker.measure(self.world.poses)
        for when, robot, (dx, dy) in self.glitches:
            if abs(when - t) < self.dt / 2:  # a swapped marker: this tick's pose is elsewhere
                measured[robot, :2] += (dx, dy)
        # The tracker sees bodies, not agents: a robot whose agent died is still tracked, so the
        # coordinator learns where its body stays and keeps the goals clear of it (5.1.2).
        tracked = np.flatnonzero(self.ever_live)
        self.bus.publish_poses(self.tick, t, tracked, measured[tracked], self.pose_frames)
        self._publish_before_start()
        self._drive_scripted()

    def _drive_scripted(self) -> None:
        """Scripted robots are dynamic obstacles: they follow their path and broadcast a state flagged
        as not avoiding anybody, so agents take full responsibility (paper Fig. 19)."""
        t = self.tick * self.dt
        for i, waypoints in self.scene.scripted.items():
            x, y, _ = self.world.poses[i]
            vx, vy = scripted_velocity(waypoints, self.world.poses[i], t, self.dt)
            self.world.set_command(i, float(vx), float(vy))
            cell = cell_of(x, y, self.params.cell_size)
            self.bus.publish(
                self.keys.state(cell, i),
                States.one(State(i, self.tick, t, x, y, vx, vy, self.params.radius, 0.0, 0.0, -1, State.DYNAMIC)),
            )

    def _publish_before_start(self) -> None:
        """Robots whose agent is not live yet hear where they are (true pose, no tracker noise drawn,
        so start-up timing cannot change the noise sequence): they subscribe to their cells and join."""
        waiting = np.flatnonzero(~self.live & self.agent_robot)
        self.bus.publish_poses(BEFORE_START, self.tick * self.dt, waiting, self.world.poses[waiting], frame=False)

    def _publish_truth(self) -> None:
        t = self.tick * self.dt
        self.bus.publish(
            self.keys.truth,
            Truth(
                self.tick,
                t,
                self.world.step_min_clearance() if self.tick else self.world.min_clearance,
                self.scene.robots,
                self.world.poses,
                self.world.velocities,
                self.color,
                self.world.commands_applied.astype(np.uint32),
            ),
        )

    def _publish_contacts(self, contacts: list) -> None:
        for c in contacts:
            self.bus.publish(self.keys.contact, ContactMsg(CONTACT_KINDS[c.kind], c.i, c.j, c.t_start, c.max_depth))

    def _apply_events(self) -> None:
        t = self.tick * self.dt
        while self.events and self.events[0]["t"] <= t + 1e-9:
            ev = self.events.pop(0)
            self.world.teleport(ev["robot"], tuple(ev["pose"]))

    # --- loops --------------------------------------------------------------------------------
    def wait_for_agents(self) -> bool:
        """Start when every robot's agent is alive, telling the robots still waiting where they are.
        False if the start-up timeout passes first (or the run is ended): a swarm that lacks robots
        is not shown in silence, as if it were the scene (``run`` names them)."""
        start = time.monotonic()
        last_sent = 0.0
        while self.running and time.monotonic() - start < self.startup_timeout:
            self._update_liveness()
            self._check_control()
            if self.live[self.agent_robot].all():
                return True
            if time.monotonic() - last_sent > 0.2:
                self._publish_before_start()
                last_sent = time.monotonic()
            time.sleep(0.02)
        return False

    def run(self, clock: str) -> None:
        self.bus.declare_alive("world", 0)
        if not self.wait_for_agents():
            missing = np.flatnonzero(self.agent_robot & ~self.live).tolist()
            self.end_reason = self.end_reason or (
                f"no agent came alive for robots {format_ids(missing)} within {self.startup_timeout:g} s"
            )
            return
        if clock == "lockstep":  # every agent heard its neighbours' hellos before it came alive
            self._run_lockstep()
        else:
            self._run_realtime()
        self._publish_truth()  # the state after the last step
        if not self.end_reason:
            self.end_reason = "duration"

    def _run_lockstep(self) -> None:
        steps = round(self.scene.duration / self.dt)
        while self.running and self.tick < steps:
            self._apply_events()
            self._update_liveness()
            self._publish_tick()
            deadline = time.monotonic() + self.deadline
            patience = time.monotonic() + AUCTION_PATIENCE
            while True:
                got = self.cmd_inbox.get(timeout=max(0.0, min(0.05, deadline - time.monotonic())))
                self._apply_commands(got)
                if sum(len(inbox.drain()) for inbox in self.auction_traffic):
                    deadline = min(time.monotonic() + self.deadline, patience)
                self._update_liveness()
                waiting = self.live & (self.last_cmd_tick < self.tick)
                if not waiting.any() or time.monotonic() >= deadline or self.tracker_out:
                    self.missed_ticks += int(waiting.sum())
                    break
            self.stopped_ticks += self._stop_expired(self.dt)
            self._publish_contacts(self.world.step(self.dt))
            self.tick += 1
            self._check_control()

    def _run_realtime(self) -> None:
        steps = round(self.scene.duration / self.dt)
        sub = self.world.substep
        per_tick = round(self.dt / sub)
        next_time = time.monotonic()
        while self.running and self.tick < steps:
            self._apply_events()
            self._update_liveness()
            self._publish_tick()
            contacts = []
            stopped = 0
            for _ in range(per_tick):
                next_time += sub
                pause = next_time - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
                self._apply_commands()
                stopped = max(stopped, self._stop_expired(sub))
                contacts += self.world.step(sub)
            self.stopped_ticks += stopped
            self.missed_ticks += int((self.live & (self.last_cmd_tick < self.tick)).sum())
            self._publish_contacts(contacts)
            self.tick += 1
            self._check_control()

    def stats(self) -> dict:
        return {
            "kind": "world-done",
            "reason": self.end_reason,
            "ticks": self.tick,
            "missed_ticks": self.missed_ticks,
            "late_commands": self.late_commands,
            "expired_commands": self.expired_commands,
            "stopped_ticks": self.stopped_ticks,
            "withheld_ticks": self.withheld_ticks,
            "commands_applied": self.world.commands_applied.astype(int).tolist(),
            "min_clearance": _finite_or_none(self.world.min_clearance),
            "dropped": dict(self.cmd_inbox.drops + self.control_inbox.drops + self.goal_inbox.drops),
            "contacts": [
                {"kind": c.kind, "i": c.i, "j": c.j, "t_start": c.t_start, "t_end": c.t_end, "max_depth": c.max_depth}
                for c in self.world.contacts
            ],
        }


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.node.world")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--run-dir", help="a run directory holding the resolved scene (no image pipeline)")
    where.add_argument("--scene", help="a scene to load (with its goal sets: the image pipeline)")
    parser.add_argument("--robots", type=int)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--clock", choices=["lockstep", "realtime"])
    parser.add_argument("--duration", type=float)
    parser.add_argument("--display", default="default")
    parser.add_argument("--deadline", type=float, default=2.0, help="lock-step: seconds to wait for commands")
    parser.add_argument("--faults", default="")
    parser.add_argument("--pose-frames", action="store_true", help="send each tick's poses as one frame (agent hosts)")
    parser.add_argument(
        "--startup-timeout",
        type=positive_seconds,
        default=STARTUP_TIMEOUT,
        metavar="SECONDS",
        help=f"how long to wait for every robot's agent to come alive (default {STARTUP_TIMEOUT:g} s)",
    )
    parser.add_argument("--exit-with-parent", action="store_true")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        if args.run_dir is not None:
            scene = load_resolved(args.run_dir, clock=args.clock, duration=args.duration)
        else:
            scene = load_scene(args.scene, robots=args.robots, seed=args.seed, clock=args.clock, duration=args.duration)
        bus = Bus(
            settings_from_args(args), args.display, faults=parse_faults(args.faults), seed=scene.seed, name="world"
        )
    except (SceneError, TransportError, ValueError) as err:
        print(f"world: error: {err}", file=sys.stderr)
        return 2
    with bus:
        node = WorldNode(
            bus, scene, deadline=args.deadline, startup_timeout=args.startup_timeout, pose_frames=args.pose_frames
        )
        if args.exit_with_parent:
            node.parent_pid = os.getppid()

        def stop(signum: int, frame: object) -> None:
            node.running = False
            node.end_reason = node.end_reason or "stopped"

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher decides; Ctrl-C reaches it too
        node.run(scene.clock)
        stats = node.stats()
        bus.publish(bus.keys.event, Event(stats))
        # The same report on stdout (the launcher's log file): a loaded router may not deliver the
        # message before this session closes.
        print("WORLD-DONE " + json.dumps(stats), flush=True)
        bus.linger()
    return 0


if __name__ == "__main__":
    sys.exit(main())
