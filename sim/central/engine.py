"""The central engine: every robot of a scene in this process, each deciding by the robot policy.

Robots hear each other through an in-process link (sim.central.link): each robot's state of a tick reaches
its neighbours at the next, rounded as the wire rounds it, and goal sets arrive as the agents decode
them. Without impairment that is exactly what lock-step agents over the bus know, so a central run
and a distributed run of one seed are the same run where no auction is involved; with a seeded loss
the same loop is the loss study (sim.central.lossy). It is the reference against which decentralisation is
studied and the fast path for large swarms.

Image scenes play their steps: at time t the robots are auctioned (paper 5.1) onto the goal set of
the step whose hold contains t. The auction is the agents' own (agent.core.bidder) with one
participant holding every robot: each `assign_period` the next block of epsilon-scaling phases starts
from the measured positions, warm from the last prices, and settles without messages (compiled,
agent.core.bidding) on a second thread while this one decides every robot's tick on the goal it holds;
only the robots whose goal the auction changed decide again, so the run is the one that waiting for
the auction would give, to the bit.
"""

from __future__ import annotations

import sys
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple, TextIO

import numpy as np
from scipy.optimize import linear_sum_assignment

from agent.core.bidder import Participant
from agent.core.goal_motion import GoalMotion
from agent.core.local_auction import LocalAuction, new_auction
from agent.core.policy import NO_GOAL, Decision, GoalTiming, Intent, Memory, act, intend
from agent.core.rounds import BlockRounds
from agent.core.step import NeighbourStates, static_segments
from agent.goal_sets import timing_of
from agent.neighbour_table import Heard
from coordinator.keyframes import goal_matching
from coordinator.motion import StepMotion
from coordinator.scene import Scene, scene_goal_set
from coordinator.service import scene_goal_message, step_motion, step_timing
from sim.bodies.movers import Movers
from sim.bodies.tracker import tracker_of, world_of
from sim.central.link import InProcessLink
from sim.central.stepclock import StepClock
from sim.outputs.rundir import RunDir
from sim.outputs.write import RunOutcome, write_run
from transport.codec import Goals, as_sent, decode


def goal_motion(motion: StepMotion | None) -> GoalMotion | None:
    """A scene step's motion as the agents' core takes it (eq. 28); None for a still image."""
    if motion is None:
        return None
    out = GoalMotion(motion.velocity, motion.angular_velocity, motion.center, motion.expansion, motion.geometric)
    return None if out.is_static else out


def optimal_assignment(
    position: np.ndarray, goals: np.ndarray, previous: np.ndarray | None, hysteresis: float
) -> np.ndarray:
    """Goal index per robot: the assignment of least total squared distance (eq. 5-7, scipy's
    linear_sum_assignment), kept only if it lowers the cost of the previous iteration's assignment by
    at least Delta C (paper 5.1's hysteresis for noisy positions). Scene `assignment = "optimal"`,
    solved every `assign_period`: scipy takes 10 ms for 1000 robots near their goals, about 1 s
    while they cross the arena (bench/bench_large.py compares it with the auction)."""
    cost = ((position[:, None, :] - goals[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    best = np.full(len(position), -1)
    best[rows] = cols
    if previous is not None and (previous >= 0).all():
        keep = cost[np.arange(len(position)), previous].sum()
        if keep - cost[rows, cols].sum() < hysteresis:
            return previous
    return best


def settle_in_process(auction: LocalAuction, positions: np.ndarray, max_rounds: int = 1_000_000) -> int:
    """One block with every robot in this process (the central engine): the rounds the agents run
    over the bus, word for word. Returns the rounds taken."""
    auction.begin_block(positions)
    while not auction.done:
        auction.hear(auction.say())
        if auction.round >= max_rounds:
            raise RuntimeError("the range-limited auction did not end")
    return auction.round


def play(block: BlockRounds, rounds: int) -> bool:
    """Up to ``rounds`` rounds of a block whose every robot this process holds (no messages);
    True once it is agreed."""
    for _ in range(rounds):
        block.say()
        if block.hear({}):
            return True
    return False


def auction_assignment(auction: Participant | LocalAuction, position: np.ndarray) -> np.ndarray:
    """Goal index per robot (-1: none): the auction's next block of phases (paper 5.1.1) settled on
    these positions (rows by robot id), warm from the last prices, as the agents settle theirs; a
    robot keeps its goal unless another is better by epsilon_A + Delta C. The participant holds
    every robot, so every phase's snapshot is its own board. Over a limited range every robot keeps
    its own board and the rounds are the agents' (agent.core.local_auction)."""
    assignment = np.full(len(position), -1)
    if isinstance(auction, LocalAuction):
        settle_in_process(auction, position)
        assignment[auction.own_ids] = [auction.agreed[r] for r in auction.own]
    else:
        assignment[auction.own_ids] = auction.settle_alone(position)
    return assignment


def warm_start(
    auction: Participant, before: Participant, previous: np.ndarray, goals: np.ndarray, assignment: np.ndarray
) -> np.ndarray:
    """The next image's auction begun from the coordinator's warm start (the goal sets' matching and
    its prices, coordinator.keyframes.goal_matching), as the agents begin it with rounds per tick
    bounded: each robot drives at once to the goal its last one is matched to (agent.assignment).
    ``previous``: the last image's goals, which ``assignment`` indexes. Returns the carried assignment."""
    matched, prices = goal_matching(previous, goals)
    current = {r: int(g) for r, g in enumerate(assignment.tolist()) if g >= 0}
    carried = auction.carry(before, matched, current=current, prices=prices)
    out = np.full(len(assignment), -1)
    out[list(carried)] = list(carried.values())
    return out


class Outcome(NamedTuple):
    """What a central run produced: the recorded ticks and what the world and the robots counted."""

    arrays: dict[str, np.ndarray]  # t, pose, velocity, color, goal, assignment, step (rows by tick)
    contacts: list  # the world's contact events
    min_clearance: float  # m, over the run's sub-steps
    fallbacks: int  # robot-ticks where ORCA's program was infeasible
    penalties: int  # deadlocks declared (paper 5.5.5)
    end_reason: str
    wall_s: float


class _Goals(NamedTuple):
    """The goals an assignment gives the robots this tick (rows by robot)."""

    goal0: np.ndarray  # (N,2) the goal as its set was published (NaN: none)
    key: np.ndarray  # (N,2) (epoch, goal index)
    color: np.ndarray  # (N,3) LED colour
    has_goal: np.ndarray  # (N,) a pixel with a goal (what convergence is judged on)


def simulate(
    scene: Scene,
    *,
    link: InProcessLink | None = None,
    progress: TextIO | None = sys.stderr,
    clock: StepClock | None = None,
    overlap: bool = True,
    view: Any = None,
) -> Outcome:
    """Step every robot of the scene in this process, each deciding by the robot policy from what the
    link let it hear (agent.core.policy), until the scene's duration or convergence. ``clock`` (if
    given) receives the wall and CPU time per part of each control step (bench/bench_large.py).
    ``overlap``: a warm auction runs on a second thread while this one searches neighbours and steps
    the control core on the goals the robots hold, and only the robots whose goal changed are
    stepped again (the same run, to the bit, as without: tests/integration/test_central_overlap.py)."""
    params, world = world_of(scene)
    tracker = tracker_of(scene)
    segments = static_segments(scene.arena, scene.obstacles)
    n = scene.robots
    link = link if link is not None else InProcessLink(n)
    movers = Movers(scene)  # scripted movers and pursuers: not robot pixels (sim.bodies.movers)
    ids = np.arange(n)
    goal_set, goal_colors = _scene_goals(scene)  # image scenes: the shown step's goal set, below
    auction: Participant | LocalAuction | None = None  # image scenes: the auction of the shown goal set
    assignment = np.where(np.isfinite(goal_set).all(axis=1), ids, -1)  # goal index per robot (scene goals: its own)
    # the goal set the assignment indexes: the shown one, or the last one until the shown one's first
    # agreement when the auction's rounds per tick are bounded (the agents drive on as well)
    assigned_image, assigned_set, assigned_colors = -1, goal_set, goal_colors
    block: BlockRounds | None = None  # lock-step rounds per tick bounded: the block under way
    budget = params.rounds_per_tick if scene.assignment != "optimal" and not np.isfinite(link.reach) else 0
    memory = Memory.new(n, latency=params.stale_after)  # until a neighbour is heard (agent.core.policy.act)
    timing: dict[int, GoalTiming] = {}
    motion: GoalMotion | None = None
    t_start = 0.0  # when the shown step started
    assigned_at: float | None = None  # when the shown goal set was last assigned
    if any(e["kind"] in ("fail", "tracker-outage", "tracker-glitch") for e in scene.events):
        raise ValueError(
            "fail and tracker-outage events, and tracker-glitch ones (faults of processes and messages), need the distributed engine"
        )
    events = sorted(scene.events, key=lambda e: e["t"])
    last_step = max(len(scene.steps) - 1, 0)
    shown = -1  # the image step whose goal set the auction works on
    rec: dict[str, list] = {"t": [], "pose": [], "velocity": [], "color": [], "goal": [], "assignment": [], "step": []}
    steps = round(scene.duration / params.dt)
    fallbacks = penalties = 0
    converged_since, end_reason = None, "duration"
    clock = clock if clock is not None else StepClock()
    wall0 = last_say = time.time()

    made: tuple[int, np.ndarray, _Goals] | None = None  # the last goals made: (image, assignment, goals)

    def goals_of(assignment: np.ndarray, measured: np.ndarray) -> _Goals:
        nonlocal made
        # most ticks the auction keeps every goal: the goals are the last ones (unless a pursuer's moved)
        if (
            made is not None
            and made[0] == assigned_image
            and not movers.pursuers
            and np.array_equal(made[1], assignment)
        ):
            last = made[2]
            return last._replace(key=last.key.copy())  # the intent's key is written into (_step_again)
        if scene.steps:
            has_goal = assignment >= 0
            goal0 = np.where(has_goal[:, None], assigned_set[assignment], np.nan)
            color = np.where(has_goal[:, None], assigned_colors[assignment], 40).astype(np.uint8)
            epoch = np.where(has_goal, assigned_image + 1, shown + 1)
            key = np.stack([epoch, np.where(has_goal, assignment, NO_GOAL)], axis=1)
        else:  # the scene's own goals, one per robot, as the agents hold them: no goal set, no auction
            goal0, color, has_goal = goal_set, goal_colors, np.isfinite(goal_set).all(axis=1)
            key = np.stack([np.zeros(n, np.int64), np.full(n, NO_GOAL)], axis=1)
        goal0, color = movers.goals(goal0, color, measured)  # a pursuer heads for its target
        made = (assigned_image, assignment.copy(), _Goals(goal0, key, color, has_goal))
        return made[2]._replace(key=key.copy())

    beside = ThreadPoolExecutor(1, thread_name_prefix="auction")  # the auction beside the control core
    try:
        for tick in range(steps + 1):
            clock.start()
            t = tick * params.dt
            while events and events[0]["t"] <= t + 1e-9:
                ev = events.pop(0)
                world.teleport(ev["robot"], tuple(ev["pose"]))
            k = scene.step_at(t)
            if k != shown:  # a new image: its goal set, and a fresh auction (the old prices mean nothing)
                last_auction = auction if isinstance(auction, Participant) and auction.agreed_instance >= 0 else None
                shown, auction, assigned_at, block = k, None, None, None
                converged_since = None
                if scene.steps:
                    previous = goal_set
                    goal_set, goal_colors, shown_timing = _step_goals(scene, k, movers.pixels)
                    motion, t_start = shown_timing.motion, shown_timing.t_start
                    timing = {e: v for e, v in timing.items() if e == assigned_image + 1} | {k + 1: shown_timing}
                    if budget and last_auction is not None:  # as the agents with bounded rounds: the warm start
                        pixels = movers.pixels.tolist()
                        auction = Participant(k, goal_set, pixels, pixels, params.assign_eps, params.assign_hysteresis)
                        assignment = warm_start(auction, last_auction, previous, goal_set, assignment)
                        assigned_image, assigned_set, assigned_colors = shown, goal_set, goal_colors
            clock.lap("other")
            measured = as_sent(tracker.measure(world.poses))  # the poses as the tracker's messages carry them
            # a moving goal set is auctioned with the positions mapped back to t = 0 (GoalMotion.to_initial_frame)
            bid_from = measured[:, :2] if motion is None else motion.to_initial_frame(measured[:, :2], t - t_start)
            clock.lap("tracker")
            pending = None  # this tick's auction, running beside the control core
            # the last tick is a pose with no command to follow (the world asks the agents for none)
            due = tick < steps and (assigned_at is None or t - assigned_at >= params.assign_period - 1e-9)
            if (
                scene.steps
                and budget
                and tick < steps
                and isinstance(auction, Participant)
                and (due or block is not None)
            ):
                # The agents' lock-step rounds, at most `budget` a tick: a block may span ticks, and
                # its agreement takes effect at the tick of its last round (agent.core.rounds). A cold
                # start (no auction yet) runs to its agreement below: no goal to drive to meanwhile.
                if block is None:
                    block, assigned_at = BlockRounds(auction, bid_from), t
                if play(block, budget):
                    block = None
                    agreed = auction.agreed
                    assignment = np.full(n, -1)
                    assignment[auction.own_ids] = [agreed.get(r, -1) for r in auction.own]
                    assigned_image, assigned_set, assigned_colors = shown, goal_set, goal_colors
            elif scene.steps and due:
                # Paper 5.1: re-assign every iteration (every assign_period, as the agents do),
                # warm-started from the previous prices, with the hysteresis Delta C against flip-flops
                # from tracking noise.
                if scene.assignment == "optimal":
                    assignment = movers.pixel_assignment(
                        optimal_assignment(
                            bid_from[movers.pixels],
                            goal_set,
                            None if assigned_at is None else assignment[movers.pixels],
                            params.assign_hysteresis,
                        )
                    )
                elif auction is None:  # a new image: a cold start (the old prices mean nothing)
                    pixels = movers.pixels.tolist()
                    auction = new_auction(k, goal_set, pixels, pixels, params, link.reach)
                    assignment = auction_assignment(auction, bid_from)
                else:
                    pending = beside.submit(clock.timed_beside, auction_assignment, auction, bid_from)
                assigned_at = t
                assigned_image, assigned_set, assigned_colors = shown, goal_set, goal_colors
            clock.lap("assignment")
            world.check()  # the contacts of the last step
            clock.lap("world")
            nbs = link.neighbours(ids, measured[:, :2], t, params.neighbour_dist, params.max_neighbours)
            clock.lap("neighbours")
            if pending is not None and not overlap:
                assignment, pending = pending.result(), None
                clock.lap("assignment")
            # While the auction runs, every robot decides on the goal it holds: a robot's decision
            # depends on its own goal and its neighbours' states only, and most robots keep their
            # goals, so only the robots whose goal changed decide again.
            goals = goals_of(assignment, measured)
            intent = intend(params, measured[:, :2], t, goals.goal0, goals.key, timing, memory)
            clock.lap("preferred")
            decide_now = partial(
                act,
                params,
                seed=scene.seed,
                tick=tick,
                watch_deadlocks=auction is not None,
                reach=link.reach,
            )
            decision = decide_now(ids, measured[:, :2], measured[:, 2], intent, memory, nbs, segments)
            clock.lap("control")
            # ... and the world moves on those commands: stepped again from here if the auction changed any
            pose, moving = world.poses, world.velocities  # this tick's, recorded below
            before = world.snapshot()
            velocity_next = _move(world, movers, decision.step, pose, t, params.dt)
            clock.lap("world")
            if pending is not None:
                settled = pending.result()
                clock.lap("assignment")
                if not np.array_equal(settled, assignment):
                    assignment = settled
                    goals = goals_of(assignment, measured)
                    again = intend(params, measured[:, :2], t, goals.goal0, goals.key, timing, memory)
                    clock.lap("preferred")
                    _step_again(
                        decision, _changed_rows(intent, again), again, decide_now, measured, memory, nbs, segments
                    )
                    clock.lap("control")
                    world.restore(before)
                    velocity_next = _move(world, movers, decision.step, pose, t, params.dt)
                    clock.lap("world")
            if auction is not None:
                for robot in np.flatnonzero(decision.deadlocked).tolist():
                    epoch, goal = decision.intent.key[robot].tolist()
                    if epoch == shown + 1:  # a goal of an earlier set is no goal of this auction
                        auction.penalise(robot, goal, params.deadlock_cost)
                        penalties += 1
            goal, has_goal = decision.intent.goal, goals.has_goal
            memory = decision.memory
            rec["t"].append(t)
            rec["pose"].append(pose)
            rec["velocity"].append(moving)
            rec["color"].append(goals.color)
            rec["goal"].append(goal)
            rec["assignment"].append(assignment)
            rec["step"].append(k)
            if view is not None:  # sim.outputs.view.SwarmView: the live view, one batch a tick
                view.tick(tick, t, pose, goals.color, goal)
            clock.lap("record")
            # Converging ends the run only once the last image is up: earlier images keep their hold.
            if (
                k == last_step
                and scene.ends_on_convergence
                and has_goal.any()
                and np.all(_goal_error(pose, goal)[has_goal] <= params.goal_tolerance)
            ):
                converged_since = t if converged_since is None else converged_since
                if t - converged_since >= scene.converge_hold:
                    end_reason = "converged"
                    world.restore(before)  # the run ends here: no last step
                    break
            else:
                converged_since = None
            if tick == steps:
                world.restore(before)
                break
            # what the robots broadcast this tick: heard by their neighbours at the next
            link.broadcast(_states(params, measured, pose, velocity_next, t, movers))
            fallbacks += int(decision.step.fallback.sum())
            clock.lap("other")
            if progress is not None and time.time() - last_say >= 1.0:
                last_say = time.time()
                at_goal = int(np.sum(_goal_error(pose, goal) <= params.goal_tolerance))
                held = f"at goal {at_goal}/{int(has_goal.sum())}" if has_goal.any() else "waiting for the goal set"
                print(
                    f"[{scene.name}] central t={t:6.1f} s  step {k}  {held}  contacts {len(world.contacts)}",
                    file=progress,
                    flush=True,
                )
            clock.lap("other")
    finally:
        beside.shutdown()
    arrays = {k: np.stack(v) if k != "t" else np.array(v) for k, v in rec.items()}
    arrays["color"] = arrays["color"].astype(np.uint8)
    arrays["step"] = arrays["step"].astype(np.int64)
    return Outcome(
        arrays, list(world.contacts), float(world.min_clearance), fallbacks, penalties, end_reason, time.time() - wall0
    )


def run_central(
    scene: Scene,
    out: Path,
    *,
    video: bool = True,
    plots: bool = True,
    progress: TextIO | None = sys.stderr,
    clock: StepClock | None = None,
    overlap: bool = True,
    reach: float = np.inf,
    view: Any = None,
) -> Path:
    """Run the scene with every robot in this process (``simulate``); returns the run directory.
    ``reach``: the robots' communication range (m)."""
    run_dir = RunDir(out)
    try:
        link = InProcessLink(scene.robots, reach=reach)
        outcome = simulate(scene, link=link, progress=progress, clock=clock, overlap=overlap, view=view)
        params, _ = world_of(scene)
        contacts = [
            {"kind": c.kind, "i": c.i, "j": c.j, "t_start": c.t_start, "t_end": c.t_end, "max_depth": c.max_depth}
            for c in outcome.contacts
        ]
        extra = dict(
            engine="central",
            end_reason=outcome.end_reason,
            complete=True,
            orca_fallbacks=outcome.fallbacks,
            deadlock_penalties=outcome.penalties,
            min_clearance_substep_m=outcome.min_clearance if np.isfinite(outcome.min_clearance) else None,
        )
        how = RunOutcome(outcome.wall_s, contacts, reach=reach, extra=extra)
        return write_run(run_dir, scene, params, outcome.arrays, how, video=video, plots=plots)
    except BaseException:
        run_dir.abort()
        raise


def _scene_goals(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The scene's own goals, one per robot, as the agents decode them from the coordinator's message
    (NaN rows and grey: no goal of its own)."""
    goals = scene.goal_positions
    message = scene_goal_message(scene)
    if message is None:
        return goals, np.full((len(goals), 3), 40, np.uint8)
    heard = _as_heard(message)
    has_goal = np.isfinite(goals).all(axis=1)[:, None]
    return np.where(has_goal, heard.positions, np.nan), np.where(has_goal, heard.colors, 40).astype(np.uint8)


def _step_goals(scene: Scene, k: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, GoalTiming]:
    """Step k's goal set, colours and timing as the agents decode them from the coordinator's message."""
    goals, colors = scene_goal_set(scene, k, len(pixels))
    message = Goals(1, 0, goals, colors, pixels, step_timing(scene, k), step_motion(scene, k))
    heard = _as_heard(message)
    return heard.positions, heard.colors, timing_of(heard)


def _as_heard(message: Goals) -> Goals:
    """A goal set as the agents decode it (the wire rounds its positions and timing)."""
    heard = decode(message.encode(), Goals)
    if not isinstance(heard, Goals):
        raise ValueError(f"goal set {message.epoch} does not survive its own encoding")
    return heard


def _states(params, measured: np.ndarray, pose: np.ndarray, velocity: np.ndarray, t: float, movers: Movers) -> Heard:
    """What every robot broadcasts this tick: its tracked position and its collision-free velocity (a
    scripted mover: its true position and scripted velocity, as the world process broadcasts them)."""
    n = len(measured)
    position = np.where(movers.cooperative[:, None], measured[:, :2], pose[:, :2])
    return Heard(
        np.arange(n),
        as_sent(position),
        as_sent(velocity),
        as_sent(np.full(n, params.radius)),
        np.full(n, t),
        movers.cooperative,
    )


def _goal_error(pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """(N,) each robot's distance from its goal (NaN: none)."""
    return np.hypot(*(pose[:, :2] - goal).T)


def _changed_rows(old: Intent, new: Intent) -> np.ndarray:
    """The robots whose goal, its key or preferred velocity differ, to the bit, between two intents."""

    def bits(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=float).view(np.int64)

    changed = (bits(old.goal) != bits(new.goal)).any(axis=1) | (old.key != new.key).any(axis=1)
    changed |= (bits(old.preferred) != bits(new.preferred)).any(axis=1)
    return np.flatnonzero(changed)


def _move(world, movers: Movers, res, pose: np.ndarray, t: float, dt: float) -> np.ndarray:
    """Command the robots (scripted movers along their script) and step the world; returns the
    collision-free velocities their neighbours hear next tick. The step's contacts are looked for
    while the next auction runs (World.check)."""
    command, velocity = movers.commands(res.command, res.velocity, pose, t, dt)
    world.set_commands(as_sent(command))
    world.step(dt, check=False)
    return velocity


def _step_again(
    decision: Decision,
    rows: np.ndarray,
    intent: Intent,
    decide_now,
    measured: np.ndarray,
    memory: Memory,
    nbs: NeighbourStates,
    segments: np.ndarray,
) -> None:
    """The robots at ``rows`` decide again on their new intent; the decision takes the new intent for
    every robot (the others' is the same, to the bit). Per robot, a decision does not depend on
    the rest of the batch."""
    if rows.size:
        again = decide_now(
            rows, measured[rows, :2], measured[rows, 2], intent.rows(rows), memory.rows(rows), nbs.rows(rows), segments
        )
        decision.put(rows, again)
    decision.intent = intent
    decision.memory.hold_left, decision.memory.hold_for = intent.hold_left, intent.hold_for
