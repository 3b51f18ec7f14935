"""The body node: one process between the robots' agents and their bodies (a ``Backend``), whatever they are.

Every control period it publishes the clock, the truth and the poses, takes each robot's newest command to
its body and lets the bodies move, on a ``LockStep`` (reproducible) or ``WallClock``. A robot whose agent is
late or gone, or whose pose is lost, stops (the watchdog): ORCA's guarantee holds only for commands computed
from the current poses. Commands no honest agent sends (from the future, or mis-stamped) are dropped, and a
robot commanded two ways at one tick (its key's holder beside its agent) stands until its commands agree.
"""

from __future__ import annotations

import bisect
import json
import math
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from agent.core.grid import nearest
from agent.core.params import RobotParams
from coordinator.scene import Scene, events_of, take_due
from sim.args import format_ids
from transport.bus import Bus
from transport.codec import BEFORE_START, Command, Event, Goals, State, Tick, Truth, intact
from transport.codec import Contact as ContactMsg
from transport.keys import Keys
from transport.plausible import CONFLICTING, FUTURE, INCONSISTENT, MISADDRESSED, GoalSets, stamp_agrees

STARTUP_TIMEOUT = 60.0  # s the node waits for every agent by default (`pixelswarm run` says how long)
BEFORE_START_EVERY = 0.2  # s: poses to robots whose agent is not live yet
# Lock-step's longest waits (s): while auction messages keep coming (a repeating peer cannot hold the world
# for ever), for a new step's goal set (agent.clocks.GOAL_SET_WAIT), for the first tick's commands (a missed
# first tick makes a different run), for the agents a 'fail' event kills to be gone (the launcher may lag).
AUCTION_PATIENCE, GOAL_SET_PATIENCE, FIRST_TICK_PATIENCE, FAIL_PATIENCE = 60.0, 10.0, 10.0, 10.0
STOP_REASONS = ("agent_lost", "pose_lost", "command_timeout")  # the watchdog's, in the order it asks
COMMAND_DROPS = (FUTURE, INCONSISTENT, MISADDRESSED, CONFLICTING)
TWO_WAYS = "commanded-two-ways"  # the event of a robot's first conflicting command after it was trusted
COMMANDS_KEPT = 8  # ticks of each robot's first commands remembered, to see a second that differs (or copies one)
CONTACT_KINDS = {"robot": 0, "obstacle": 1, "wall": 2}


class Backend(Protocol):
    """The bodies: commands in, poses out, stop. ``tracked``: robots whose pose is known now."""

    params: RobotParams
    tracked: np.ndarray

    @property
    def min_clearance(self) -> float: ...  # the smallest clearance so far (m)
    @property
    def contacts(self) -> list: ...  # the contacts so far
    def sense(self, t: float) -> None: ...  # take in the bodies at time t of the run
    def measure(self, t: float) -> np.ndarray | None: ...  # the tracker's poses; None: withheld
    def true_poses(self) -> np.ndarray: ...  # where the bodies are (told to robots before they start)
    def hold(self, cmd: Command) -> float | None: ...  # until when a command holds; None: it ran out already
    def horizon(self, span: float) -> float: ...  # a command must hold past this to drive the next span
    def moving(self) -> np.ndarray: ...  # bodies a stop would change
    def apply(self, ids: list[int], cmds: list[Command], colors: np.ndarray) -> None: ...
    def stop(self, ids: list[int]) -> None: ...
    def step(self, span: float) -> list: ...  # let the bodies move for span s; the contacts that began
    def own_movers(self, tick: int, t: float) -> list[State]: ...  # bodies it drives itself: their states
    def truth(self, tick: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]: ...
    def applied(self) -> np.ndarray: ...  # commands applied per robot
    def report(self, node: BodyNode) -> dict[str, Any]: ...  # what the run's report adds for them


@dataclass
class Tally:
    """The run's statistics, per robot where the hardware report lists them."""

    n: int
    expired_commands: int = 0  # commands that arrived too late to drive anything
    stopped_ticks: int = 0  # robot-ticks in which a live robot was stopped for want of a valid command
    withheld_ticks: int = 0  # ticks whose poses the tracker withheld (an outage)
    goal_sets_not_awaited: int = 0  # lock-step ticks that went out past GOAL_SET_PATIENCE without their step's goal set
    missed: np.ndarray = field(init=False)  # ticks a live robot's agent did not answer in time
    late: np.ndarray = field(init=False)  # commands older than one applied
    dropped: dict[str, np.ndarray] = field(init=False)
    stops: dict[str, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        self.missed = np.zeros(self.n, int)
        self.late = np.zeros(self.n, int)
        self.dropped = {reason: np.zeros(self.n, int) for reason in COMMAND_DROPS}
        self.stops = {reason: np.zeros(self.n, int) for reason in STOP_REASONS}


class LockStep:
    """Publish tick k, wait until every agent live when it went out answered it or a deadline passes (a missed
    tick), then advance one period. An agent heard alive meanwhile is waited for from the next tick: it may
    have missed this tick's pose (a restarted one subscribes as the world goes on). The deadline runs from
    the last auction message heard; a tick at which the scene kills robots waits until their agents are
    gone, and a tick whose goal set is due (a starting step's, or the survivors' of a kill) until it is heard."""

    def __init__(self, bus: Bus, deadline: float) -> None:
        self.deadline = deadline
        self.auction_traffic = [bus.subscribe_raw(bus.keys.all_of(kind)) for kind in ("auction", "boards")]

    def publishing(self, node: BodyNode) -> None:
        """Tick ``node.tick`` is about to go out. Under command faults delays count on the run's clock and
        the inbox notes each robot's commands as they come, so ``spans`` waits for none that came and was lost."""
        inbox = node.cmd_inbox
        if inbox.fault is not None:
            inbox.sim_time = node.tick * node.dt
            if inbox.seen is None:  # noted from the first tick on
                inbox.seen = {}

    def spans(self, node: BodyNode) -> Iterator[float]:
        deadline = time.monotonic() + (self.deadline if node.tick else max(self.deadline, FIRST_TICK_PATIENCE))
        patience = time.monotonic() + AUCTION_PATIENCE
        goal_set_patience = time.monotonic() + GOAL_SET_PATIENCE
        fail_patience = time.monotonic() + FAIL_PATIENCE
        dies = node.killed_now()
        expected = node.live.copy()
        told = -math.inf  # when the robots not alive last heard where they are
        while True:
            # read before the commands are taken: one seen by then is queued, held or lost
            seen, n = node.cmd_inbox.seen, len(node.live)
            arrived = np.array([seen is not None and seen.get(i) == node.tick for i in range(n)], bool)
            node.take_commands(node.cmd_inbox.get(timeout=max(0.0, min(0.05, deadline - time.monotonic()))))
            heard = [data for inbox in self.auction_traffic for _, data, _ in inbox.drain()]
            node.hear_goals()
            # a goal set due and unheard: the coordinator works it out, and the tick waits for it, so that every
            # host takes it up at the same tick however slow the coordinator or the machine
            at_work = time.monotonic() < goal_set_patience and node.awaits_goal_set(dies)
            if any(map(intact, heard)) or at_work:  # a damaged copy is no agent at work
                deadline = min(time.monotonic() + self.deadline, patience)
            node.update_liveness()
            waiting = node.live & expected & (node.last_cmd_tick < node.tick) & ~arrived
            dying = node.live[dies].any() and time.monotonic() < fail_patience
            if at_work and time.monotonic() - told >= BEFORE_START_EVERY:
                node.publish_before_start()  # as before the first tick: the coordinator hears the dead bodies
                told = time.monotonic()
            if (not waiting.any() or time.monotonic() >= deadline or node.withheld) and not dying and not at_work:
                node.tally.goal_sets_not_awaited += int(node.awaits_goal_set(dies))  # still due: patience ran out
                break
        yield node.dt


class WallClock:
    """Real time: the period passes in slices of the wall clock, each command taken as it arrives. After a
    stall, ``catch_up`` runs the missed slices at once (simulated time keeps to the wall); else (real
    robots) the next period starts now."""

    def __init__(self, slice_s: float, catch_up: bool) -> None:
        self.slice, self.catch_up = slice_s, catch_up
        self.next: float | None = None

    def publishing(self, node: BodyNode) -> None:
        """Tick ``node.tick`` is about to go out: nothing to prepare."""

    def spans(self, node: BodyNode) -> Iterator[float]:
        now = time.monotonic()
        due = now if self.next is None or (not self.catch_up and self.next < now) else self.next
        for _ in range(max(1, round(node.dt / self.slice))):
            due = self.next = due + self.slice
            while node.running and (left := due - time.monotonic()) > 0:
                node.take_commands(node.cmd_inbox.get(timeout=left))
                node.update_liveness()
                node.check_control()
            if not node.running:
                return
            node.take_commands()
            yield self.slice


class BodyNode:
    """The body node: its attributes are the state the loop's steps share; the statistics are in ``tally``."""

    def __init__(
        self,
        bus: Bus,
        scene: Scene,
        backend: Backend,
        clock: LockStep | WallClock,
        *,
        startup_timeout: float = STARTUP_TIMEOUT,
        pose_frames: bool = False,
    ) -> None:
        """``pose_frames``: each tick's poses as one frame of every robot (for agent hosts)."""
        self.bus, self.scene, self.backend, self.clock = bus, scene, backend, clock
        self.params, self.dt, n = backend.params, backend.params.dt, scene.robots
        self.startup_timeout, self.pose_frames = startup_timeout, pose_frames
        self.tally = Tally(n)
        self.agent_robot = np.array([i not in scene.scripted for i in range(n)])  # scripted: no agent
        self.color = np.zeros((n, 3), np.uint8)
        self.color[~self.agent_robot] = 255
        self.last_cmd_tick = np.full(n, -1)
        self.valid_until = np.full(n, -np.inf)  # when each robot's command runs out (-inf: stopped)
        self.first_cmd: list[dict[int, Command]] = [{} for _ in range(n)]  # per robot: tick -> its first command
        # a robot commanded two ways stands until this tick; each conflict puts it stale_after further
        self.distrusted_until = np.full(n, -1)
        self.distrust_ticks = self.params.stale_ticks
        self.live, self.ever_live = np.zeros(n, bool), np.zeros(n, bool)
        # this tick's commands of robots not yet heard alive: a restarted agent's first command may
        # overtake the news that it is alive by more than the one drain take_commands waits for
        self.early: list[tuple] = []
        self.tick, self.withheld, self.goal_epoch = 0, False, 0
        self.listed: frozenset[int] = frozenset()  # the robots of the newest goal set heard
        # which goal sets can be the coordinator's, as the agents judge them; the world starts with the run
        self.believed = GoalSets(scene.arena, newest=0)
        self.step_starts, self.step_heard = scene.step_starts, -1  # the newest scene step whose goal set came
        self.cmd_inbox = bus.commands_inbox()
        self.control_inbox = bus.subscribe(bus.keys.event, Event)
        self.goal_inbox = bus.subscribe(bus.keys.all_of("goals"), Goals)
        self.alive = bus.watch_alive("agent")
        self.running, self.end_reason = True, ""
        self.parent_pid: int | None = None  # set by end_on
        self.failures = events_of(scene, "fail")  # the scene's kills to come

    # --- the loop -----------------------------------------------------------------------------
    def run(self) -> None:
        self.bus.declare_alive("world", 0)
        if not self.wait_for_agents():
            missing = np.flatnonzero(self.agent_robot & ~self.live).tolist()
            self.end_reason = self.end_reason or (
                f"no agent came alive for robots {format_ids(missing)} within {self.startup_timeout:g} s"
            )
            return
        steps = round(self.scene.duration / self.dt)
        while self.running and self.tick < steps:
            self.step_tick()
        self.backend.sense(self.tick * self.dt)
        self._publish_truth()  # the state after the last step
        self.end_reason = self.end_reason or "duration"

    def step_tick(self) -> None:
        """One control period: poses and the clock out, commands in, the watchdog, the bodies moved."""
        self.bus.renew_if_due()  # its link to the router came back a while ago
        self.backend.sense(self.tick * self.dt)
        self.update_liveness()
        self.clock.publishing(self)
        self._publish_tick()
        stopped = 0
        for span in self.clock.spans(self):
            stopped = max(stopped, self._watchdog(span))
            self._publish_contacts(self.backend.step(span))
        self.tally.stopped_ticks += stopped
        self.tally.missed += self.live & (self.last_cmd_tick < self.tick)
        self.early = []  # a dead agent's commands are never applied later
        self.tick += 1
        self.check_control()

    def wait_for_agents(self) -> bool:
        """Start when every robot's agent is alive, telling the robots still waiting where they are; False
        if the start-up timeout passes first (or the run is ended): a swarm that lacks robots is not shown."""
        start, last_sent = time.monotonic(), -math.inf
        while self.running and time.monotonic() - start < self.startup_timeout:
            self.bus.renew_if_due()
            self.update_liveness()
            self.check_control()
            if self.live[self.agent_robot].all():
                return True
            if time.monotonic() - last_sent >= BEFORE_START_EVERY:
                self.backend.sense(0.0)
                self.publish_before_start()
                last_sent = time.monotonic()
            time.sleep(0.02)
        return False

    # --- inputs -------------------------------------------------------------------------------
    def update_liveness(self) -> None:
        for _, ident, alive, _, _ in self.alive.drain():
            if not ident.isdigit() or int(ident) >= self.scene.robots:
                continue
            i = int(ident)
            if alive:
                self.live[i] = self.ever_live[i] = True
            elif self.live[i]:
                self.live[i] = False
                self._watchdog(0.0)  # a dead agent's body stays, stopped

    def killed_now(self) -> list[int]:
        """The robots the scene kills at this tick (the launcher kills them by the same rule)."""
        return [int(e["robot"]) for e in take_due(self.failures, self.tick * self.dt)]

    def hear_goals(self) -> None:
        """Take in the goal sets heard, as the agents do, refusing epochs and stamps from the future."""
        for _, goals in self.goal_inbox.drain():
            why = self.believed.admit(goals, self.tick * self.dt)
            if why is None:
                if goals.epoch > self.goal_epoch:  # an id beyond the scene's robots is nobody's
                    self.listed = frozenset(r for r in goals.robots.tolist() if r < self.scene.robots)
                self.goal_epoch = max(self.goal_epoch, goals.epoch)
                self.step_heard = max(self.step_heard, goals.timing.step)
            else:
                self.goal_inbox.drops[why] += 1

    def step_due(self, tick: int) -> int:
        """The scene step shown at ``tick`` (-1: none)."""
        return bisect.bisect_right(self.step_starts, tick * self.dt + 1e-9) - 1

    def awaits_goal_set(self, killed: list[int]) -> bool:
        """This tick begins a scene step whose goal set has not been heard, or kills robots (``killed``) that
        the newest goal set heard lists: the set for the survivors (5.1.2), if any live on, is due."""
        due = self.step_due(self.tick)
        step_unheard = due > self.step_heard and due > self.step_due(self.tick - 1)
        if step_unheard or not self.listed.intersection(killed):  # most ticks kill nobody: asked every wait
            return step_unheard
        return bool(self.live[sorted(self.listed.difference(killed))].any())

    def take_commands(self, first: tuple | None = None) -> None:
        """Every robot's newest command, to its body at once (a robot out of sight is not driven blind)."""
        arrived = self.early + ([first] if first is not None else []) + self.cmd_inbox.drain()
        if any(not self.live[cmd.robot] for _, cmd in arrived if cmd.robot < self.scene.robots):
            self.update_liveness()  # an agent's first command may overtake the news that it is alive
        self.early = [(k, cmd) for k, cmd in arrived if cmd.robot < self.scene.robots and not self.live[cmd.robot]]
        newest: dict[int, Command] = {}
        for key, cmd in arrived:
            i = cmd.robot
            if i >= self.scene.robots or not self.live[i]:
                continue
            why = (
                FUTURE if cmd.tick > self.tick else None if stamp_agrees(cmd.tick, cmd.stamp, self.dt) else INCONSISTENT
            )
            if Keys.last_id(key) not in (i, self.alive.sender.get(i)):  # its own key, or its host's frame
                why = MISADDRESSED
            if why is None and self._commanded_two_ways(cmd):
                why = CONFLICTING
                newest.pop(i, None)
            if why is not None:
                self.tally.dropped[why][i] += 1
                self.cmd_inbox.drops[why] += 1  # with the decoder's drops: the run's dropped messages
                continue
            if cmd.tick <= self.last_cmd_tick[i]:
                self.tally.late[i] += 1
                continue
            self.last_cmd_tick[i] = cmd.tick  # answered: lock-step waits no longer for it
            if self.tick < self.distrusted_until[i]:
                continue
            self.color[i] = (cmd.r, cmd.g, cmd.bl)
            until = self.backend.hold(cmd)
            if until is None:
                self.tally.expired_commands += 1
                continue
            self.valid_until[i] = until
            newest[i] = cmd
        drive = [i for i in newest if self.backend.tracked[i]]
        if drive:
            self.backend.apply(drive, [newest[i] for i in drive], self.color[drive])

    def _commanded_two_ways(self, cmd: Command) -> bool:
        """Whether ``cmd`` differs from the robot's first command of its tick: one agent sends one command a
        tick, so another controller holds its key (stolen, or a second agent). Which one to believe is
        unknown: the robot stops, and stands until its commands have agreed for ``stale_after``. A braking
        second only stops it (its agent taking back a command made from a doubted pose, agent.runtime), and a
        copy of the robot's own command of another tick, under a past tick it answered, is a replay, which drives
        nothing."""
        i, recent = cmd.robot, self.first_cmd[cmd.robot]
        first = recent.setdefault(cmd.tick, cmd)
        if len(recent) > COMMANDS_KEPT:
            del recent[min(recent)]
        if first is cmd or first == cmd:  # the first of its tick (the common case), or a copy of it
            return False
        braking = (cmd.a, cmd.b) == (0.0, 0.0)
        # a replay's tick is past (a second command's tick was answered by its first); at the tick under way a
        # rival may have come first, and a robot driving straight repeats its command: its agent's, not a replay
        if not braking and cmd.tick < self.tick and _copies_another_tick(cmd, recent):
            return False
        if np.isfinite(self.valid_until[i]):
            self.backend.stop([i])
            self.valid_until[i] = -np.inf
        if braking:
            return True
        if self.tick >= self.distrusted_until[i]:  # the launcher says so as it happens
            self.bus.publish(self.bus.keys.event, Event({"kind": TWO_WAYS, "robot": i, "t": self.tick * self.dt}))
        self.distrusted_until[i] = self.tick + self.distrust_ticks
        return True

    def _watchdog(self, span: float) -> int:
        """Stop every body driven by a command whose agent is gone, whose pose is lost or whose command
        runs out before the next ``span`` seconds have passed; how many live robots stand for want of one."""
        expired = self.valid_until <= self.backend.horizon(span)
        causes = {"agent_lost": ~self.live, "pose_lost": ~self.backend.tracked, "command_timeout": expired}
        driven = np.isfinite(self.valid_until) & self.backend.moving()
        stop = np.zeros(len(driven), bool)
        for reason in STOP_REASONS:
            hit = driven & causes[reason] & ~stop
            self.tally.stops[reason] += hit
            stop |= hit
        if stop.any():
            ids = np.flatnonzero(stop).tolist()
            self.backend.stop(ids)
            self.valid_until[ids] = -np.inf
        return int((self.agent_robot & self.live & (expired | stop)).sum())

    def check_control(self) -> None:
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.running = False  # orphaned: the launcher died without stopping us
            self.end_reason = "launcher gone"
        for _, ev in self.control_inbox.drain():
            if ev.data.get("kind") == "end":
                self.running = False
                self.end_reason = str(ev.data.get("reason", "end"))

    # --- outputs ------------------------------------------------------------------------------
    def _publish_tick(self) -> None:
        t = self.tick * self.dt
        self.hear_goals()
        self._publish_truth()
        measured = self.backend.measure(t)
        # the clock just before the poses, which it bounds: both often leave in one batch to each agent
        self.bus.publish(self.bus.keys.clock, Tick(self.tick, t, self.dt, self.goal_epoch))
        self.withheld = measured is None
        if measured is None:
            self.tally.withheld_ticks += 1
        else:
            # The tracker sees bodies, not agents: a robot whose agent died is still tracked, so the
            # coordinator learns where its body stays and keeps the goals clear of it (5.1.2).
            shown = np.flatnonzero(self.ever_live & self.backend.tracked)
            near = None if self.pose_frames else self._near(shown, measured[shown])
            self.bus.publish_poses(self.tick, t, shown, measured[shown], self.pose_frames, near)
            self.publish_before_start()
        # the movers' states, as agents broadcast theirs (one frame for agent hosts, or each under its
        # cell), and the bodies of dead or silent agents as obstacles (_standing_bodies)
        states = self.backend.own_movers(self.tick, t) + self._standing_bodies(measured, t)
        first = states[0].robot if self.pose_frames and states else None
        self.bus.publish_states(self.tick, t, states, self.params.cell_size, first)

    def _near(self, robots: np.ndarray, poses: np.ndarray) -> list[np.ndarray]:
        """For robots alone, who hear no other pose: the rows of the bodies each picks its neighbours
        from (the nearest max_neighbours within neighbour_dist, positions as the wire rounds them), which
        it falls back on for neighbours whose states it has lost (agent.neighbour_table.with_bodies)."""
        p, ids = self.params, robots.astype(np.int64)
        xy = np.ascontiguousarray(poses[:, :2], np.float32).astype(float)
        rows = nearest(xy, ids, xy, ids, p.neighbour_dist, p.max_neighbours)
        return [row[row >= 0] for row in rows]

    def _standing_bodies(self, measured: np.ndarray | None, t: float) -> list[State]:
        """A state per robot whose agent died, or lives but sent no command for ``stale_after`` (hung), or
        that was commanded two ways: its body where the tracker sees it, standing, avoiding nobody.
        Neighbours that never heard the agent, or have forgotten it, would otherwise drive into the body
        the watchdog stopped."""
        if measured is None:
            return []
        r = self.params.radius
        silent = (self.last_cmd_tick >= 0) & ((self.tick - self.last_cmd_tick) * self.dt > self.params.stale_after)
        distrusted = self.tick < self.distrusted_until
        standing = np.flatnonzero(self.ever_live & (~self.live | silent | distrusted) & self.backend.tracked)
        return [
            State(int(i), self.tick, t, float(x), float(y), 0.0, 0.0, r, 0.0, 0.0, -1, State.DYNAMIC)
            for i, (x, y) in zip(standing, measured[standing, :2])
        ]

    def publish_before_start(self) -> None:
        """Robots whose agent is not live (yet, or any more) hear where they are, without tracker noise (so
        timing cannot change the noise sequence); so does the coordinator of the dead bodies it keeps goals
        clear of."""
        waiting = np.flatnonzero(~self.live & self.agent_robot & self.backend.tracked)
        if not len(waiting):
            return
        poses = self.backend.true_poses()[waiting]
        self.bus.publish_poses(BEFORE_START, self.tick * self.dt, waiting, poses, self.pose_frames)

    def _publish_truth(self) -> None:
        clearance, poses, velocities, applied = self.backend.truth(self.tick)
        truth = Truth(
            self.tick, self.tick * self.dt, clearance, self.scene.robots, poses, velocities, self.color, applied
        )
        self.bus.publish(self.bus.keys.truth, truth)

    def _publish_contacts(self, contacts: list) -> None:
        for c in contacts:
            self.bus.publish(self.bus.keys.contact, ContactMsg(CONTACT_KINDS[c.kind], c.i, c.j, c.t_start, c.max_depth))

    def end_on(self, exit_with_parent: bool, *signums: int) -> None:
        """These signals end the run, as an end event does; so does the launcher's end if ``exit_with_parent``."""
        self.parent_pid = os.getppid() if exit_with_parent else None

        def stop(signum: int, frame: object) -> None:
            self.running = False
            self.end_reason = self.end_reason or "stopped"

        for signum in signums:
            signal.signal(signum, stop)

    def report(self) -> None:
        """The run's report as an event, and on stdout (a loaded router may not deliver the event in time)."""
        stats = self.stats()
        self.bus.publish(self.bus.keys.event, Event(stats))
        print("WORLD-DONE " + json.dumps(stats), flush=True)
        self.bus.linger()

    def stats(self) -> dict:
        """The run's report (kind world-done), whatever the bodies."""
        tally, backend = self.tally, self.backend
        drops = self.cmd_inbox.drops + self.control_inbox.drops + self.goal_inbox.drops
        return {
            "kind": "world-done",
            "reason": self.end_reason,
            "ticks": self.tick,
            "missed_ticks": int(tally.missed.sum()),
            "missed_ticks_by_robot": tally.missed.tolist(),
            "late_commands": int(tally.late.sum()),
            "expired_commands": tally.expired_commands,
            "stopped_ticks": tally.stopped_ticks,
            "withheld_ticks": tally.withheld_ticks,
            "goal_sets_not_awaited": tally.goal_sets_not_awaited,
            "commanded_two_ways": np.flatnonzero(tally.dropped[CONFLICTING]).tolist(),
            "commands_applied": backend.applied().astype(int).tolist(),
            "min_clearance": backend.min_clearance if math.isfinite(backend.min_clearance) else None,
            "dropped": dict(drops),
            "contacts": [asdict(c) for c in backend.contacts],  # sim.bodies.world.Contact's fields
            **backend.report(self),
        }


def _copies_another_tick(cmd: Command, firsts: dict[int, Command]) -> bool:
    """Whether ``cmd`` says what the robot's first command of another tick said (a copy under a moved tick):
    equal but for its tick and stamp, by the command's own equality, so a field added to it counts too."""
    return any(t != cmd.tick and replace(c, tick=cmd.tick, stamp=cmd.stamp) == cmd for t, c in firsts.items())
