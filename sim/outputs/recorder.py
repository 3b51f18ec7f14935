"""The recorder: keeps what the run directory needs from the bus, measured from the world's TRUE poses
(``sim/truth``), never from what agents believed; logs every kind to MCAP. Details: docs/outputs.md."""

from __future__ import annotations

import dataclasses
import time
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson

from sim.outputs.foxglove import GOAL_SIZE, SceneUpdate, goal_markers, scene_update, swarm_scene
from sim.outputs.logschema import LoggedKind, kind_of
from sim.outputs.mcaplog import McapLog
from sim.outputs.rundir import json_safe
from sim.outputs.stream import ROWS
from sim.outputs.ticklog import TickLog
from sim.outputs.write import goal_set_arrays
from transport.bus import Bus
from transport.codec import (
    BEFORE_START,
    BY_NAME,
    AuctionRecord,
    Bid,
    Commands,
    Contact,
    DropCounter,
    Event,
    Goals,
    State,
    States,
    Truth,
    decode,
)
from transport.plausible import AHEAD, GoalSets, stamp_agrees

SCENE_TOPIC = "/display/scene"  # what Foxglove's 3D panel shows: robots in their LED colours, and goals
GOALS_TOPIC = "/display/goals"  # above LOG_ROBOTS: the goal sets, apart from the robots

# the most robots whose every tick is logged: a larger swarm's every ceil(N / LOG_ROBOTS)-th, so the log grows no faster
LOG_ROBOTS = 1000
# s of display time between scene messages above LOG_ROBOTS robots; none while nothing moved or changed colour
SCENE_PERIOD = 1.0

FLUSH_EVERY = 1.0  # s of wall time between flushes of the MCAP log (a killed run keeps all but the last)

_JSON_TYPES = {int: "integer", float: "number", str: "string", dict: "object"}


def json_schema_of(message_type: type) -> dict[str, Any]:
    """A JSON schema for a message dataclass (arrays become arrays of numbers)."""
    hints = typing.get_type_hints(message_type)
    props: dict[str, dict[str, Any]] = {}
    for f in dataclasses.fields(message_type):
        hint = hints.get(f.name)
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        if hint in _JSON_TYPES:
            props[f.name] = {"type": _JSON_TYPES[hint]}
        elif getattr(getattr(default, "dtype", None), "names", None) or f.name == "records":
            props[f.name] = {"type": "object"}  # records of several fields: one array per field (Bid, frames)
        elif any(dataclasses.is_dataclass(t) for t in (hint, *typing.get_args(hint))):
            props[f.name] = {"type": ["object", "null"]}  # a goal set's part (absent: null)
        else:
            props[f.name] = {"type": "array"}
    return {"type": "object", "title": message_type.__name__, "properties": props}


def display_converged(
    pose: np.ndarray,
    goal: np.ndarray,
    assign_epoch: np.ndarray,
    alive: np.ndarray,
    newest: Goals | None,
    tolerance: float,
) -> bool:
    """Every live robot within ``tolerance`` of its goal, agreed on the newest goal set, which holds no
    dead robot (paper 5.1.2)."""
    err = np.hypot(*(pose[alive, :2] - goal[alive]).T)
    if not (np.all(np.isfinite(err)) and np.all(err <= tolerance)):
        return False
    if newest is None:
        return True
    members = newest.robots[newest.robots < len(alive)]
    return bool(np.all(assign_epoch[alive] == newest.epoch) and np.all(alive[members]))


@dataclass
class Trajectory:
    """Per-tick arrays, grown as truth messages arrive."""

    t: list[float] = field(default_factory=list)
    pose: list[np.ndarray] = field(default_factory=list)
    velocity: list[np.ndarray] = field(default_factory=list)
    color: list[np.ndarray] = field(default_factory=list)
    goal: list[np.ndarray] = field(default_factory=list)
    assignment: list[np.ndarray] = field(default_factory=list)
    assignment_epoch: list[np.ndarray] = field(default_factory=list)
    assignment_instance: list[np.ndarray] = field(default_factory=list)
    step: list[int] = field(default_factory=list)
    goal_set_epoch: list[int] = field(default_factory=list)
    wall: list[float] = field(default_factory=list)  # wall time each tick arrived (real-time factor)


RECORD_AHEAD = 25 * AHEAD  # ticks a state may come before the world's truth of its tick reaches the recorder


@dataclass
class RobotsSaid:
    """What each robot said in its newest state (goal NaN: none; radius NaN until it says); a tick
    records a copy of these."""

    goal: np.ndarray
    goal_index: np.ndarray
    assign_epoch: np.ndarray
    assign_instance: np.ndarray
    radius: np.ndarray
    state_tick: np.ndarray

    @classmethod
    def nothing_yet(cls, robots: int) -> RobotsSaid:
        return cls(
            goal=np.full((robots, 2), np.nan),
            goal_index=np.full(robots, -1),
            assign_epoch=np.zeros(robots, np.int64),
            assign_instance=np.zeros(robots, np.int64),
            radius=np.full(robots, np.nan),
            state_tick=np.full(robots, np.iinfo(np.int64).min),
        )

    def size_once(self, robot: int, radius: float) -> None:
        """A robot's size from a state that says nothing else yet (a hello, or one before its tick's truth)."""
        if np.isnan(self.radius[robot]):
            self.radius[robot] = radius


@dataclass
class GoalSetsHeard:
    """The goal sets as the swarm believed them (judged as robots judge them, so a faulty peer's copies
    are not measured): every epoch's, the newest and the scene step it shows."""

    believed: GoalSets = field(default_factory=lambda: GoalSets(newest=0))  # it starts with the run
    by_epoch: dict[int, Goals] = field(default_factory=dict)
    newest: Goals | None = None  # the goal set of the highest epoch
    step: int = 0  # the scene step of the newest goal set


class BidsFrom:
    """Where each robot bid from in each auction instance, and its C_d in force: its newest claim's x, y
    and penalty, float32 as records carry them (NaN: no claim heard). An array per instance: a host
    repeats its robots' claims every round, and a run of 1000 robots agrees about once a tick."""

    def __init__(self, robots: int) -> None:
        self.robots = robots
        self.by_instance: dict[tuple[int, int], np.ndarray] = {}  # (epoch, instance) -> (robots, 3)

    def claimed(self, key: tuple[int, int], claims: np.ndarray) -> None:
        """These claims (records of this run's robots) heard for that instance; a robot's latest stands."""
        rows = self.by_instance.get(key)
        if rows is None:
            rows = self.by_instance[key] = np.full((self.robots, 3), np.nan, np.float32)
        rows[claims["robot"]] = np.column_stack([claims["x"], claims["y"], claims["penalty"]])

    def of(self, key: tuple[int, int]) -> np.ndarray:
        """(robots, 3): x, y, penalty per robot in that instance."""
        return self.by_instance.get(key, np.full((self.robots, 3), np.nan, np.float32))


@dataclass
class WorldHeard:
    """What the world's truth told beside the trajectory: newest tick, control period, rows, least clearance."""

    latest_tick: int = -1
    dt: float = 0.0
    row_of_tick: dict[int, int] = field(default_factory=dict)
    least_clearance: float = np.inf
    # states heard before their tick's truth, the first per (tick, robot): the world sends a tick's truth
    # before its poses, so a robot's own state of that tick comes after it and is taken before these
    early: dict[tuple[int, int], State] = field(default_factory=dict)


@dataclass
class BusTally:
    """What crossed the bus: messages and bytes per kind, commands (by record) and undecodable drops."""

    counts: dict[str, int] = field(default_factory=dict)
    bytes: dict[str, int] = field(default_factory=dict)
    commands: int = 0
    drops: DropCounter = field(default_factory=DropCounter)


@dataclass
class RunEvents:
    """What happened beside the ticks: contacts, the run's events, processes coming alive or going."""

    contacts: list[Contact] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    liveliness: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class Convergence:
    """Whether and since when the display has converged over the live agents, and the run's end
    (``ends``: converged since, now -> end here)."""

    tolerance: float
    agent_alive: np.ndarray
    converged_since: float | None = None
    ends: Callable[[float, float], bool] | None = None
    ended_at: int | None = None  # ticks recorded when it ended (none recorded after)

    def end_reason(self, world_reason: str) -> str:
        """The run's end as recorded: a recorder behind the world still ends at the converged tick."""
        return "converged" if world_reason == "duration" and self.ended_at is not None else world_reason

    def check(self, t: float, pose: np.ndarray, said: RobotsSaid, newest: Goals | None) -> None:
        """Converged: every live robot has a goal and is within tolerance of it (true position)."""
        if not self.agent_alive.any():
            return
        if not display_converged(pose, said.goal, said.assign_epoch, self.agent_alive, newest, self.tolerance):
            self.converged_since = None
        elif self.converged_since is None:
            self.converged_since = t


class DisplayLog:
    """The run's logs, written as it goes: each kind on its MCAP channel, Foxglove scenes, the tick log."""

    def __init__(self, robots: int, log_path: str | None, ticks_path: str | None) -> None:
        self.n = robots
        self.log = McapLog(log_path) if log_path else None
        self.ticks = TickLog(ticks_path, robots) if ticks_path else None
        self._flushed = time.monotonic()
        self._channels: dict[str, int] = {}
        self.every = max(1, -(-robots // LOG_ROBOTS))  # ticks
        self.heading = True  # a heading arrow per robot in the scene: not for holonomic robots, which never turn
        self._next_scene = -np.inf  # display time of the next scene message (above LOG_ROBOTS)
        self._last_scene: bytes = b""  # the swarm's last scene message, but for its time
        self._last_goals: tuple[str, bytes] | None = None  # the goal set logged last: its key and payload

    def repeats(self, kind: str, key: str, payload: bytes) -> bool:
        """A goal set republished unchanged (for late joiners): logged once, or it would fill the log."""
        if kind != "goals":
            return False
        same = self._last_goals == (key, payload)
        self._last_goals = (key, payload)
        return same

    def json(self, kind: str, wall: float, payload: dict[str, Any]) -> None:
        """One message on its kind's channel, as JSON (orjson: numpy arrays as lists, NaN and inf as null)."""
        if (log := self.log) is None:
            return

        def add() -> int:
            cls = BY_NAME.get(kind)
            name, schema = (cls.__name__, json_schema_of(cls)) if cls else (kind, {"type": "object"})
            return log.add_channel("/" + kind, f"pixelswarm.{name}", schema)

        # what orjson leaves to json_safe: numpy arrays that are views with strides (e.g. a column of records)
        payload_bytes = orjson.dumps(payload, default=json_safe, option=orjson.OPT_SERIALIZE_NUMPY)
        log.write_bytes(self._channel(kind, add), int(wall * 1e9), payload_bytes)

    def proto(self, kind: str, wall: float, as_proto: LoggedKind, msg: Any, key: str, tick: int) -> None:
        """A per-tick kind in its protobuf form (sim.outputs.logschema), at a logged ``tick``."""
        if (log := self.log) is None or tick % self.every:
            return
        cid = self._channel(kind, lambda: log.add_protobuf_channel("/" + kind, as_proto.name, as_proto.descriptor_set))
        log.write_bytes(cid, int(wall * 1e9), as_proto.encode(msg, key))

    def _channel(self, kind: str, add: Callable[[], int]) -> int:
        """The log's channel of ``kind`` (a key kind or a scene topic), ``add``ed at its first message."""
        cid = self._channels.get(kind)
        if cid is None:
            cid = self._channels[kind] = add()
        return cid

    def scene(self, wall: float, m: Truth, radius: np.ndarray, goal: np.ndarray) -> None:
        """The display for Foxglove's 3D panel, at wall time (panels play in step): an entity a robot, or
        above :data:`LOG_ROBOTS` the swarm's one entity every :data:`SCENE_PERIOD`."""
        if (log := self.log) is None:
            return
        t_ns = int(wall * 1e9)
        channel = self._channel(SCENE_TOPIC, lambda: log.add_foxglove_channel(SCENE_TOPIC, SceneUpdate))
        if self.n <= LOG_ROBOTS:
            log.write_bytes(channel, t_ns, scene_update(t_ns, m.pose, radius, m.color, goal=goal, heading=self.heading))
            return
        if m.stamp < self._next_scene - 1e-9:
            return
        self._next_scene = (np.floor(m.stamp / SCENE_PERIOD + 1e-9) + 1) * SCENE_PERIOD
        unstamped = swarm_scene(0, m.pose, radius, m.color)
        if unstamped == self._last_scene:
            return  # nothing moved: the newest message still shows it
        self._last_scene = unstamped
        log.write_bytes(channel, t_ns, swarm_scene(t_ns, m.pose, radius, m.color))

    def goals(self, wall: float, g: Goals, radius: np.ndarray) -> None:
        """A large swarm's goal set as spheres in its colours (:func:`goal_markers`): once a set."""
        if (log := self.log) is None or self.n <= LOG_ROBOTS:
            return
        known = radius[np.isfinite(radius)]
        r = float(np.median(known)) if len(known) else 0.05  # before any state: a typical robot's
        t_ns = int(wall * 1e9)
        channel = self._channel(GOALS_TOPIC, lambda: log.add_foxglove_channel(GOALS_TOPIC, SceneUpdate))
        log.write_bytes(channel, t_ns, goal_markers(t_ns, g.positions, g.colors, GOAL_SIZE * 2 * r))

    def flush_now_and_then(self) -> None:
        """Flush the MCAP log every :data:`FLUSH_EVERY` of wall time."""
        if self.log is not None and time.monotonic() - self._flushed >= FLUSH_EVERY:
            self.log.flush()
            self._flushed = time.monotonic()

    def close(self) -> None:
        if self.log is not None:
            self.log.close()
        if self.ticks is not None:
            self.ticks.close()


class Recorder:
    """The run's record from the bus, in parts with one job each; the launcher reads the parts."""

    def __init__(
        self, bus: Bus, robots: int, tolerance: float, log_path: str | None = None, ticks_path: str | None = None
    ) -> None:
        self.bus, self.n = bus, robots
        self.raw = bus.subscribe_raw(bus.keys.everything)
        self.alive = bus.watch_alive()
        self.traj = Trajectory()
        self.said = RobotsSaid.nothing_yet(robots)  # as each robot announces it in its state
        self.sets = GoalSetsHeard()
        self.world = WorldHeard()
        self.bids_from = BidsFrom(robots)
        self.tally = BusTally()
        self.happened = RunEvents()
        self.progress = Convergence(tolerance, np.zeros(robots, bool))
        self.out = DisplayLog(robots, log_path, ticks_path)
        self.view: Any = None  # sim.outputs.view.SwarmView (pixelswarm run --view): the truth of every tick, one batch

    def poll(self) -> None:
        for role, ident, alive, wall, _ in self.alive.drain():
            self.happened.liveliness.append({"role": role, "id": ident, "alive": alive, "wall_time": wall})
            if role == "agent" and ident.isdigit() and int(ident) < self.n:
                self.progress.agent_alive[int(ident)] = alive
            self.out.json("alive", wall, {"role": role, "id": ident, "alive": alive})
        tally = self.tally
        for key, payload, wall in self.raw.drain():
            kind = self.bus.keys.kind_of(key)
            tally.counts[kind] = tally.counts.get(kind, 0) + 1
            tally.bytes[kind] = tally.bytes.get(kind, 0) + len(payload)
            expected = BY_NAME.get(kind)
            msg = decode(payload, expected, tally.drops) if expected else None
            if msg is None:
                continue
            if (as_proto := kind_of(msg)) is not None:
                self.out.proto(kind, wall, as_proto, msg, key, self.world.latest_tick)
            elif not self.out.repeats(kind, key, payload):
                self.out.json(kind, wall, msg.to_dict() | {"key": key})
            self._take(msg, wall)

    def _take(self, msg: Any, wall: float) -> None:
        """A decoded message into the part of the record it belongs to."""
        if isinstance(msg, States):
            for state in msg.messages():
                self._on_state(state)
        elif isinstance(msg, Truth):
            self._on_truth(msg, wall)
        elif isinstance(msg, Bid):
            self._on_bid(msg)
        elif isinstance(msg, Goals):
            now = self.traj.t[-1] if self.traj.t else None
            if self.sets.believed.admit(msg, now) is None and not msg.per_robot and msg.epoch not in self.sets.by_epoch:
                self._on_goals(msg, wall)
        elif isinstance(msg, Commands):
            self.tally.commands += len(msg.records)
        elif isinstance(msg, Contact):
            self.happened.contacts.append(msg)
        elif isinstance(msg, Event):
            self.happened.events.append(msg.data)

    def _on_state(self, s: State) -> None:
        """A robot's goal and assignment of tick k go into row k and the rows after it until its next
        state, as the central engine records it."""
        r, said, world = s.robot, self.said, self.world
        if r >= self.n:
            return
        if s.tick == BEFORE_START:  # a hello before the first tick: its size, no goal yet
            said.size_once(r, s.radius)
            return
        row = world.row_of_tick.get(s.tick)
        if s.tick > world.latest_tick + RECORD_AHEAD or s.tick == said.state_tick[r]:
            return  # from the future, or a copy (the first heard is the robot's)
        if s.tick > world.latest_tick:
            # a forged copy of a later tick taken now would hide the robot's states until that tick
            said.size_once(r, s.radius)
            world.early.setdefault((s.tick, r), s)
            return
        if world.dt and not stamp_agrees(s.tick, s.stamp, world.dt):
            return  # its stamp is not its tick's
        named = self.sets.by_epoch.get(s.assign_epoch)
        if named is not None and s.goal_index >= len(named.positions):
            return  # a goal its goal set does not have (a damaged field)
        goal = (s.goal_x, s.goal_y) if s.flags & State.HAS_GOAL else (np.nan, np.nan)
        told = (goal, s.goal_index, s.assign_epoch, s.assign_instance)
        newest = s.tick > said.state_tick[r]
        if newest:
            said.radius[r] = s.radius
            said.goal[r], said.goal_index[r], said.assign_epoch[r], said.assign_instance[r] = told
            said.state_tick[r] = s.tick
        if row is None:
            return
        tr = self.traj
        for i in range(row, len(tr.t) if newest else row + 1):
            tr.goal[i][r], tr.assignment[i][r], tr.assignment_epoch[i][r], tr.assignment_instance[i][r] = told

    def _on_goals(self, g: Goals, wall: float) -> None:
        """A new goal set: the newest from its stamp on, also in rows recorded before it arrived."""
        sets = self.sets
        sets.by_epoch[g.epoch] = g
        if g.epoch != max(sets.by_epoch):
            return
        sets.step, sets.newest = g.timing.step, g
        self.out.goals(wall, g, self.said.radius)
        tr = self.traj
        for i in range(len(tr.t) - 1, -1, -1):
            if tr.t[i] < g.timing.stamp - 1e-9:
                break
            tr.step[i], tr.goal_set_epoch[i] = g.timing.step, g.epoch

    def _on_bid(self, m: Bid) -> None:
        """The positions each robot bid from in each instance, to check agreements against the optimum."""
        recs = m.records
        claims = recs[((recs["flags"] & AuctionRecord.RELEASED) == 0) & (recs["robot"] < self.n)]  # not releases
        if len(claims):
            self.bids_from.claimed((m.epoch, m.instance), claims)

    def _on_truth(self, m: Truth, wall: float) -> None:
        """A tick of the world's truth: its row, the tick log, convergence, the scene, the live view."""
        progress, world, said, tr = self.progress, self.world, self.said, self.traj
        if m.count != self.n or progress.ended_at is not None or (tr.t and m.stamp <= tr.t[-1]):
            return
        world.row_of_tick[m.tick] = len(tr.t)
        world.latest_tick = max(world.latest_tick, m.tick)
        if m.tick > 0:
            world.dt = m.stamp / m.tick  # the control period, as the world's clock counts it
        # states heard before the truth of their tick, now a later tick's truth has come: by then the robot's own
        # state of their tick was heard, if it was sent, and a copy of it is not taken
        for key in sorted(k for k in world.early if k[0] < m.tick):
            self._on_state(world.early.pop(key))
        self._append_row(m, wall)
        world.least_clearance = min(world.least_clearance, m.min_clearance)
        progress.check(m.stamp, m.pose, said, self.sets.newest)
        self.out.scene(wall, m, said.radius, said.goal)
        if self.view is not None:
            self.view.truth(m, said.goal, said.radius)
        self.out.flush_now_and_then()
        since, ends = progress.converged_since, progress.ends
        if since is not None and ends is not None and ends(since, m.stamp):
            progress.ended_at = len(tr.t)  # the run ends with this tick, whenever the world hears of it

    def _append_row(self, m: Truth, wall: float) -> None:
        """A tick's row in the trajectory and the tick log: the truth, and a copy of what robots said."""
        tr, said = self.traj, self.said
        row = (m.pose, m.velocity, m.color, said.goal.copy(), said.goal_index.copy())  # sim.outputs.stream.ROWS
        for name, value in zip(ROWS, row, strict=True):
            getattr(tr, name).append(value)
        if self.out.ticks is not None:
            self.out.ticks.append(m.stamp, wall, row)
        tr.t.append(m.stamp)
        tr.wall.append(wall)
        tr.assignment_epoch.append(said.assign_epoch.copy())
        tr.assignment_instance.append(said.assign_instance.copy())
        tr.step.append(self.sets.step)
        tr.goal_set_epoch.append(max(self.sets.by_epoch) if self.sets.by_epoch else 0)

    def robots_died(self, robots: list[int]) -> None:
        """Robots whose agent was killed (a scene's fail event): the display converges anew without them."""
        self.progress.agent_alive[[r for r in robots if r < self.n]] = False
        self.progress.converged_since = None

    @property
    def sim_time(self) -> float:
        return self.traj.t[-1] if self.traj.t else 0.0

    def arrays(self) -> dict[str, np.ndarray]:
        tr, n = self.traj, self.n
        if not tr.t:
            return {"t": np.zeros(0)} | {name: np.zeros((0, n, *shape), kind) for name, (shape, kind) in ROWS.items()}
        out = {"t": np.array(tr.t)} | {name: np.stack(getattr(tr, name)) for name in ROWS}
        out["color"] = out["color"].astype(np.uint8)
        out["step"] = np.array(tr.step)  # 0 throughout for a scene without images, as the central engine records
        if self.sets.by_epoch:
            out.update(self._auction_arrays())
        return out

    def _auction_arrays(self) -> dict[str, np.ndarray]:
        """The agreed assignments as announced, the goal sets, and the positions bid from in each instance."""
        tr, n = self.traj, self.n
        epoch = np.stack(tr.assignment_epoch)
        instance = np.stack(tr.assignment_instance)
        announced = sorted(
            {(int(e), int(k)) for e, k in zip(epoch.ravel(), instance.ravel()) if e > 0 and k != State.CARRIED}
        )  # carried goals were never agreed
        heard = np.array([self.bids_from.of(key) for key in announced], float).reshape(len(announced), n, 3)
        return {
            "goal_set_epoch": np.array(tr.goal_set_epoch),
            "assignment_epoch": epoch,
            "assignment_instance": instance,
            "agreements": np.array(announced, np.int64).reshape(-1, 2),
            "agreement_positions": heard[..., :2],
            "agreement_penalties": heard[..., 2],
        } | goal_set_arrays(self.sets.by_epoch, n)
