"""The agent runtime: binds the pure control core to the bus for K robots in one process (time comes only from
messages: each tick, poses and neighbours' states in; states, commands and LED colours out)."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, fields, replace
from functools import partial
from typing import Any

import numpy as np

from transport.bus import Bus, Inbox, KeepRobots, LivelinessWatch
from transport.codec import BEFORE_START, BLOCK_ABANDONED, Command, Commands, Event, Goals, Pose, State, life_number
from transport.keys import cell_of, cells_of, robots_ident
from transport.plausible import CONFLICTING, FUTURE, INCONSISTENT, GoalSets, TickLine, stamp_agrees

from . import loop
from .assignment import AuctionLink, LockStepRounds
from .clocks import HostClock, LockStep, WallClock
from .core.control import touch_reach
from .core.params import DIFFDRIVE, RobotParams
from .core.policy import Decision, GoalTiming, Memory
from .core.step import NeighbourStates, settings_of, static_segments
from .goal_sets import motion_of, timing_of
from .held_goals import HeldGoals
from .loop import Sensed
from .neighbour_table import NeighbourTable, TrackedBodies
from .pose_trust import PoseTrust

GOAL_SETS_KEPT = 4  # goal sets remembered (an agreed assignment may still be of an older epoch)
POSES_KEPT = 8  # ticks of each robot's poses remembered, to see a second pose of a tick that differs, or a copy


@dataclass
class RobotMemory:
    """Where one robot was last tracked (its goal is in AgentHost.held_goals)."""

    robot: int
    position: np.ndarray | None = None  # tracked position of the last tick
    stamp: float = 0.0  # display time of `position`


@dataclass
class HostConfig:
    """A robot's own configuration, as a real robot would read it from its config file."""

    robots: list[int]
    params: RobotParams
    display: str = "default"
    seed: int = 0
    arena: tuple[float, float, float, float] | None = None
    obstacles: list[list[tuple[float, float]]] = field(default_factory=list)
    batch_wait: float = 0.05  # how long to wait for the other robots' poses of a tick (real time)
    lockstep: bool = False  # wait for the previous tick's states of nearby robots (reproducible runs)
    state_wait: float = 1.5  # lock-step: how long to wait for a nearby robot's state before going on
    pursue: dict[int, int] = field(default_factory=dict)  # robot -> the robot whose broadcasts are its goal
    greet: list[int] = field(default_factory=list)  # lock-step: robots near ours at the start (see AgentHost.start)
    frames: bool = False  # a host of several robots: one frame a tick of poses, of states, of commands (else per robot)
    steps: list[float] = field(default_factory=list)  # lock-step: display times goal sets are due (a tick waits)
    reach: float = math.inf  # communication range (m): states and the auction heard only from robots this close
    swarm: int = 0  # robots in the run (0: not known): lock-step hellos are rarer in large swarms (agent.clocks)

    @classmethod
    def from_json(cls, text: str) -> HostConfig:
        """The configuration to_json wrote; keys it lacks take the defaults above."""
        data = json.loads(text)
        data["params"] = RobotParams.from_dict(data["params"])
        data["arena"] = tuple(data["arena"]) if data.get("arena") else None
        data["obstacles"] = [[tuple(v) for v in o] for o in data.get("obstacles", [])]
        data["pursue"] = {int(k): int(v) for k, v in data.get("pursue", {}).items()}  # JSON keys are strings
        data["reach"] = math.inf if data.get("reach") is None else float(data["reach"])
        return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data})

    @property
    def hears_itself(self) -> bool:
        """A host's robots hear each other through the bus; a robot alone does not hear its own states."""
        return len(self.robots) > 1

    def to_json(self) -> str:
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data["params"] = self.params.to_dict()
        data["reach"] = self.reach if math.isfinite(self.reach) else None
        return json.dumps(data)


def interpreter(robots: int) -> list[str]:
    """The Python and flags that run an agent process: a robot alone runs -OO where make compiled that bytecode."""
    import importlib.util  # here: the launcher asks, a robot's process need not load it

    samples = (json.__file__, np.__file__, __file__)  # the standard library, numpy, ours
    compiled = all(os.path.exists(importlib.util.cache_from_source(f, optimization=2)) for f in samples)
    return [sys.executable, *(["-OO", "-X", "no_debug_ranges"] if compiled and robots == 1 else [])]


ARENA_SLACK = 1.0  # m beyond the arena's edges where a pose is still believed (a robot carried off it)
AUCTION_SHARE = 0.2  # of a control period, spent on auction rounds after a tick (AgentHost._auction_rounds)
AUCTION_SHARE_COLD = 0.8  # ... until the newest goal set's first agreement: robots wait for it


class KeepCells(KeepRobots):
    """The records in these spatial cells (a host's neighbourhood), and those of ``robots`` (its pursuers' targets)."""

    def __init__(self, cells: set[tuple[int, int]], cell_size: float, robots: frozenset[int]) -> None:
        super().__init__(robots)
        self.cells, self.cell_size = cells, cell_size
        self._keys = np.array(sorted(self._key(c) for c in cells), np.int64)  # a set's: unique already

    @staticmethod
    def _key(cell: Any) -> Any:
        return cell[0] * (1 << 32) + cell[1]  # one int64 per cell (or per column of cells), for np.isin

    def mask(self, records: np.ndarray) -> np.ndarray:
        cells = cells_of(np.column_stack([records["x"], records["y"]]), self.cell_size)
        return np.isin(self._key(cells.T), self._keys) | super().mask(records)

    def keeps(self, view: Any) -> bool:
        return cell_of(view.x, view.y, self.cell_size) in self.cells or super().keeps(view)


class CellSubscriptions:
    """Subscriptions to the 5x5 cells around each robot; lock-step's 7x7 are in place before anyone in the outer ring
    can become a neighbour (zenoh is asynchronous). With ``listen`` off they only pick what the inbox keeps."""

    def __init__(self, bus: Bus, inbox: Any, cell_size: float, reach: int = 3, listen: bool = True) -> None:
        self.bus, self.inbox, self.cell_size, self.reach, self.listen = bus, inbox, cell_size, reach, listen
        self.targets: frozenset[int] = frozenset()  # robots heard wherever they are (not listening)
        self._subs: dict[tuple[int, int], Any] = {}  # cell -> its subscriber (None: not listening)
        self._own: list[list[int]] | None = None  # the robots' own cells at the last update

    def update(self, positions: np.ndarray) -> None:
        # every robot's cell at once: a host may place hundreds a tick
        own = cells_of(positions, self.cell_size).tolist()
        if own == self._own:
            return  # most ticks: every robot is still in its cell
        self._own = own
        # the square of cells around each, as a set: np.unique would load numpy's sorting code into every robot
        span = range(-self.reach, self.reach + 1)
        wanted = {(cx + dx, cy + dy) for cx, cy in own for dx in span for dy in span}
        for cell in set(self._subs) - wanted:
            if (sub := self._subs.pop(cell)) is not None:
                self.bus.unsubscribe(sub)
        for cell in sorted(wanted - set(self._subs)):
            self._subs[cell] = (
                self.bus.subscribe_into(self.bus.keys.state_cell(cell), self.inbox) if self.listen else None
            )
        if not self.listen:
            self.inbox.keep = KeepCells(wanted, self.cell_size, self.targets)

    @property
    def cells(self) -> set[tuple[int, int]]:
        return set(self._subs)


@dataclass
class Inboxes:
    """What a host hears: its robots' poses, its neighbours' states (by cell), the goal sets, whose agents died."""

    pose: Inbox[Pose]
    bodies: TrackedBodies  # where the tracker saw the others, from the pose frames
    state: Inbox[State]
    cells: CellSubscriptions
    goals: Inbox[Goals]
    departed: Departures
    bell: threading.Event  # rung by poses, goal sets, auction messages and a stop: the loop sleeps until one comes

    @classmethod
    def of(cls, bus: Bus, config: HostConfig, own: np.ndarray) -> Inboxes:
        # a host keeps its rows of the tracker's frames (a subscription per robot is a thread in zenoh-python)
        keys = bus.keys
        pose, bodies = bus.inbox(Pose, only=own), TrackedBodies()
        pose.bodies = bodies.hear
        for key in [keys.poses] if config.frames else [keys.pose(r) for r in config.robots]:
            bus.subscribe_into(key, pose)
        state = bus.inbox(State, pulled=True)  # fed by the spatial cells around the robots ...
        reach = 3 if config.lockstep else 2
        everyone = not config.frames and window_covers_a_third(config.arena, config.params.cell_size, reach)
        whole = config.frames or everyone  # ... or by every host's frames, or every robot's, kept by cell
        if whole:
            bus.subscribe_into(keys.states_all if config.frames else keys.states_in_cells, state)
        cells = CellSubscriptions(bus, state, config.params.cell_size, reach, listen=not whole)
        cells.targets = frozenset(config.pursue.values())  # a pursuer hears its target wherever it is
        for target in () if everyone else cells.targets:
            bus.subscribe_into(keys.state_of(target), state)
        goals = bus.subscribe(keys.all_of("goals"), Goals)
        pose.bell = goals.bell = bell = threading.Event()
        return cls(pose, bodies, state, cells, goals, Departures(bus.watch_alive("agent")), bell)


def window_covers_a_third(arena: tuple[float, float, float, float] | None, cell_size: float, reach: int) -> bool:
    """Whether a robot's cells cover a third of the arena: one subscription to all states is then cheaper."""
    if arena is None:
        return False
    (c0, r0), (c1, r1) = cell_of(arena[0], arena[1], cell_size), cell_of(arena[2], arena[3], cell_size)
    return 3 * (2 * reach + 1) ** 2 >= (c1 - c0 + 1) * (r1 - r0 + 1)


class OwnRobots:
    """The robots a host steps: their rows in its batches (in id order), where each was last tracked and where
    they bid from in the auction."""

    def __init__(self, robots: list[int]) -> None:
        self.ids = np.array(sorted(robots))
        self.row_of = {r: b for b, r in enumerate(self.ids.tolist())}  # robot -> its row in the batches
        self.tracked = {r: RobotMemory(r) for r in robots}  # in the configuration's order
        self.bid_from: dict[int, np.ndarray] | None = None  # AgentHost._positions(), until positions or goals change

    def __contains__(self, robot: object) -> bool:
        return robot in self.tracked

    def __len__(self) -> int:
        return len(self.tracked)

    def rows(self, robots: Iterable[int]) -> np.ndarray:
        return np.array([self.row_of[r] for r in robots], np.int64)

    def known(self) -> list[RobotMemory]:
        """The robots tracked at least once."""
        return [m for m in self.tracked.values() if m.position is not None]


class PoseIntake:
    """The poses the next step acts on, by robot, checked against the clock and where the robot could have driven.
    A second pose of a tick that differs from the first, and lies nearer where the robot's last command took it
    (a forged pose came first), makes the robot brake until its poses have agreed for ``stale_after``, as the
    body node stops a robot commanded two ways; one farther off (a late copy of another tick's) is refused."""

    def __init__(self, config: HostConfig, pose_period: float | None) -> None:
        p = config.params
        self.dt = p.dt
        self.pending: dict[int, Pose] = {}
        self.trust = PoseTrust(p.v_max, p.dt, 2 * p.noise_bound)
        self.lines = {r: TickLine(pose_period) for r in config.robots}
        self.arena = config.arena
        # per robot, the last POSES_KEPT ticks': the pose acted on; the velocity it drove at and the command sent
        self.acted: dict[int, dict[int, tuple[float, float, float]]] = {r: {} for r in config.robots}
        self.sent: dict[int, dict[int, tuple[tuple[float, float], Command]]] = {r: {} for r in config.robots}
        self.doubted_until: dict[int, int] = {}  # robot -> the tick from which its poses are believed again
        self.doubt_ticks = p.stale_ticks

    def off_arena(self, pose: Pose) -> bool:
        """A pose farther than ARENA_SLACK outside the arena: no tracker sees a robot there (a forged pose)."""
        if self.arena is None:
            return False
        x0, y0, x1, y1 = self.arena
        return not (x0 - ARENA_SLACK <= pose.x <= x1 + ARENA_SLACK and y0 - ARENA_SLACK <= pose.y <= y1 + ARENA_SLACK)

    def take(self, pose: Pose, latest_tick: Callable[[], int | None]) -> str | None:
        """Hold a robot's pose for the next step (the newest tick wins), or say why it is refused."""
        if not stamp_agrees(pose.tick, pose.stamp, self.dt):
            return INCONSISTENT
        if self.off_arena(pose):
            return "invalid"
        latest = latest_tick()
        if latest is not None and pose.tick > latest:
            return FUTURE  # taken, it would make the honest poses until its tick look old: the robot would skip them
        if self.second_pose(pose):
            return CONFLICTING
        why = self.lines[pose.robot].admit(pose.tick, time.monotonic(), latest)
        held = self.pending.get(pose.robot)
        if why is None and (held is None or pose.tick > held.tick):
            self.pending[pose.robot] = pose
        return why

    def second_pose(self, pose: Pose) -> bool:
        """Is this a pose of a tick the robot holds or acted on, at another place? Which is the tracker's: not a
        copy of another tick's pose (a tracker measures anew each tick), else the one nearer where the robot's
        last command took it. If it is this one, held, the robot acts on it instead; acted on (or with nothing
        to judge by), the robot brakes a while."""
        held = self.pending.get(pose.robot)
        holds = held is not None and held.tick == pose.tick
        first = (held.x, held.y, held.theta) if holds and held is not None else self.acted[pose.robot].get(pose.tick)
        place = (pose.x, pose.y, pose.theta)
        if first is None or first == place:
            return False
        others = [v for t, v in self.acted[pose.robot].items() if t != pose.tick]
        copied = (first in others, place in others)
        expected = self.expected(pose.robot, pose.tick)
        trackers: bool | None  # is this one the tracker's (None: nothing to tell by)
        if copied in ((True, False), (False, True)):
            trackers = copied[0]
        else:
            trackers = None if expected is None else math.dist(place[:2], expected) < math.dist(first[:2], expected)
        if trackers and holds:
            self.pending[pose.robot] = pose
        elif trackers is not False:
            self.doubted_until[pose.robot] = pose.tick + self.doubt_ticks
        return True

    def drove(self, tick: int, velocity: list[tuple[float, float]], commands: list[Command]) -> None:
        """The robots' commands of ``tick`` and the velocities they were sent to drive at (where their next
        poses should be), in the same order."""
        for (vx, vy), command in zip(velocity, commands):
            _remember(self.sent[command.robot], tick, ((vx, vy), command))

    def doubts(self, pose: Pose) -> bool:
        """Does the robot doubt its poses at this pose's tick?"""
        return pose.tick < self.doubted_until.get(pose.robot, -1)

    def expected(self, robot: int, tick: int) -> tuple[float, float] | None:
        """Where the robot's last command, from its last pose acted on before ``tick``, took it by ``tick``."""
        last = max((t for t in self.sent[robot] if t < tick and t in self.acted[robot]), default=None)
        if last is None:
            return None
        (x, y, _), ((vx, vy), _) = self.acted[robot][last], self.sent[robot][last]
        return x + vx * (tick - last) * self.dt, y + vy * (tick - last) * self.dt

    def judged(self, poses: list[Pose]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each robot's position and heading to drive on, and whether it brakes on its last trusted pose."""
        for q in poses:
            _remember(self.acted[q.robot], q.tick, (q.x, q.y, q.theta))
        judged = [self.trust.judge(q.robot, q.tick, q.x, q.y, q.theta) for q in poses]
        pose_of = np.array([j if j is not None else self.trust.last(q.robot) for q, j in zip(poses, judged)], float)
        doubted = [self.doubts(q) for q in poses]
        braking = np.array([j is None or d for j, d in zip(judged, doubted)], bool)
        return pose_of[:, :2].copy(), pose_of[:, 2].copy(), braking


def _remember(kept: dict[int, Any], tick: int, value: Any) -> None:
    """A robot's ``value`` of ``tick`` kept, with those of its POSES_KEPT newest ticks only."""
    kept[tick] = value
    if len(kept) > POSES_KEPT:
        del kept[min(kept)]


@dataclass
class GoalSetsHeard:
    """The goal sets a host took up, by epoch, the newest epoch heard, and the first its robots may bid in."""

    believed: GoalSets
    by_epoch: dict[int, Goals] = field(default_factory=dict)
    newest_heard: int = 0
    bid_from: int = 0
    # refused as from the future, heard again once the clock has gone on: a host back from a stall knows an old
    # display time, and the coordinator repeats only its newest set, so one it missed would name no tick for it
    early: list[Goals] = field(default_factory=list)


class Departures:
    """Robots whose agent died: their bodies stand still (5.1.2). Who lock-step rounds wait for: a goal set that
    lists its robots' lives (transport.codec.Lives) says, the same for every host; of one that lists none, not
    those ``gone`` during it (they cannot rejoin its auction until the next)."""

    def __init__(self, alive: LivelinessWatch) -> None:
        self.alive = alive
        self.dead: set[int] = set()
        self.life: dict[int, int] = {}  # each live robot's agent's life, as heard
        self.gone: set[int] = set()
        self.gone_since = 0  # the goal set ``gone`` is of
        self.listed: dict[int, int] | None = None  # that goal set's robots' lives (None: it lists none)
        self._other_life: set[int] | None = None  # those listed robots heard in another life (None: to renew)

    def now(self) -> set[int]:
        """The robots whose agent is dead, as liveliness says now."""
        for _, ident, alive, _, incarnation in self.alive.drain():
            if ident.isdigit():
                robot, self._other_life = int(ident), None
                (self.dead.discard if alive else self.dead.add)(robot)
                if alive:
                    self.life[robot] = life_number(incarnation)
                else:
                    self.life.pop(robot, None)
                    self.gone.add(robot)
        return self.dead

    def not_bidding(self) -> set[int]:
        """The robots the auction does not wait for: dead, or in another life than the goal set in force lists
        (one that lists none: gone during it)."""
        dead = self.now()
        if self.listed is None:
            return dead | self.gone
        if self._other_life is None:  # rounds ask often: renewed only when liveliness or the set changed
            self._other_life = {r for r, life in self.listed.items() if life and self.life.get(r, life) != life}
        return dead | self._other_life

    def new_goal_set(self, goals: Goals) -> None:
        if goals.epoch != self.gone_since:  # a new goal set (the coordinator repeats the newest)
            # liveliness taken in first: an agent back before the set came is no departure from it
            self.gone, self.gone_since = set(self.now()), goals.epoch
            self.listed, self._other_life = goals.listed_lives(), None


@dataclass
class TickCounts:
    """How far a host has run: for its statistics, and its start-up (hellos until the first tick)."""

    ticks: int = 0  # ticks stepped
    fallbacks: int = 0  # robot-ticks whose program was infeasible (the fallback ran)


class SubscriptionRenewal:
    """After the router link came back: the subscriptions declared again (Bus.renew_if_due), and again each
    ``renew_delay`` until a pose comes."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.deaf_since: float | None = None  # when the subscriptions were last renewed and no pose came since

    def keep(self) -> None:
        now = time.monotonic()
        if self.bus.renew_if_due():
            self.deaf_since = now
        elif self.deaf_since is not None and now - self.deaf_since >= self.bus.renew_delay:
            self.bus.renew()
            self.deaf_since = now

    def pose_came(self) -> None:
        self.deaf_since = None


class AgentHost:
    """K robots in one process, each deciding for itself from its own messages."""

    def __init__(self, bus: Bus, config: HostConfig) -> None:
        self.bus, self.config = bus, config
        p = config.params
        self.robots = OwnRobots(config.robots)
        self.table = NeighbourTable(p.dt)
        self.counts = TickCounts()
        # rows: the own robots in id order; until a neighbour is heard, its states may be as old as stale_after
        self.policy_memory = Memory.new(len(self.robots), latency=p.stale_after)
        self.held_goals = HeldGoals.new(len(self.robots))  # rows as policy_memory's
        self.inbox = Inboxes.of(bus, config, self.robots.ids)
        self.goal_sets = GoalSetsHeard(GoalSets(config.arena))
        self.clock: HostClock = LockStep(self) if config.lockstep else WallClock(self)
        self.poses = PoseIntake(config, self.clock.pose_period)
        if math.isfinite(config.reach) and not config.lockstep:
            raise ValueError("a communication range needs the lock-step clock")
        rounds = LockStepRounds(self._hold, self.inbox.departed.not_bidding, config.reach, self.round_moot)
        self.auction = AuctionLink(
            bus, config.robots, p, self._on_agreed, self._positions, rounds if config.lockstep else None
        )
        self.running = True
        self._renewal = SubscriptionRenewal(bus)
        segments = static_segments(config.arena, config.obstacles)
        self.seams = loop.Seams(self, self.auction, segments, config.seed, config.reach)

    @property
    def params(self) -> RobotParams:
        return self.config.params

    def start(self, timeout: float = 60.0) -> bool:
        """Fetch the goal set, learn where the robots are and subscribe to their cells, then announce them alive."""
        for _, goals in self.bus.query(self.bus.keys.all_of("goals"), Goals, timeout=2.0):
            self.hear_goals(goals)
        where: dict[int, Pose] = {}
        ticking: list[Pose] = []  # poses of ticks under way (a robot whose body is tracked already)
        end = time.monotonic() + timeout
        while len(where) < len(self.robots) and self.running and time.monotonic() < end:
            self._renewal.keep()
            got = self.inbox.pose.get(timeout=0.2)
            if got is not None and self.poses.off_arena(got[1]):
                self.inbox.pose.drops["invalid"] += 1
            elif got is not None:
                self._renewal.pose_came()
                where[got[1].robot] = got[1]
                if got[1].tick != BEFORE_START:
                    ticking.append(got[1])
        if len(where) < len(self.robots):
            return False
        self.inbox.cells.update(np.array([(q.x, q.y) for q in where.values()]))
        believed = self.goal_sets.believed
        if believed.newest is None and max(q.stamp for q in where.values()) <= 0.0:
            believed.newest = 0  # nothing to fetch at the run's start: its epochs count from 1
        self.clock.greet(where, timeout)
        for q in ticking:
            self._take_pose(q)
        self.bus.declare_alive("agent", robots_ident(self.config.robots))
        return True

    def publish_states(self, tick: int, stamp: float, states: list[State]) -> None:
        """A host's frame of its robots' states; a robot alone its frame of one under its cell (HostConfig.frames)."""
        first = int(self.robots.ids[0]) if self.config.frames else None
        self.bus.publish_states(tick, stamp, states, self.params.cell_size, first)

    def hear_goals(self, goals: Goals) -> None:
        """A goal set heard (lock-step holds it until its tick: HostClock.holds). One whose epoch or stamp lies
        beyond what the robots know is refused: taken as the newest, it would shut out the coordinator's."""
        why = self._believe(goals)
        if why is not None:
            self.inbox.goals.drops[why] += 1

    def hear_early_goals(self) -> None:
        """The goal sets refused as from the future, heard again (once the clock has gone on); counted once."""
        early, self.goal_sets.early = self.goal_sets.early, []
        for goals in early:
            self._believe(goals)

    def _believe(self, goals: Goals) -> str | None:
        """Take a goal set in, or say why not (one from the future is kept to be heard again)."""
        now = self.clock.display_time()  # the newest display time known: the lock-step clock, else the newest pose
        if now is None:
            now = max((m.stamp for m in self.robots.known()), default=None)
        why = self.goal_sets.believed.admit(goals, now)
        if why == FUTURE and all(goals.epoch != g.epoch for g in self.goal_sets.early):
            self.goal_sets.early = [*self.goal_sets.early, goals][-GoalSets.KEPT :]
        if why is None:
            self.goal_sets.newest_heard = max(self.goal_sets.newest_heard, goals.epoch)
            if not self.clock.holds(goals):
                self.on_goals(goals)
        return why

    def on_goals(self, goals: Goals) -> None:
        if not goals.per_robot:
            self.robots.bid_from = None
            self.goal_sets.by_epoch[goals.epoch] = goals
            if not self._takes_part(goals):
                return  # its auction began before this agent joined: the robots wait for the next
            self.inbox.departed.new_goal_set(goals)
            for old in sorted(self.goal_sets.by_epoch)[:-GOAL_SETS_KEPT]:
                del self.goal_sets.by_epoch[old]
            # a keyframe names its predecessor; an image follows the last
            follows = goals.correspondence.follows if goals.correspondence else self.auction.epoch
            key = self.held_goals.key
            driving = {
                r: int(key[b, 1]) for r, b in self.robots.row_of.items() if key[b, 1] >= 0 and key[b, 0] == follows
            }  # agreed or itself carried
            carried = self.auction.on_goals(goals, self._positions(), driving)
            # the next keyframe or image: drive on at once (6.2), the auction follows
            self._on_agreed(goals.epoch, State.CARRIED, carried, goals.positions, goals.colors)
            # not in this goal set (e.g. it joined late): it waits; a pursuer's goal comes from its target (on_state)
            self.held_goals.idle(self.robots.rows(r for r in self.auction.idle_robots() if r not in self.config.pursue))
            return
        own = [r for r in self.robots.ids.tolist() if r < len(goals.positions)]
        self.held_goals.color[self.robots.rows(own)] = goals.colors[own]
        sent = [r for r in own if r not in self.config.pursue]  # a pursuer's goal comes from its target's broadcasts
        self.held_goals.goal[self.robots.rows(sent)] = goals.positions[sent]

    def _takes_part(self, goals: Goals) -> bool:
        """Whether our robots bid in this set's auction: it lists them in this life (an agent started again waits
        for the set that does); a set that lists no lives, if published after this agent joined."""
        listed = goals.listed_lives()
        if listed is None:
            return goals.epoch >= self.goal_sets.bid_from
        return all(listed.get(r, 0) in (0, life_number(self.bus.incarnation)) for r in self.robots.ids.tolist())

    @property
    def timing(self) -> dict[int, GoalTiming]:
        return {epoch: timing_of(gs) for epoch, gs in self.goal_sets.by_epoch.items()}

    def _positions(self) -> dict[int, np.ndarray]:
        """The own robots' positions as the auction takes them (cached): for a moving goal set (7.4.1) mapped back
        through eq. 28, for a robot on its way to a goal where it will be when the instance is adopted."""
        if self.robots.bid_from is not None:
            return self.robots.bid_from
        by_epoch = self.goal_sets.by_epoch
        newest = by_epoch[max(by_epoch)] if by_epoch else None
        motion = motion_of(newest) if newest is not None else None
        out, on_way, key = {}, [], self.held_goals.key
        for m in self.robots.tracked.values():
            if m.position is None:
                continue
            b = self.robots.row_of[m.robot]
            if motion is not None and newest is not None:
                out[m.robot] = motion.to_initial_frame(m.position, m.stamp - newest.timing.t_start)
            elif newest is not None and key[b, 0] == newest.epoch and key[b, 1] >= 0:
                on_way.append(m)  # on its way: where it will be
            else:
                out[m.robot] = m.position
        if on_way:
            rows = self.robots.rows(m.robot for m in on_way)
            goal, velocity = self.held_goals.goal[rows], self.policy_memory.velocity[rows]
            lead = bid_position(np.array([m.position for m in on_way]), goal, velocity, self.auction.times.latency)
            out.update(zip([m.robot for m in on_way], lead))
            out = {r: out[r] for r in self.robots.tracked if r in out}  # back in the robots' order
        self.robots.bid_from = out
        return out

    def _on_agreed(
        self, epoch: int, instance: int, goals: dict[int, int], positions: np.ndarray, colors: np.ndarray
    ) -> None:
        """An auction instance is agreed: each own robot drives to its goal and lights its colour."""
        self.robots.bid_from = None
        index = np.fromiter(goals.values(), np.int64, len(goals))
        self.held_goals.drive_to(self.robots.rows(goals), epoch, instance, index, positions, colors)

    def _hold(self, robots: list[int]) -> None:
        """These robots' auction block was abandoned: they hold (another may have been agreed their goals). Unless
        a goal set that begins every host's auction again is on its way, the coordinator hears of it: the hosts'
        blocks may have parted for good (one gave up a block that others finished), and a new set joins them."""
        self.robots.bid_from = None
        self.held_goals.hold(self.robots.rows(robots))
        epoch = self.auction.epoch
        if not self.clock.begins_again_after(epoch):
            said = Event({"kind": BLOCK_ABANDONED, "epoch": epoch, "robots": sorted(robots)})
            self.bus.publish(self.bus.keys.stats(int(self.robots.ids.min())), said)

    def round_moot(self, epoch: int) -> bool:
        """Lock-step: a round of ``epoch`` is not worth waiting for any more: a goal set after it is held that begins
        every host's auction again, at the tick that names it (a host stalled, or one gave a block up)."""
        for _, goals in self.inbox.goals.drain():  # held, not taken up: the round goes on as it was
            self.hear_goals(goals)
        return self.clock.begins_again_after(epoch)

    def on_state(self, msg: State) -> None:
        if msg.tick == BEFORE_START:  # a hello (lock-step start-up), not a state to steer by
            self.clock.hear_hello(msg)
            return
        if not self.config.hears_itself and msg.robot in self.robots:
            # the body node's standing body of our robot alone: kept, it would make a lock-step tick wait
            # for our state of the last tick, which never comes, as for a neighbour's
            return
        why = self.table.update(msg)
        if why is not None:
            self.inbox.state.drops[why] += 1
            return
        self.clock.silent.discard(msg.robot)
        for robot, target in self.config.pursue.items():
            if msg.robot == target and robot in self.robots:
                self.held_goals.goal[self.robots.row_of[robot]] = msg.x, msg.y

    def run(self, parent_pid: int | None = None) -> None:
        """Step every tick until stopped, or (``parent_pid``) until that process, the launcher, is gone."""
        bell = self.auction.inbox.bell = self.inbox.bell
        while self.running:
            bell.clear()
            self._renewal.keep()
            got = self.inbox.pose.get(timeout=0)
            if self.auction.active or self.inbox.goals.has_delayed:
                for _, msg in self.inbox.goals.drain():
                    self.hear_goals(msg)
                self.auction.poll(self._positions())
            if got is None:
                if not self.counts.ticks:
                    self.clock.say_hello()  # until the first tick: a neighbour may still wait for it
                if parent_pid is not None and os.getppid() != parent_pid:
                    self.running = False  # orphaned: the launcher died without stopping us
                bell.wait(self._idle_wait())
                continue
            tick_start = time.monotonic()
            self._renewal.pose_came()
            self._take_pose(got[1])
            # Behind (poses of later ticks queued): act on the newest only (docs/overload.md, rule 2).
            for _, pose in self.inbox.pose.drain():
                self._take_pose(pose)
            self.clock.poses_arrived(list(self.poses.pending.values()), tick_start)
            # the rest of this tick's poses (a loaded machine can split a frame): lock-step waits for all of them
            deadline = tick_start + self.clock.collect
            while len(self.poses.pending) < len(self.robots) and self.running:
                got = self.inbox.pose.get(timeout=max(0.0, deadline - time.monotonic()))
                if got is None:
                    break
                self._take_pose(got[1])
            self.step()
            self._auction_rounds(bell, tick_start)

    def _idle_wait(self) -> float:
        """How long the loop may sleep with no pose: until an auction round or a hello is due."""
        wait = min(0.2, self.auction.next_due()) if self.auction.active else 0.2
        if not self.counts.ticks:
            wait = min(wait, self.clock.hello_every)
        if self.inbox.pose.has_delayed:
            wait = min(wait, 0.005)
        return wait

    def _auction_rounds(self, bell: threading.Event, tick_start: float) -> None:
        """Real time: trade auction messages for a share of the period, never making the next command late."""
        link = self.auction
        share = AUCTION_SHARE_COLD if link.cold else AUCTION_SHARE
        end = tick_start + share * self.params.dt
        while link.busy and self.running:
            bell.clear()
            link.poll(self._positions())
            now = time.monotonic()
            if now >= end:
                return
            bell.wait(min(end - now, link.next_due()))

    def _take_pose(self, pose: Pose) -> None:
        if pose.robot not in self.robots or pose.tick == BEFORE_START:
            return
        why = self.poses.take(pose, self.clock.latest_pose_tick)  # lock-step: the world's clock says which tick it is
        if why is not None:
            self.inbox.pose.drops[why] += 1
        if why == CONFLICTING and pose.tick in self.poses.acted[pose.robot]:
            self._answer_again(pose)

    def _answer_again(self, pose: Pose) -> None:
        """A second pose of a tick the robot acted on: its command of that tick again, or (the robot doubts its
        first pose) taken back, braking. The body node may have refused the first, sent before that tick went
        out (on a forged clock): the robot then answers the tick. If it took it, a copy is no news, and a
        braking command, a second of one tick, stops the robot there."""
        if pose.tick not in self.poses.sent[pose.robot]:
            return
        _, sent = self.poses.sent[pose.robot][pose.tick]
        if self.poses.doubts(pose):
            sent = replace(sent, a=0.0, b=0.0)
        self.bus.publish_frame(Commands, pose.tick, pose.stamp, [sent], self._command_key(pose.robot))

    def _command_key(self, robot: int) -> str:
        """Where a robot's commands go: its host's frame, keyed by its first robot, or (a robot alone) its own."""
        return self.bus.keys.cmd(int(self.robots.ids.min()) if self.config.frames else robot)

    def step(self) -> None:
        """Compute and publish one tick for every robot whose pose has arrived."""
        pending = self.poses.pending
        if not pending:
            return
        self.clock.before_step(list(pending.values()))
        self.table.advance(max(p.tick for p in pending.values()))
        for _, goals in self.inbox.goals.drain():  # what arrived meanwhile
            self.hear_goals(goals)
        for state in self.inbox.state.take():
            self.on_state(state)
        self.auction.poll(self._positions())
        poses = [pending.pop(r) for r in sorted(pending)]
        for tick in sorted({p.tick for p in poses}):  # a host's robots may hold poses of different ticks
            self._step_tick([p for p in poses if p.tick == tick])

    def _step_tick(self, poses: list[Pose]) -> None:
        """The one tick loop (agent.loop.tick) for the robots whose pose of one tick arrived."""
        began = time.monotonic()
        tick, stamp = poses[0].tick, poses[0].stamp
        p = self.clock.params_at(stamp, began)
        position, heading, braking = self.poses.judged(poses)
        self.clock.await_neighbours(tick, position)
        for q, xy in zip(poses, position):
            self.robots.tracked[q.robot].position, self.robots.tracked[q.robot].stamp = xy.copy(), stamp
        self.robots.bid_from = None
        self.clock.take_up_goal_sets(tick, stamp)
        self.inbox.departed.now()
        sensed = Sensed(np.array([q.robot for q in poses]), position, heading, tick, stamp, p, braking)
        decision = loop.tick(self, sensed, self.seams)
        self.counts.fallbacks += int(np.count_nonzero(decision.step.fallback))
        self.counts.ticks += 1
        self.clock.stepped(began)

    def rows(self, ids: np.ndarray) -> np.ndarray:
        return self.robots.rows(ids.tolist())

    def goals(self, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's goal as its goal set was published and its key (epoch, goal index)."""
        return self.held_goals.targets(self.rows(sensed.ids))

    def neighbours(self, sensed: Sensed) -> NeighbourStates:
        p = sensed.params
        # a dead robot may have moved one period after its last state
        stopped = {r: p.v_max * p.dt for r in self.inbox.departed.dead}
        heard_within = min(p.neighbour_dist, self.config.reach)  # a robot hears states only within its range
        return self.table.gather(sensed, heard_within, stopped, self.inbox.bodies.at(sensed.tick))

    def send(self, sensed: Sensed, decision: Decision) -> None:
        """Each robot's state and command on the bus, then the cells around the robots."""
        p, tick, stamp, position = sensed.params, sensed.tick, sensed.stamp, sensed.position
        rows, held = self.rows(sensed.ids), self.held_goals
        moved = held.has_goal(rows)  # a moving goal set's goal moved (eq. 28): where it is now
        held.goal[rows[moved]] = decision.intent.goal[moved]
        mode = Command.WHEELS if p.kinematics == DIFFDRIVE else Command.HOLONOMIC
        states, commands, velocity = [], [], []
        # robot by robot in Python: a robot alone's rows are one, where numpy's calls would cost more than the sums
        columns = (sensed.ids, position, decision.step.velocity, decision.step.command, sensed.braking)
        held_columns = (held.goal[rows], held.key[rows], held.instance[rows], held.color[rows])
        for (robot, (x, y), v, c, braking), ((gx, gy), (epoch, index), instance, color) in zip(
            zip(*(a.tolist() for a in columns)), zip(*(a.tolist() for a in held_columns))
        ):
            (vx, vy), (cx, cy) = ((0.0, 0.0), (0.0, 0.0)) if braking else (v, c)
            flags = 0
            if math.isfinite(gx) and math.isfinite(gy):
                flags = State.HAS_GOAL | (State.AT_GOAL if math.hypot(gx - x, gy - y) <= p.goal_tolerance else 0)
            else:
                gx = gy = 0.0
            states.append(State(robot, tick, stamp, x, y, vx, vy, p.radius, gx, gy, index, flags, epoch, instance))
            commands.append(Command(robot, tick, stamp, mode, cx, cy, *color))
            velocity.append((vx, vy))
        self.poses.drove(tick, velocity, commands)
        # States before commands: by the time the world moves on, neighbours have our states.
        self.publish_states(tick, stamp, states)
        # a host's frame of its robots' commands, as its token names them; a robot alone its frame of one
        to = (
            self._command_key(int(self.robots.ids.min()))
            if self.config.frames
            else lambda c: self._command_key(c.robot)
        )
        self.bus.publish_frame(Commands, tick, stamp, commands, to)
        # the cells around EVERY own robot, not only this batch: a tick's poses can arrive split (forget_outside)
        around = np.array([m.position for m in self.robots.known()])
        self.inbox.cells.update(around)
        dead = self.inbox.departed.dead
        self.table.forget_outside(self.inbox.cells.cells, self.params.cell_size, keep=dead)
        reach = partial(touch_reach, settings_of(p), p.radius)
        self.table.forget_silent(stamp, p.forget_after, around.reshape(-1, 2), reach, keep=dead)
        self.robots.bid_from = None  # the robots' velocities changed: they move where they bid from

    def stats(self) -> dict[str, Any]:
        drops: Counter[str] = Counter()
        inboxes: list[Any] = [self.inbox.pose, self.inbox.state, self.inbox.goals, self.auction.inbox, self.clock.inbox]
        for inbox in filter(None, inboxes):
            drops.update(inbox.drops)
        return {
            "role": "agent",
            "robots": self.config.robots,
            "ticks": self.counts.ticks,
            "fallbacks": self.counts.fallbacks,
            "subscriptions_renewed": self.bus.renewals,
            "poses_held": self.poses.trust.held,
            "dropped": drops,
            "neighbours_known": len(self.table),
            "state_waits": self.clock.state_waits,
            "states_heard": self.inbox.state.received,  # messages (frames): its robots' neighbours' load
            "worst_lateness_s": round(self.clock.lateness.worst, 4),
            "mean_lateness_s": round(self.clock.lateness.mean, 4),
            "silent": sorted(self.clock.silent),
            "lockstep_gave_up": self.clock.gave_up,
            "auction": self.auction.stats(),
        }

    def report(self) -> None:
        self.bus.publish(self.bus.keys.stats(int(self.robots.ids.min())), Event({"kind": "stats", **self.stats()}))


def bid_position(position: np.ndarray, goal: np.ndarray, velocity: np.ndarray, lead: float) -> np.ndarray:
    """Where robots will be ``lead`` s on (the auction's latency): toward the goal, as far as their speed carries."""
    position = np.asarray(position, float)
    to_goal = np.asarray(goal, float) - position
    if lead <= 0:
        return position.copy()
    d = np.hypot(to_goal[..., 0], to_goal[..., 1])
    speed = np.hypot(*np.moveaxis(np.asarray(velocity, float), -1, 0))
    reach = np.minimum(1.0, speed * lead / np.maximum(d, 1e-9))
    return position + to_goal * np.where(d <= 1e-9, 0.0, reach)[..., None]


def install_stop_handlers(host: AgentHost) -> None:
    def stop(signum: int, frame: object) -> None:
        host.running = False
        host.auction.stop()
        # wake the loop now, from a thread: this handler may have interrupted the main thread inside the bell's lock
        threading.Thread(target=host.inbox.bell.set, daemon=True).start()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
