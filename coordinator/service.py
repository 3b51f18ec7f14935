"""The coordinator service: publishes the goal set of each step for the robots alive (paper 5.1.2), with an
epoch, re-published every second; a restarted coordinator goes on from the run's newest recorded set."""

from __future__ import annotations

import argparse
import colorsys
import os
import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from agent.core.params import RobotParams
from transport.bus import Bus, Inbox, KeepRobots
from transport.codec import (
    BLOCK_ABANDONED,
    Correspondence,
    Event,
    Goals,
    Lives,
    Motion,
    Pose,
    Tick,
    Timing,
    WarmStart,
    as_sent,
    life_number,
)
from transport.plausible import Clock
from transport.session import TransportError, add_zenoh_args, settings_from_args

from .resolved import add_scene_args, scene_of_args
from .scene import Scene, SceneError, scene_goal_set
from .warm_start import goal_matching

SETTLE_S = 0.5  # a change in the live robots must hold this long before a new goal set (debounce)
FIRST_SET_PATIENCE = 5.0  # s after the world's first tick that the first goal set waits for every robot's agent
BODY_WAIT_S = 1.0  # display (not wall) s to wait for a dead robot's body: a lock-step tick may wait for it
RESUME_WAIT_S = 2.0  # s a starting coordinator waits for the run's newest goal set (none: a new run)
PREPARE_AHEAD = 5.0  # s of display before an image change that the coordinator prepares its warm start


def clear_of_bodies(goals: np.ndarray, bodies: np.ndarray, clearance: float) -> np.ndarray:
    """Goals pushed radially out of the disks around dead robots' bodies (which stay where they stopped)."""
    out = np.array(goals, float)
    for b in bodies:
        d = out - b
        dist = np.hypot(d[:, 0], d[:, 1])
        near = dist < clearance
        direction = np.where(dist[near, None] > 1e-9, d[near] / np.maximum(dist[near, None], 1e-9), [1.0, 0.0])
        out[near] = b + direction * clearance
    return out


def palette(n: int) -> np.ndarray:
    """Distinct, bright LED colours for robots with individual goals (hue around the circle)."""
    rgb = [colorsys.hsv_to_rgb(k / max(n, 1), 0.85, 1.0) for k in range(n)]
    return (np.array(rgb).reshape(-1, 3) * 255).round().astype(np.uint8)


def scene_goal_message(scene: Scene) -> Goals | None:
    """Per-robot goals of a scene (RVO2-style examples), or None when the scene has none."""
    goals = scene.goal_positions
    if np.isnan(goals).all():
        return None
    none = np.isnan(goals).any(axis=1)
    goals = np.where(none[:, None], scene.poses[:, :2], goals)  # robots without a goal stay put
    return Goals(1, 1, goals, palette(len(goals)))


def step_timing(scene: Scene, step: int, stamp: float = 0.0) -> Timing:
    """A step's goal set's timing part, published at ``stamp`` (its start is t = 0 of eq. 28; K_f dt, eq. 27)."""
    s = scene.steps[step]
    return Timing(stamp, step, float(s.hold), scene.step_starts[step], s.frame_period)


def step_motion(scene: Scene, step: int) -> Motion | None:
    """A step's goal set's motion part: a dynamic image's (eq. 28), None for a still one."""
    m = scene.steps[step].motion
    return None if m is None else Motion(*m.velocity, m.angular_velocity, *m.center, m.expansion, int(m.geometric))


def follows_keyframe(before: Goals, goals: Goals) -> bool:
    """Whether two image sets are consecutive keyframes (paper 6.1-6.2) for the same robots, which carry
    their goals over."""
    return (
        before.timing.frame_period > 0
        and goals.timing.frame_period > 0
        and goals.timing.step == before.timing.step + 1
        and np.array_equal(before.robots, goals.robots)
        and not before.moves
        and not goals.moves
    )


@dataclass
class Roster:
    """The agents heard alive, whose robots the next goal set is for, and when that last changed."""

    live: set[int] = field(default_factory=set)
    changed: float = 0.0  # wall time of the last change in the live robots
    ever: set[int] = field(default_factory=set)  # robots whose agent was ever alive
    lives: dict[int, str] = field(default_factory=dict)  # each robot's agent's last incarnation heard
    restarted: set[int] = field(default_factory=set)  # robots that need a goal set to bid again (hear)
    lockstep: bool = False  # the run's clock
    heard_dead: set[int] = field(default_factory=set)  # robots whose agent this coordinator heard die

    def hear(self, r: int, alive: bool, life: str) -> None:
        changed = (r in self.live) != alive  # not a copy of the set: thousands of agents say so at start
        (self.live.add if alive else self.live.discard)(r)
        # a restarted agent bids only in sets published after it joined: it needs one, the live robots unchanged.
        # Lock-step, so does an agent heard dead and back in the same life (its link lost, its process stalled):
        # the other hosts may have closed rounds without it, and a new set starts every host's auction again.
        if alive and self.lives.setdefault(r, life) != life:
            self.lives[r] = life
            self.restarted.add(r)
        elif alive and self.lockstep and r in self.heard_dead:
            self.restarted.add(r)
        (self.heard_dead.discard if alive else self.heard_dead.add)(r)
        if changed or r in self.restarted:
            self.changed = time.monotonic()
        if alive:
            self.ever.add(r)

    def gave_up(self, robots: set[int]) -> None:
        """Lock-step: a host gave up an auction block of the current set for these robots. The hosts' blocks may
        have parted for good (one gave up a block that others finished): a new set, cold, begins every host's
        auction again from one board, as after a restart."""
        robots &= self.live
        self.restarted |= robots
        if robots:
            self.changed = time.monotonic()


@dataclass
class ShowClock:
    """What the coordinator heard of the run's clock: the world's ticks it believed."""

    ticks: Inbox[Tick] | None = None  # the world's clock, subscribed to in image scenes
    t: float | None = None  # display time of the last tick
    first_tick_at: float = 0.0  # wall time the world's first tick was heard (0: none yet)
    plausible: Clock = field(default_factory=Clock)

    def hear(self) -> None:
        for _, tick in self.ticks.drain() if self.ticks is not None else []:
            if self.plausible.admit(tick, time.monotonic()) is not None:
                continue  # not believed: a forged stamp could jump the show to its end
            self.t = tick.stamp if self.t is None else max(self.t, tick.stamp)
            self.first_tick_at = self.first_tick_at or time.monotonic()


@dataclass
class DeadBodies:
    """Where dead robots' bodies stand (they stay where they stopped), which the goals are kept clear of."""

    positions: dict[int, np.ndarray] = field(default_factory=dict)  # dead robots' tracked positions
    poses: Inbox[Pose] | None = None  # the tracker's poses of dead robots, from the first death
    wait_since: float | None = None  # display time a goal set began to wait for a body not tracked yet

    def watch(self, bus: Bus, dead: np.ndarray) -> None:
        """Hear where these dead robots' bodies stay: one subscription (zenoh-python gives each its own thread)."""
        if self.poses is None:
            self.poses = bus.subscribe(bus.keys.all_of("pose"), Pose, only=dead)
        else:
            self.poses.keep = KeepRobots(dead)

    def hear(self) -> None:
        for _, pose in self.poses.drain() if self.poses is not None else []:
            self.positions[pose.robot] = np.array([pose.x, pose.y])

    def waited_for(self, dead: list[int], t: float) -> bool:
        """Whether a goal set may go out at display time ``t``: every dead robot's body is tracked, or
        BODY_WAIT_S has passed waiting for the rest."""
        if any(r not in self.positions for r in dead):
            self.wait_since = t if self.wait_since is None else self.wait_since
            if t - self.wait_since < BODY_WAIT_S:
                return False
        self.wait_since = None
        return True

    def of(self, dead: list[int]) -> np.ndarray:
        """The tracked positions of these dead robots' bodies, one row each."""
        return np.array([self.positions[r] for r in dead if r in self.positions]).reshape(-1, 2)


class Coordinator:
    """The goal sets of a run (paper 5): each step's image for the robots alive, clear of dead bodies."""

    def __init__(self, bus: Bus, scene: Scene) -> None:
        self.bus, self.scene = bus, scene
        self.current = scene_goal_message(scene)
        self.images = bool(scene.steps)
        self.epoch = 0
        period = RobotParams.from_dict(scene.robot).dt if scene.clock == "realtime" else None  # lock-step: no pace
        self.clock = ShowClock(plausible=Clock(period))
        self.roster = Roster(lockstep=scene.clock == "lockstep")
        self.shown: tuple[int, frozenset[int]] | None = None  # (step, robots) of the current epoch
        self.pixels = frozenset(scene.pixel_robots)  # the robots that show the image
        self.bodies = DeadBodies()
        self._matching: tuple[tuple[bytes, bytes], tuple[np.ndarray, np.ndarray]] | None = None  # goal_matching's last
        self.ready_for_a_loss = False  # _prepare_for_a_loss has run
        if self.images:
            self.clock.ticks = bus.subscribe(bus.keys.clock, Tick)
            self.alive = bus.watch_alive("agent")
        # lock-step: hosts that gave up an auction block (Roster.gave_up)
        self.agent_events = (
            bus.subscribe(bus.keys.agents_events, Event) if self.images and self.roster.lockstep else None
        )
        bus.serve(bus.keys.all_of("goals"), self._answer)
        self.running = True

    def resume(self) -> Goals | None:
        """Go on from the newest goal set the run recorded (a restart mid-run), returned if there is one."""
        found = [g for _, g in self.bus.query(self.bus.keys.run_goals, Goals, timeout=RESUME_WAIT_S) if not g.per_robot]
        if not self.images or not found:
            return None
        newest = max(found, key=lambda g: g.epoch)
        robots = frozenset(int(r) for r in newest.robots)
        self.current, self.epoch = newest, newest.epoch
        self.shown = (newest.timing.step, robots)
        self.roster.ever |= robots
        self.roster.changed = time.monotonic()  # the live robots are heard again: none counts as a change yet
        return newest

    def _answer(self) -> list[tuple[str, bytes]]:
        current = self.current  # once: the bus's thread asks while the loop may replace it
        return [] if current is None else [(self.bus.keys.goals(current.epoch), current.encode())]

    def _follow_show(self) -> bool:
        """Image scenes: a new goal set when the step or the live robots change; True if published."""
        self._hear()
        robots = frozenset(self.roster.live) & self.pixels
        t = self.clock.t
        if t is None or not robots:
            return False  # the show starts with the world's first tick
        patient = time.monotonic() - self.clock.first_tick_at < FIRST_SET_PATIENCE
        if self.shown is None and robots != self.pixels and patient:
            return False  # agents not heard yet would join in a second epoch, at a tick load decides
        step = self.scene.step_at(t)
        restarted = bool(self.roster.restarted & robots)
        if self.shown is not None:
            if (step, robots) == self.shown and not restarted:
                return False
            if (robots != self.shown[1] or restarted) and time.monotonic() - self.roster.changed < SETTLE_S:
                return False
        dead = list(self.roster.ever - self.roster.live)
        if not self.bodies.waited_for(dead, t):
            return False
        self._publish(step, robots, dead)
        return True

    def _hear(self) -> None:
        """The world's clock, the agents' liveliness, and where dead robots' bodies stand."""
        self.clock.hear()
        for _, ident, alive, _, life in self.alive.drain():
            if ident.isdigit() and int(ident) < self.scene.robots:
                self.roster.hear(int(ident), alive, life)
                if not alive:  # hear where its body stays, with every other dead robot's
                    self.bodies.watch(self.bus, np.array(sorted((self.roster.ever - self.roster.live) | {int(ident)})))
        self.bodies.hear()
        for _, event in self.agent_events.drain() if self.agent_events is not None else ():
            data = event.data
            if data.get("kind") == BLOCK_ABANDONED and data.get("epoch") == self.epoch:
                robots = data.get("robots")
                if isinstance(robots, list):
                    self.roster.gave_up({r for r in robots if isinstance(r, int)})

    def _publish(self, step: int, robots: frozenset[int], dead: list[int]) -> None:
        """The next epoch's goal set, clear of dead robots' bodies, warm-started from the last set."""
        assert self.clock.t is not None
        goals, colors = scene_goal_set(self.scene, step, len(robots))
        bodies = self.bodies.of(dead)
        if len(bodies):
            goals = clear_of_bodies(goals, bodies, 2 * self.scene.radius + 0.05)  # room for its inflated radius
        before = self.current
        # lock-step: a restarted agent has no last agreement to warm-start from (a stalled one, maybe not the
        # others'), so nobody does. But a step's set is taken up at the step's first tick, which the world may have
        # sent before a robot was heard back (it went on without it), and that robot's host takes it up later: the
        # step's set goes out as ever, and one more right after it, cold, named by a tick every host steps (it
        # differs from the step's by its warm start: the same content under a new epoch is refused as a replay).
        restarted = self.scene.clock == "lockstep" and bool(self.roster.restarted & robots)
        cold = restarted and self.shown is not None and step == self.shown[0]
        if not restarted or cold:
            self.roster.restarted.clear()
        stamp = self._stamp()
        self.epoch += 1
        self.shown = (step, robots)
        timing, motion = step_timing(self.scene, step, stamp), step_motion(self.scene, step)
        self.current = Goals(self.epoch, 0, goals, colors, np.array(sorted(robots)), timing, motion)
        # who takes part, in which life: every host reads the same, however its liveliness events come
        self.current.lives = Lives(np.array([life_number(self.roster.lives.get(r, "")) for r in sorted(robots)]))
        if before is not None and not before.per_robot and len(before.positions) == len(goals):
            matched, prices = self._warm_start(as_sent(before.positions), goals)
            self.current.warm_start = None if cold else WarmStart(before.epoch, matched, prices)
            if follows_keyframe(before, self.current):  # the same matching is a keyframe's correspondence (6.1)
                self.current.correspondence = Correspondence(before.epoch, matched)
        elif before is None and self._rounds_bounded():
            # the first set, from where the robots start: they drive at once while its auction spans ticks
            self.current.warm_start = WarmStart(0, *self._warm_start(self._starts(self.current.robots), goals))
        self.bus.publish(self.bus.keys.goals(self.epoch), self.current)

    def _stamp(self) -> float:
        """The next set's stamp: the display time, and always past the current set's. A set that is the current
        one under a new epoch (a cold set again for the same robots, at the same tick) is refused as a replay
        (transport.plausible.GoalSets); waiting a tick for a new stamp would stall a lock-step world whose hosts
        wait for that set to leave a round they cannot finish."""
        t, current = self.clock.t, self.current
        assert t is not None
        return t if current is None or t > current.timing.stamp else float(np.nextafter(current.timing.stamp, np.inf))

    def _rounds_bounded(self) -> bool:
        """Lock-step with rounds per tick bounded: an auction spans ticks, the robots need goals meanwhile."""
        return self.scene.clock == "lockstep" and bool(self.scene.robot.get("rounds_per_tick", 0))

    def _warm_start(self, start: np.ndarray, goals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """goal_matching from robots standing on ``start`` to these goals, kept for _prepare_next's reuse."""
        start, goals = np.asarray(start, float), as_sent(goals)
        key = (start.tobytes(), goals.tobytes())
        if self._matching is None or self._matching[0] != key:
            eps = self.scene.robot.get("assign_eps")  # the robots' epsilon_A, which the matching settles to
            self._matching = (key, goal_matching(start, goals, None if eps is None else float(eps)))
        return self._matching[1]

    def _starts(self, robots: np.ndarray) -> np.ndarray:
        return np.asarray(self.scene.poses, float)[robots, :2]

    def _prepare_next(self) -> None:
        """The next set's warm start ahead of time (a large matching would delay the change): the first set's
        while the agents start, each next one's PREPARE_AHEAD s before it is due."""
        if self.current is None and self._matching is None and self.scene.steps and self._rounds_bounded():
            first = np.array(sorted(self.pixels), np.int64)  # the first set's robots once all are alive
            self._warm_start(self._starts(first), scene_goal_set(self.scene, 0, len(first))[0])
        if self.shown is None or self.clock.t is None or self.current is None:
            return
        step, robots = self.shown[0] + 1, self.shown[1]
        if step >= len(self.scene.steps) or self.scene.step_starts[step] - self.clock.t > PREPARE_AHEAD:
            return
        goals, _ = scene_goal_set(self.scene, step, len(robots))
        if len(goals) == len(self.current.positions) and not self.bodies.positions:
            self._warm_start(as_sent(self.current.positions), goals)

    def _prepare_for_a_loss(self) -> None:
        """Once: the current set for one robot fewer, so the image pipeline is loaded before a robot dies."""
        if self.ready_for_a_loss or self.shown is None:
            return
        self.ready_for_a_loss = True
        step, robots = self.shown
        if len(robots) > 1:
            scene_goal_set(self.scene, step, len(robots) - 1)

    def run(self, period: float = 1.0, parent_pid: int | None = None) -> None:
        """Until stopped, or until the launcher ``parent_pid`` (--exit-with-parent) is gone."""
        self.bus.declare_alive("coordinator", 0)
        next_publish = 0.0
        while self.running:
            self.bus.renew_if_due()  # its link to the router came back a while ago
            if self.images and self._follow_show():
                next_publish = time.monotonic() + period
            elif self.images:
                self._prepare_next()
                self._prepare_for_a_loss()
            if self.current is not None and time.monotonic() >= next_publish:
                self.bus.publish(self.bus.keys.goals(self.current.epoch), self.current)
                next_publish = time.monotonic() + period
            time.sleep(0.02)
            if parent_pid is not None and os.getppid() != parent_pid:
                self.running = False  # orphaned: the launcher died without stopping us


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m coordinator.service")
    add_scene_args(parser)
    parser.add_argument("--exit-with-parent", action="store_true")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        scene = scene_of_args(args)
        bus = Bus(settings_from_args(args), args.display, name="coordinator")
    except (SceneError, TransportError) as err:
        print(f"coordinator: error: {err}", file=sys.stderr)
        return 2
    with bus:
        coordinator = Coordinator(bus, scene)
        resumed = coordinator.resume()
        if resumed is not None:
            print(f"coordinator: going on from goal set {resumed.epoch} (step {resumed.timing.step})", flush=True)

        def stop(signum: int, frame: object) -> None:
            coordinator.running = False

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        coordinator.run(parent_pid=os.getppid() if args.exit_with_parent else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
