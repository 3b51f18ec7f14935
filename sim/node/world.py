"""The world process: the simulated bodies, the central tracker and the clock, on the bus.

The simulated world is one backend of the body node (sim/node/body.py, whose clocks say how ticks pass):
physics in substeps, the tracker's poses with seeded noise (paper 7.1), and a command holding for its
control period and a margin (RobotParams.command_margin) of simulated time."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import Any

import numpy as np

from coordinator.resolved import add_scene_args, scene_of_args
from coordinator.scene import Scene, SceneError, events_of
from sim.args import add_seconds, refuse
from sim.bodies.movers import scripted_velocity
from sim.bodies.tracker import tracker_of, world_of
from sim.node.body import STARTUP_TIMEOUT, BodyNode, LockStep, WallClock
from transport.bus import Bus
from transport.codec import Command, State
from transport.faults import parse_faults
from transport.session import TransportError, add_zenoh_args, settings_from_args


class SimulatedBodies:
    """The simulated world as the node's bodies: physics, the tracker with its noise, and the scene's
    teleports, tracker outages and glitches; it drives the scripted movers itself."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.params, self.world = world_of(scene)
        self.tracker = tracker_of(scene)
        self.tracked = np.ones(scene.robots, bool)  # the tracker sees every body (or, in an outage, none)
        self.events = events_of(scene, "teleport")
        # the scene's tracker outages: display time windows [t, t + duration) in which no pose is sent
        self.outages = [(e["t"], e["t"] + e["duration"]) for e in scene.events if e["kind"] == "tracker-outage"]
        # the scene's tracker glitches: (display time, robot, offset), the robot reported off by it at that tick
        self.glitches = [(e["t"], e["robot"], e["offset"]) for e in scene.events if e["kind"] == "tracker-glitch"]

    @property
    def min_clearance(self) -> float:
        return self.world.min_clearance

    @property
    def contacts(self) -> list:
        return self.world.contacts

    def sense(self, t: float) -> None:
        self.world.teleport_due(self.events, t)

    def measure(self, t: float) -> np.ndarray | None:
        """Within a scene's tracker outage none (the agents hear no pose, so none can answer)."""
        if any(start - 1e-9 <= t < end - 1e-9 for start, end in self.outages):
            return None
        measured = self.tracker.measure(self.world.poses)
        for when, robot, (dx, dy) in self.glitches:
            if abs(when - t) < self.params.dt / 2:  # a swapped marker: this tick's pose is elsewhere
                measured[robot, :2] += (dx, dy)
        return measured

    def true_poses(self) -> np.ndarray:
        return self.world.poses

    def hold(self, cmd: Command) -> float | None:
        until = (cmd.tick + 1) * self.params.dt + self.params.command_margin
        return until if until > self.world.time else None

    def horizon(self, span: float) -> float:
        """Physics counts a command from the start of each substep: lock-step steps a period at once."""
        return self.world.time + span - self.world.substep + 1e-9

    def moving(self) -> np.ndarray:
        return self.tracked

    def apply(self, ids: list[int], cmds: list[Command], colors: np.ndarray) -> None:
        for i, cmd in zip(ids, cmds):
            self.world.set_command(i, cmd.a, cmd.b)

    def stop(self, ids: list[int]) -> None:
        for i in ids:
            self.world.stop(i)

    def step(self, span: float) -> list:
        return self.world.step(span)

    def own_movers(self, tick: int, t: float) -> list[State]:
        """Scripted robots are dynamic obstacles: they follow their path and broadcast a state flagged
        as not avoiding anybody, so agents take full responsibility (paper Fig. 19)."""
        dt, radius = self.params.dt, self.params.radius
        states = []
        for i, waypoints in self.scene.scripted.items():
            x, y, _ = self.world.poses[i]
            vx, vy = scripted_velocity(waypoints, self.world.poses[i], t, dt)
            self.world.set_command(i, float(vx), float(vy))
            states.append(State(i, tick, t, x, y, vx, vy, radius, 0.0, 0.0, -1, State.DYNAMIC))
        return states

    def truth(self, tick: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        clearance = self.world.step_min_clearance() if tick else self.world.min_clearance
        return clearance, self.world.poses, self.world.velocities, self.applied().astype(np.uint32)

    def applied(self) -> np.ndarray:
        return self.world.commands_applied

    def report(self, node: BodyNode) -> dict[str, Any]:
        return {}


def world_node(
    bus: Bus,
    scene: Scene,
    *,
    deadline: float = Scene.deadline,
    startup_timeout: float = STARTUP_TIMEOUT,
    pose_frames: bool = False,
) -> BodyNode:
    """The body node on the simulated world, on the scene's clock (``deadline``: lock-step, seconds to
    wait for commands)."""
    bodies = SimulatedBodies(scene)
    clock = LockStep(bus, deadline) if scene.clock == "lockstep" else WallClock(bodies.world.substep, catch_up=True)
    return BodyNode(bus, scene, bodies, clock, startup_timeout=startup_timeout, pose_frames=pose_frames)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.node.world")
    add_scene_args(parser)
    parser.add_argument(
        "--deadline", type=float, default=Scene.deadline, help="lock-step: seconds to wait for commands"
    )
    parser.add_argument("--faults", default="")
    parser.add_argument("--pose-frames", action="store_true", help="send each tick's poses as one frame (agent hosts)")
    add_seconds(parser, "--startup-timeout", STARTUP_TIMEOUT, "how long to wait for every robot's agent to come alive")
    parser.add_argument("--exit-with-parent", action="store_true")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        scene = scene_of_args(args)
        bus = Bus(
            settings_from_args(args), args.display, faults=parse_faults(args.faults), seed=scene.seed, name="world"
        )
    except (SceneError, TransportError, ValueError) as err:
        return refuse("world", err)
    with bus:
        node = world_node(
            bus, scene, deadline=args.deadline, startup_timeout=args.startup_timeout, pose_frames=args.pose_frames
        )
        node.end_on(args.exit_with_parent, signal.SIGTERM)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher decides; Ctrl-C reaches it too
        node.run()
        node.report()
    return 0


if __name__ == "__main__":
    sys.exit(main())
