"""The central engine: every robot of a scene in this process, each deciding by the robot policy.

States reach neighbours a tick later, rounded as on the wire, so an unimpaired central run equals a
lock-step distributed run of the same seed where no auction is involved. Image scenes use the agents'
own auction (one participant holding every robot); a warm block may settle on a second thread, and
only robots whose goal it changed decide again, so the run is the same to the bit.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TextIO, TypedDict, Unpack

import numpy as np
from scipy.optimize import linear_sum_assignment

from agent import loop
from agent.core.bidder import Participant
from agent.core.goal_motion import GoalMotion
from agent.core.local_auction import LocalAuction, new_auction
from agent.core.params import RobotParams
from agent.core.policy import Decision, GoalTiming, Memory
from agent.core.rounds import BlockRounds
from agent.core.step import NeighbourStates, static_segments
from agent.goal_sets import timing_of
from agent.held_goals import HeldGoals
from agent.loop import Seams, Sensed
from agent.neighbour_table import Heard
from coordinator.scene import Scene, scene_goal_set
from coordinator.service import scene_goal_message, step_motion, step_timing
from coordinator.warm_start import goal_matching
from sim.bodies.movers import Movers
from sim.bodies.tracker import tracker_of, world_of
from sim.central.link import InProcessLink
from sim.central.stepclock import StepClock
from sim.outputs.metrics import lockstep_waits_given_up
from sim.outputs.rundir import RunDir
from sim.outputs.stream import ROWS, SCRATCH, TickRecorder
from sim.outputs.write import RunOutcome, goal_set_arrays, write_run
from sim.processes import handling_signals
from transport.codec import START_TICK, Goals, State, as_sent, decode


def optimal_assignment(
    position: np.ndarray, goals: np.ndarray, previous: np.ndarray | None, hysteresis: float
) -> np.ndarray:
    """Goal index per robot of least total squared distance (eq. 5-7), adopted only if it beats the
    previous assignment by at least Delta C (paper 5.1's hysteresis). Scene `assignment = "optimal"`."""
    cost = ((position[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    if previous is not None and (previous >= 0).all():
        keep = cost[np.arange(len(position)), previous].sum()
        if keep - cost[rows, cols].sum() < hysteresis:
            return previous
    return _goal_index(len(position), rows, cols)


def settle_in_process(auction: LocalAuction, positions: np.ndarray, max_rounds: int = 1_000_000) -> int:
    """One block with every robot in this process, word for word the agents' rounds; the rounds taken."""
    auction.begin_block(positions)
    while not auction.done:
        auction.hear(auction.say())
        if auction.round >= max_rounds:
            raise RuntimeError("the range-limited auction did not end")
    return auction.round


def play(block: BlockRounds, rounds: int) -> bool:
    """``rounds`` rounds of a block held here, the last left open to be heard next tick as the agents
    do (AuctionLink.settle_block); True once it is agreed."""
    for played in range(1, rounds + 1):
        block.say()
        if played < rounds and block.hear({}):
            return True
    return False


def auction_assignment(auction: Participant | LocalAuction, position: np.ndarray) -> np.ndarray:
    """Goal index per robot (-1: none): the auction's next block (paper 5.1.1) settled on these positions,
    warm from the last prices, as the agents settle it; a block begun beside is waited for."""
    if isinstance(auction, LocalAuction):
        settle_in_process(auction, position)
        return _goal_index(len(position), auction.own_ids, [auction.agreed[r] for r in auction.own])
    goals = auction.settled() if auction.settling else auction.settle_alone(position)  # begun beside, or now
    return _goal_index(len(position), auction.own_ids, goals)


def warm_start(
    auction: Participant, before: Participant, previous: np.ndarray, goals: np.ndarray, assignment: np.ndarray
) -> np.ndarray:
    """The next image's auction begun from the coordinator's warm start, as bounded-rounds agents begin
    it; ``previous``: the last image's goals, which ``assignment`` indexes. Returns the carried assignment."""
    matched, prices = goal_matching(previous, goals, auction.schedule[-1])
    current = {r: int(g) for r, g in enumerate(assignment.tolist()) if g >= 0}
    carried = auction.carry(before, matched, current=current, prices=prices)
    return _goal_index(len(assignment), list(carried), list(carried.values()))


def start_warm(auction: Participant, poses: np.ndarray, goals: np.ndarray, robots: int) -> np.ndarray:
    """The first image's auction begun from the robots' starts (WarmStart.matched_from 0); returns the
    carried assignment of ``robots`` robots."""
    matched, prices = goal_matching(np.asarray(poses, float)[auction.robots, :2], goals, auction.schedule[-1])
    carried = auction.start_from(auction.robots[matched], prices)
    return _goal_index(robots, list(carried), list(carried.values()))


def _bid_in(auction: Participant | LocalAuction, goals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The positions the own robots bid from in the auction's last block, and the C_d in force on each one's
    ``goals`` (-1: none), as their bids carry them."""
    if isinstance(auction, LocalAuction):
        return auction.xy, np.where(goals >= 0, auction.penalty[np.arange(len(goals)), np.maximum(goals, 0)], 0.0)
    if not auction.penalty:  # deadlocks are rare: most agreements have none in force
        return auction.position, np.zeros(len(goals))
    return auction.position, np.array([auction.penalty.get((r, g), 0.0) for r, g in enumerate(goals.tolist())])


def _goal_index(robots: int, ids: Any, goals: Any) -> np.ndarray:
    """Goal index per robot (-1: none), ``goals`` being those of the robots ``ids``."""
    out = np.full(robots, -1)
    out[ids] = goals
    return out


class Outcome(NamedTuple):
    """What a central run produced: the recorded ticks and what the world and the robots counted."""

    arrays: dict[str, Any]  # t, pose, velocity, color, goal, assignment, step (rows by tick; sim.outputs.stream)
    contacts: list  # the world's contact events
    min_clearance: float  # m, over the run's sub-steps
    fallbacks: int  # robot-ticks where ORCA's program was infeasible
    penalties: int  # deadlocks declared (paper 5.5.5)
    end_reason: str
    wall_s: float
    stepping_wall_s: float  # from the first tick to the last (start-up excluded), as the distributed engine counts it
    commands: tuple[int, int]  # commands the robots' policy sent, and those the world applied


# an image scene's recording also holds, per tick and robot, which agreement each robot's goal is from
AGREEMENT_ROWS = {"assignment_epoch": ((), np.int64), "assignment_instance": ((), np.int64)}


# per agreement and robot (a TickRecorder's layout: an agreement streams as a tick's rows)
AGREED = {"agreement_positions": ((2,), np.float64), "agreement_penalties": ((), np.float64)}


@dataclass
class Agreements:
    """What trajectory.npz keeps of an image scene's auction, as the recorder keeps the agents': every goal set
    shown (by epoch: step + 1), and every agreement with the positions bid from and the penalties in force;
    and the deadlock penalties charged, for metrics.json. A run written to a directory streams the agreements'
    rows to raw files there (``stream_to``), as its ticks'."""

    robots: int
    goal_sets: dict[int, Goals] = field(default_factory=dict)
    keys: list[tuple[int, int]] = field(default_factory=list)  # (epoch, instance) of each agreement, as made
    # per agreement the positions each robot bid from (N,2) and the C_d in force on its goal (N,), NaN: none;
    # held here unless streamed (``stream_to``)
    held: dict[str, list[np.ndarray]] = field(default_factory=lambda: {name: [] for name in AGREED})
    stream: TickRecorder | None = None  # streamed: the rows of agreement k as those of a tick k
    last: tuple[tuple[int, int], dict[str, np.ndarray]] | None = None  # the newest, which one of its key may replace
    solves: int = 0  # the optimal assignment's solves (its instances)
    instance: int = 0  # the agreement the robots' goals are from now (State.CARRIED: the warm start's, never agreed)
    penalties: int = 0  # deadlock penalties charged in the auction (paper 5.5.5)

    def stream_to(self, directory: Path | None, ticks: int) -> None:
        """The agreements of ``ticks`` ticks from now on into raw files in ``directory``, written a chunk at a
        time on a thread as the ticks' rows are (an agreement a tick is as large as a tick's poses); None: held."""
        most = 2 * ticks + 1  # a tick agrees once, or twice: a cold start, then beside; and the last is kept at the end
        self.stream = None if directory is None else TickRecorder(most, self.robots, directory, AGREED)

    def agree(self, epoch: int, instance: int, robots: np.ndarray, position: np.ndarray, penalty: np.ndarray) -> None:
        """Agreement ``instance`` of goal set ``epoch``, the robots' goals from now: ``robots`` bid from
        ``position`` with ``penalty`` in force."""
        if len(robots) == self.robots:  # every robot, in id order (robots: sorted ids)
            positions, penalties = np.array(position, float).reshape(-1, 2), np.array(penalty, float)
        else:
            positions, penalties = np.full((self.robots, 2), np.nan), np.full(self.robots, np.nan)
            positions[robots], penalties[robots] = position, penalty
        key = (epoch, instance)
        if self.last is not None and self.last[0] != key:
            self._keep(*self.last)
        self.last = (key, {"agreement_positions": positions, "agreement_penalties": penalties})
        self.instance = instance

    def _keep(self, key: tuple[int, int], rows: dict[str, np.ndarray]) -> None:
        self.keys.append(key)
        if self.stream is not None:
            self.stream.record(len(self.keys) - 1, 0.0, 0, tuple(rows.values()))
            return
        for name, row in rows.items():
            self.held[name].append(row)

    def arrays(self, step: np.ndarray) -> dict[str, Any]:
        """trajectory.npz's goal-set and agreement arrays (sim.outputs.recorder makes the same of the bus), by
        epoch and instance: the agreements as made, unless made out of that order (then read whole)."""
        if self.last is not None:
            self._keep(*self.last)
            self.last = None
        streamed = None if self.stream is None else self.stream.arrays(len(self.keys))  # written out: OnDisk reads them
        if not self.goal_sets:
            return {}
        n, at = self.robots, {key: k for k, key in enumerate(self.keys)}  # the last of a key made twice
        order = [at[key] for key in sorted(at)]
        out = {"goal_set_epoch": np.asarray(step) + 1, "agreements": np.array(sorted(at), np.int64).reshape(-1, 2)}
        for name, (shape, _) in AGREED.items():
            if streamed is not None:
                rows: Any = streamed[name]
            else:
                rows = np.array(self.held[name], float).reshape(len(self.keys), n, *shape)
            out[name] = rows if order == list(range(len(self.keys))) else np.asarray(rows)[order]
        return out | goal_set_arrays(self.goal_sets, n)


@dataclass
class Shown:
    """The image step the auction works on (-1: none yet), as the agents decode it (motion None: still)."""

    k: int
    goal_set: np.ndarray
    goal_colors: np.ndarray
    motion: GoalMotion | None = None
    t_start: float = 0.0


class CentralAuction:
    """The central engine's auction step (agent.loop.Auction): the shown image's goal set and its auction,
    settled beside the policy when ``overlap``; ``clock`` times the engine's parts."""

    def __init__(
        self, scene: Scene, params: RobotParams, movers: Movers, reach: float, clock: StepClock, overlap: bool
    ) -> None:
        self.scene, self.params, self.movers, self.reach = scene, params, movers, reach
        self.clock, self.overlap = clock, overlap
        self.image = Shown(-1, *_scene_goals(scene))  # image scenes: the shown step's, below
        self.auction: Participant | LocalAuction | None = None  # image scenes: the auction of the shown goal set
        ids = np.arange(scene.robots)
        self.assignment = np.where(np.isfinite(self.image.goal_set).all(axis=1), ids, -1)  # scene goals: its own
        # the goal set the assignment indexes: the shown one, or the last one until the shown one's first
        # agreement when the auction's rounds per tick are bounded (the agents drive on as well)
        self.assigned = (-1, self.image.goal_set, self.image.goal_colors)  # (image, goal set, colours)
        self.block: BlockRounds | None = None  # lock-step rounds per tick bounded: the block under way
        self.timing: dict[int, GoalTiming] = {}
        self.assigned_at: float | None = None  # when the shown goal set was last assigned
        self.pending: tuple[Participant, np.ndarray] | None = None  # a block settling beside, and its positions
        self.agreements = Agreements(scene.robots)  # and which the assignment is from

    def show(self, k: int) -> None:
        """A new image: its goal set, and a fresh auction (the old prices mean nothing)."""
        last = self.auction if isinstance(self.auction, Participant) and self.auction.common_owner is not None else None
        first = self.image.k < 0
        self.image.k, self.auction, self.assigned_at, self.block = k, None, None, None
        if not self.scene.steps:
            return
        previous, image = self.image.goal_set, self.assigned[0]
        heard, timing = _step_goals(self.scene, k, self.movers.pixels)
        self.agreements.goal_sets[k + 1] = heard
        self.image = Shown(k, heard.positions, heard.colors, timing.motion, timing.t_start)
        self.timing = {e: v for e, v in self.timing.items() if e == image + 1} | {k + 1: timing}
        if self.budget and (last is not None or first):  # as the agents with bounded rounds: the warm start
            pixels, p = self.movers.pixels.tolist(), self.params
            self.auction = Participant(k, self.image.goal_set, pixels, pixels, p.assign_eps, p.assign_hysteresis)
            if last is not None:
                self.assignment = warm_start(self.auction, last, previous, self.image.goal_set, self.assignment)
            else:
                self.assignment = start_warm(self.auction, self.scene.poses, self.image.goal_set, len(self.assignment))
            self.assigned, self.agreements.instance = (k, self.image.goal_set, self.image.goal_colors), State.CARRIED

    @property
    def budget(self) -> int:
        """The auction's lock-step rounds a tick (0: every block settles within its tick)."""
        unbounded = self.scene.assignment == "optimal" or np.isfinite(self.reach)
        return 0 if unbounded else self.params.rounds_per_tick

    @property
    def active(self) -> bool:
        return self.auction is not None

    def step(self, sensed: Sensed) -> None:
        """Paper 5.1: re-assign every assign_period, warm from the previous prices, with hysteresis Delta C."""
        t, p, movers = sensed.stamp, self.params, self.movers
        # a moving goal set is auctioned with the positions mapped back to t = 0 (GoalMotion.to_initial_frame)
        motion = self.image.motion
        bid_from = (
            sensed.position if motion is None else motion.to_initial_frame(sensed.position, t - self.image.t_start)
        )
        # the last tick is a pose with no command to follow (the world asks the agents for none)
        last = sensed.tick == round(self.scene.duration / p.dt)
        due = not last and (self.assigned_at is None or t - self.assigned_at >= p.assign_period - 1e-9)
        auction = self.auction
        if not self.scene.steps or not (due or self.block is not None):
            pass
        elif self.budget and not last and isinstance(auction, Participant):
            # the agents' lock-step rounds, at most `budget` a tick; a cold start settles at once below
            if self.block is not None and self.block.open and self.block.hear({}):
                self._adopt(auction)
            if self.block is not None and self.assigned_at is not None and p.stale_block(t - self.assigned_at):
                self.block = None  # the robots keep the last agreement; the next block begins now
            if self.block is None and due:
                self.block, self.assigned_at = BlockRounds(auction, bid_from), t
            if self.block is not None and play(self.block, self.budget):
                self._adopt(auction)
        elif due:
            if self.scene.assignment == "optimal":
                before = None if self.assigned_at is None else self.assignment[movers.pixels]
                best = optimal_assignment(bid_from[movers.pixels], self.image.goal_set, before, p.assign_hysteresis)
                self.assignment = movers.pixel_assignment(best)
                if best is not before:  # kept by the hysteresis: the last solve's agreement stands
                    self._agreed(None, bid_from)
            elif isinstance(auction, Participant) and self.overlap:
                auction.settle_beside(bid_from)
                self.pending = (auction, bid_from)
            else:  # a new image: a cold start (the old prices mean nothing)
                if auction is None:
                    pixels = movers.pixels.tolist()
                    auction = self.auction = new_auction(
                        self.image.k, self.image.goal_set, pixels, pixels, p, self.reach
                    )
                self.assignment = auction_assignment(auction, bid_from)
                self._agreed(auction, bid_from)
            self.assigned_at = t
            self.assigned = (self.image.k, self.image.goal_set, self.image.goal_colors)
        self.clock.lap("assignment")

    def _adopt(self, auction: Participant) -> None:
        """The block just agreed: every robot takes its goal of the agreement at this tick."""
        self.block = None
        agreed = [auction.agreed.get(r, -1) for r in auction.own]
        self.assignment = _goal_index(len(self.assignment), auction.own_ids, agreed)
        self.assigned = (self.image.k, self.image.goal_set, self.image.goal_colors)
        self._agreed(auction, None)

    def _agreed(self, auction: Participant | LocalAuction | None, bid_from: np.ndarray | None) -> None:
        """The assignment just made is an agreement of the shown goal set (``auction`` None: an optimal solve
        on ``bid_from``): its instance, which the robots hold their goals from, kept for trajectory.npz."""
        epoch, pixels, kept = self.image.k + 1, self.movers.pixels, self.agreements
        if auction is None:
            assert bid_from is not None
            kept.solves += 1
            kept.agree(epoch, kept.solves - 1, pixels, bid_from[pixels], np.zeros(len(pixels)))
            return
        position, penalty = _bid_in(auction, self.assignment[auction.own_ids])
        kept.agree(epoch, auction.agreed_instance, auction.own_ids, position, penalty)

    def settled_beside(self) -> bool:
        """The auction beside is settled: True when it changed the assignment."""
        if self.pending is None:
            return False
        (auction, bid_from), self.pending = self.pending, None
        bids = auction.bids
        settled = auction_assignment(auction, bid_from)
        reassigned = int((settled != self.assignment).sum())
        self.clock.add_beside(auction.beside_seconds, auction.bids - bids, reassigned)
        self.clock.lap("assignment")
        self.assignment = settled
        self._agreed(auction, None)
        return reassigned > 0

    def penalise(self, robot: int, epoch: int, goal: int) -> None:
        # a goal of an earlier set is no goal of this auction
        if self.auction is not None and epoch == self.image.k + 1:
            self.auction.penalise(robot, goal, self.params.deadlock_cost)
            self.agreements.penalties += 1


class Central:
    """Every robot of a scene in one batch (agent.loop.Robots and Link): what the tracker measured,
    the goals the assignment gives them, and their neighbours over the in-process link."""

    def __init__(self, scene: Scene, link: InProcessLink, auction: CentralAuction, world: Any) -> None:
        self.scene, self.link, self.auction, self.world, self.movers = scene, link, auction, world, auction.movers
        self.params, self.tracker = auction.params, tracker_of(scene)
        self.policy_memory = Memory.new(scene.robots, latency=self.params.stale_after)  # until a neighbour is heard
        self.measured = np.zeros((scene.robots, 3))
        self.held_goals = HeldGoals.new(scene.robots)
        # what the held goals were taken from: ((image, agreed instance), assignment)
        self.made: tuple[tuple[int, int], np.ndarray] | None = None

    @property
    def timing(self) -> dict[int, GoalTiming]:
        return self.auction.timing

    def sense(self, tick: int) -> Sensed:
        """The poses as the tracker's messages carry them."""
        self.measured = as_sent(self.tracker.measure(self.world.poses))
        self.auction.clock.lap("tracker")
        n, m = len(self.measured), self.measured
        return Sensed(np.arange(n), m[:, :2], m[:, 2], tick, tick * self.params.dt, self.params, np.zeros(n, bool))

    def rows(self, ids: np.ndarray) -> slice:
        return slice(None)  # every robot, in order: the memory's rows are read and written in place

    def neighbours(self, sensed: Sensed) -> NeighbourStates:
        lap = self.auction.clock.lap
        self.world.check()  # the contacts of the last step, while the auction runs beside
        lap("world")
        heard = self.link.neighbours(sensed)
        lap("neighbours")
        return heard

    def goals(self, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        """The robots hold the goals the assignment gives them now (agent.held_goals, as the agents)."""
        a, held, rows = self.auction, self.held_goals, self.rows(sensed.ids)
        image, goal_set, colors = a.assigned
        # most ticks the auction keeps every goal, and the rest it gives few robots: those alone take theirs
        made, last = (image, a.agreements.instance), self.made
        if last is None or last[0][0] != image:  # the first goals, or a new image's: every robot takes one
            moved = np.arange(len(a.assignment))
        else:
            moved = np.flatnonzero(last[1] != a.assignment)
        if moved.size and self.scene.steps:
            index = a.assignment[moved]
            held.drive_to(moved[index >= 0], image + 1, made[1], index[index >= 0], goal_set, colors)
            held.idle(moved[index < 0])
            held.instance[a.assignment >= 0] = made[1]  # the others hold theirs from this agreement too
        elif moved.size:  # the scene's own goals, one per robot, as the agents hold them: no goal set, no auction
            held.goal[:], held.color[:] = goal_set, colors
        if moved.size:
            self.made = (made, a.assignment.copy())
        else:  # a new agreement that gives no robot another goal: only the instance they hold them from is new
            self.hold_newest_agreement()
        if moved.size or self.movers.pursuers:  # the movers' goals and colours over the goals just taken
            held.goal[:], held.color[:] = self.movers.goals(held.goal, held.color, self.measured)
        return held.targets(rows)

    def hold_newest_agreement(self) -> None:
        """The robots hold their goals from the newest agreement, which an auction settled beside the policy
        may have made after they took them, changing none (the agents take every agreement as it comes)."""
        a, made = self.auction, self.made
        if made is not None and made[0][1] != a.agreements.instance and np.array_equal(made[1], a.assignment):
            self.held_goals.instance[a.assignment >= 0] = a.agreements.instance
            self.made = ((made[0][0], a.agreements.instance), made[1])

    def has_goal(self) -> np.ndarray:
        """The robots whose goal convergence is judged on: a pixel of the image with a goal."""
        if self.scene.steps:
            return self.held_goals.key[:, 1] >= 0
        return np.isfinite(self.auction.image.goal_set).all(axis=1)

    def send(self, sensed: Sensed, decision: Decision) -> None:
        """The world applies the commands between ticks (simulate)."""


@dataclass
class Convergence:
    """Whether every robot has held its goal for ``hold`` s (None: the run does not end on it)."""

    hold: float | None
    since: float | None = None  # when the robots last arrived, all of them

    def held(self, t: float, at_goals: bool) -> bool:
        if self.hold is None or not at_goals:
            self.since = None
            return False
        self.since = t if self.since is None else self.since
        return t - self.since >= self.hold


@dataclass
class Stop:
    """The stop signals a central run heeds while it runs (SIGINT, SIGTERM), as the distributed engine's
    launcher does: the first ends the run at its tick, written marked incomplete; a second abandons the
    writing (KeyboardInterrupt: nothing is written)."""

    signal: int | None = None  # the first stop signal received
    interrupted: bool = False  # it ended the run (one that came as the run ended: the run is complete)

    def on_signal(self, signum: int, frame: object) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signum


def simulate(
    scene: Scene,
    *,
    link: InProcessLink | None = None,
    progress: TextIO | None = sys.stderr,
    clock: StepClock | None = None,
    overlap: bool = True,
    view: Any = None,
    scratch: Path | None = None,
    stop: Stop | None = None,
) -> Outcome:
    """Every robot through agent.loop.tick, the world moving between ticks, until the duration, convergence or
    a signal ``stop`` heeds. ``overlap``: warm auctions on a second thread; ``scratch``: where a recording streams."""
    refuse_process_faults(scene)
    _keep_freed_memory()
    link, clock = link or InProcessLink(scene.robots), clock or StepClock()
    robots, seams = _swarm(scene, link, clock, overlap)
    params, world, auction = robots.params, robots.world, robots.auction
    events = sorted(scene.events, key=lambda e: e["t"])
    steps, last_step = round(scene.duration / params.dt), max(len(scene.steps) - 1, 0)
    rec = TickRecorder(steps + 1, scene.robots, scratch, ROWS | AGREEMENT_ROWS if scene.steps else ROWS)
    auction.agreements.stream_to(scratch, steps + 1)
    converged = Convergence(scene.converge_hold if scene.ends_on_convergence else None)
    fallbacks, end_reason = 0, "duration"
    wall0 = last_say = time.time()
    _say_hello(link, robots)
    stepping0 = time.time()
    for tick in range(steps + 1):
        clock.start()
        t = tick * params.dt
        world.teleport_due(events, t)
        # the last tick is the poses after the last step, as the world reports them: no image begins in it
        k = scene.step_at(t) if tick < steps or auction.image.k < 0 else auction.image.k
        if k != auction.image.k:
            auction.show(k)
        clock.lap("other")
        decision = loop.tick(robots, robots.sense(tick), seams)
        pose, goal = world.poses, decision.intent.goal
        _record_tick(rec, view, (tick, t, k), robots, pose, goal)
        clock.lap("record")
        if converged.held(t, _all_at_goals(robots, k == last_step, pose, goal)):
            end_reason = "converged"
            break  # the run ends here: no last step
        if tick == steps or (stop is not None and stop.signal is not None):
            end_reason = end_reason if tick == steps else "interrupted"
            break
        velocity_next = _move(world, robots.movers, decision.step, pose, t, params.dt)
        clock.lap("world")
        # what the robots broadcast this tick: heard by their neighbours at the next
        link.broadcast(_states(params, robots.measured, pose, velocity_next, t, robots.movers))
        fallbacks += int(decision.step.fallback.sum())
        if progress is not None and time.time() - last_say >= 1.0:
            at_goal = _at_goal(pose, goal, params)
            last_say = _say_progress(progress, scene.name, (t, k), at_goal, robots.has_goal(), world)
        clock.lap("other")
    stepping, arrays = time.time() - stepping0, rec.arrays(tick + 1)  # a converged run ends early
    arrays |= auction.agreements.arrays(arrays["step"])
    how = (list(world.contacts), float(world.min_clearance), fallbacks, auction.agreements.penalties)
    commands = (tick * int(robots.movers.cooperative.sum()), int(world.commands_applied.sum()))
    return Outcome(arrays, *how, end_reason, time.time() - wall0, stepping, commands)


def _swarm(scene: Scene, link: InProcessLink, clock: StepClock, overlap: bool) -> tuple[Central, Seams]:
    """Every robot of the scene in one batch over ``link``, and the seams agent.loop.tick steps it through."""
    params, world = world_of(scene)
    auction = CentralAuction(scene, params, Movers(scene), link.reach, clock, overlap)
    robots = Central(scene, link, auction, world)
    link.threads = threads = len(os.sched_getaffinity(0))  # the batch's rows shared among the cores
    segments = static_segments(scene.arena, scene.obstacles)
    return robots, Seams(robots, auction, segments, scene.seed, link.reach, clock.lap, threads)


def _say_hello(link: InProcessLink, robots: Central) -> None:
    """Every robot but the scripted movers says hello: where it stands, before the first tick."""
    params, world, n = robots.params, robots.world, robots.scene.robots
    standing = _states(params, world.poses, world.poses, np.zeros((n, 2)), START_TICK * params.dt, robots.movers)
    link.start(standing, robots.movers.cooperative)


def _keep_freed_memory() -> None:
    """Let glibc's heap keep what a tick frees for the next, rather than fault large arrays in anew."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD: a tick's arrays come from the heap, not fresh mappings
    mallopt(-1, 128 << 20)  # M_TRIM_THRESHOLD: what they free stays in the heap for the next tick
    mallopt(-2, 16 << 20)  # M_TOP_PAD: the heap grows in steps that hold a tick's arrays


def _record_tick(
    rec: TickRecorder, view: Any, when: tuple[int, float, int], robots: Central, pose: np.ndarray, goal: np.ndarray
) -> None:
    """This tick's row of the recording (``pose``: the world's, as the tick read them), and the live view's batch
    (sim.outputs.view.SwarmView)."""
    (tick, t, k), held = when, robots.held_goals
    rows: tuple[np.ndarray, ...] = (pose, robots.world.velocities, held.color, goal, robots.auction.assignment)
    if robots.scene.steps:  # which agreement each robot's goal is from (AGREEMENT_ROWS)
        robots.hold_newest_agreement()
        rows += (held.key[:, 0], held.instance)
    color = rec.record(tick, t, k, rows)["color"]  # this tick's colours, as recorded
    if view is not None:
        view.tick(tick, t, pose, color, goal)


def _all_at_goals(robots: Central, last_image: bool, pose: np.ndarray, goal: np.ndarray) -> bool:
    """The last image is up and every robot with a goal is at it (the run may end on convergence)."""
    has_goal = robots.has_goal()
    return bool(last_image and has_goal.any() and _at_goal(pose, goal, robots.params)[has_goal].all())


def refuse_process_faults(scene: Scene) -> None:
    """ValueError for the scene's events that fault processes and messages, which this engine has none of."""
    if any(e["kind"] in ("fail", "tracker-outage", "tracker-glitch") for e in scene.events):
        raise ValueError(
            "fail and tracker-outage events, and tracker-glitch ones (faults of processes and messages), need the distributed engine"
        )


def _say_progress(
    out: TextIO, name: str, when: tuple[float, int], at_goal: np.ndarray, has_goal: np.ndarray, world
) -> float:
    """One line of progress; returns the wall time it was said."""
    (t, k), held = when, f"at goal {int(at_goal.sum())}/{int(has_goal.sum())}"
    held = held if has_goal.any() else "waiting for the goal set"
    print(f"[{name}] central t={t:6.1f} s  step {k}  {held}  contacts {len(world.contacts)}", file=out, flush=True)
    return time.time()


class Timing(TypedDict, total=False):
    """How simulate times its parts and runs its auction (as its keywords ``clock`` and ``overlap``)."""

    clock: StepClock | None
    overlap: bool


def run_central(
    scene: Scene,
    out: Path,
    *,
    video: bool = True,
    plots: bool = True,
    progress: TextIO | None = sys.stderr,
    reach: float = np.inf,
    view: Any = None,
    stop: Stop | None = None,
    **timing: Unpack[Timing],
) -> Path:
    """Run the scene with every robot in this process (``simulate``); returns the run directory.
    ``reach``: the robots' communication range (m); ``stop``: heed SIGINT and SIGTERM meanwhile (the first
    signal, and whether it ended the run, are kept there); ``timing``: simulate's clock and overlap."""
    run_dir = RunDir(out)
    try:
        with handling_signals(stop.on_signal) if stop is not None else contextlib.nullcontext():
            link = InProcessLink(scene.robots, reach=reach)
            outcome = simulate(
                scene, link=link, progress=progress, view=view, scratch=run_dir / SCRATCH, stop=stop, **timing
            )
            interrupted = outcome.end_reason == "interrupted"
            if stop is not None:
                stop.interrupted = interrupted
            params = RobotParams.from_dict(scene.robot)
            how = RunOutcome(
                outcome.wall_s,
                [asdict(c) for c in outcome.contacts],
                reach=reach,
                extra=_metrics(outcome, scene.robots),
            )
            # as the distributed engine: an interrupted run's video is left out, what was recorded is written
            video = video and not interrupted
            return write_run(run_dir, scene, params, outcome.arrays, how, video=video, plots=plots, progress=progress)
    except BaseException:
        run_dir.abort()
        raise


def _metrics(outcome: Outcome, robots: int) -> dict[str, Any]:
    """metrics.json's keys beside the true record, as the distributed engine's launcher writes them, for a run
    in one process: no agent process or router, no message to drop or be late, each command applied at once."""
    t = outcome.arrays["t"]
    stepped = float(t[-1] - t[0]) if len(t) else 0.0
    sent, applied = outcome.commands
    return dict(
        agents_failed_by_scene=[],  # fail events need the distributed engine
        end_reason=outcome.end_reason,
        complete=outcome.end_reason != "interrupted",
        engine="central",
        agent_processes=0,
        min_clearance_substep_m=outcome.min_clearance if np.isfinite(outcome.min_clearance) else None,
        commands_applied=applied,
        commands_sent=sent,  # what the robots' policy gave the world: no router sees them
        late_commands=0,
        expired_commands=0,
        stopped_ticks=0,
        withheld_ticks=0,  # tracker outages need the distributed engine
        commanded_two_ways=[],  # no bus carries its commands
        missed_ticks_by_robot=[0] * robots,  # each robot answers every tick at once
        orca_fallbacks=outcome.fallbacks,
        poses_held=0,  # the tracker's poses are trusted: tracker glitches need the distributed engine
        subscriptions_renewed=0,
        lockstep_waits_given_up=lockstep_waits_given_up([], {}),  # one process waits for nobody
        deadlock_penalties=outcome.penalties,
        dropped_messages={},
        crashes=[],
        restarts=[],
        liveliness_lost=[],
        faults="",  # --faults needs the distributed engine
        stepping_wall_s=outcome.stepping_wall_s,
        stepping_realtime_factor=stepped / outcome.stepping_wall_s if outcome.stepping_wall_s else None,
    )


def _scene_goals(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The scene's own goals as the agents decode them (NaN rows and grey: no goal of its own)."""
    goals = scene.goal_positions
    message = scene_goal_message(scene)
    if message is None:
        return goals, np.full((len(goals), 3), 40, np.uint8)
    heard = _as_heard(message)
    has_goal = np.isfinite(goals).all(axis=1)[:, None]
    return np.where(has_goal, heard.positions, np.nan), np.where(has_goal, heard.colors, 40).astype(np.uint8)


def _step_goals(scene: Scene, k: int, pixels: np.ndarray) -> tuple[Goals, GoalTiming]:
    """Step k's goal set (positions, colours, robots) and timing as the agents decode the coordinator's message."""
    goals, colors = scene_goal_set(scene, k, len(pixels))
    message = Goals(k + 1, 0, goals, colors, pixels, step_timing(scene, k), step_motion(scene, k))
    heard = _as_heard(message)
    return heard, timing_of(heard)


def _as_heard(message: Goals) -> Goals:
    """A goal set as the agents decode it (the wire rounds its positions and timing)."""
    heard = decode(message.encode(), Goals)
    if not isinstance(heard, Goals):
        raise ValueError(f"goal set {message.epoch} does not survive its own encoding")
    return heard


def _states(params, measured: np.ndarray, pose: np.ndarray, velocity: np.ndarray, t: float, movers: Movers) -> Heard:
    """What every robot broadcasts this tick: tracked position and collision-free velocity (a scripted
    mover: its true position and scripted velocity, as the world process sends them)."""
    n = len(measured)
    position, scripted = measured[:, :2].copy(), ~movers.cooperative
    position[scripted] = pose[scripted, :2]
    return Heard(
        np.arange(n),
        as_sent(position),
        as_sent(velocity),
        as_sent(np.full(n, params.radius)),
        np.full(n, t),
        movers.cooperative,
    )


def _at_goal(pose: np.ndarray, goal: np.ndarray, params: RobotParams) -> np.ndarray:
    """(N,) each robot within the goal tolerance of its goal (none: False)."""
    return np.hypot(*(pose[:, :2] - goal).T) <= params.goal_tolerance


def _move(world, movers: Movers, res, pose: np.ndarray, t: float, dt: float) -> np.ndarray:
    """Command the robots and step the world (contacts checked later, beside the auction); returns the
    velocities their neighbours hear next tick."""
    command, velocity = movers.commands(res.command, res.velocity, pose, t, dt)
    world.set_commands(as_sent(command))
    world.step(dt, check=False)
    return velocity
