"""The central engine: every robot stepped by the same control core in one call, perfect information.

No messages: each tick every robot sees every neighbour's current state (tracked position, its
collision-free velocity, age zero), as RVO2 does. It is the reference against which decentralisation
is studied (`--engine central` against `--engine distributed`), and the fast path for large swarms.

Image scenes play their steps: at time t the robots are auctioned (paper 5.1) onto the goal set of
the step whose hold contains t; the `step` array records which one, tick by tick. The auction is the
agents' own (agent.core.bidder) with one participant holding every robot: each `assign_period` the
next block of epsilon-scaling phases starts from the measured positions, warm from the last prices,
and settles in this process without messages (`auction_assignment`; its rounds are compiled,
agent.core.jacobi), on a second thread while this one searches neighbours, steps the control core
and moves the world on the goals the robots hold: a robot's control depends on its own goal and its
neighbours' last states only, so only the robots whose goal the auction changed are stepped again,
and the run is the one that waiting for the auction would give, to the bit. Animation keyframes
are steps whose robots hold eq. 27's velocity (agent.core.animation); a dynamic image's goals move by
eq. 28 and the robots drive with the goals' velocity fed forward (agent.core.goal_motion), auctioned
on the published goal set with their positions mapped back, as the agents do (agent.runtime).
"""

from __future__ import annotations

import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple, TextIO

import numpy as np
from scipy.optimize import linear_sum_assignment

from agent.core.animation import frame_hold, iterations_left
from agent.core.bidder import Participant
from agent.core.goal_motion import GoalMotion, tracking_velocity
from agent.core.step import NeighbourStates, control_step, static_segments
from coordinator.motion import StepMotion
from coordinator.scene import Scene, scene_goal_set
from coordinator.service import palette

from .movers import Movers
from .output import write_run
from .proximity import gather, nearest_within
from .rundir import RunDir
from .stepclock import StepClock
from .tracker import tracker_of, world_of


def nearest_neighbours(
    position: np.ndarray,
    velocity: np.ndarray,
    radius: float,
    reach: float,
    max_neighbours: int,
    cooperative: np.ndarray | None = None,
) -> NeighbourStates:
    """Every robot's nearest neighbours within reach, from one snapshot (perfect information)."""
    n = len(position)
    m = min(max_neighbours, n - 1)
    if m <= 0:
        return NeighbourStates.empty(n, 0)
    position = np.ascontiguousarray(position, dtype=float)
    idx = nearest_within(position, float(reach), m)
    # a scripted mover avoids nobody: its neighbours take full responsibility
    coop = np.ones(n, bool) if cooperative is None else np.ascontiguousarray(cooperative, dtype=bool)
    pos, vel, valid, coop = gather(idx, position, np.ascontiguousarray(velocity, dtype=float), coop)
    return NeighbourStates(pos, vel, np.full((n, m), float(radius)), np.zeros((n, m)), valid, coop)


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


def auction_assignment(auction: Participant, position: np.ndarray) -> np.ndarray:
    """Goal index per robot (-1: none): the auction's next block of phases (paper 5.1.1) settled on
    these positions (rows by robot id), warm from the last prices, as the agents settle theirs; a
    robot keeps its goal unless another is better by epsilon_A + Delta C. The participant holds
    every robot, so every phase's snapshot is its own board."""
    assignment = np.full(len(position), -1)
    assignment[auction.own_ids] = auction.settle_alone(position)
    return assignment


def run_central(
    scene: Scene,
    out: Path,
    *,
    video: bool = True,
    progress: TextIO | None = sys.stderr,
    clock: StepClock | None = None,
    overlap: bool = True,
) -> Path:
    """Run the scene with every robot in this process; returns the run directory. ``clock`` (if
    given) receives the wall and CPU time per part of each control step (bench/bench_large.py).
    ``overlap``: a warm auction runs on a second thread while this one searches neighbours and steps
    the control core on the goals the robots hold, and only the robots whose goal changed are
    stepped again (the same run, to the bit, as without: tests/test_central_overlap.py)."""
    params, world = world_of(scene)
    tracker = tracker_of(scene)
    segments = static_segments(scene.arena, scene.obstacles)
    n = scene.robots
    movers = Movers(scene)  # scripted movers and pursuers: not robot pixels (sim.movers)
    ids = np.arange(n)
    goal_set = scene.goal_positions  # the scene's goals; image scenes: the shown step's goal set
    has_goal = np.isfinite(goal_set).all(axis=1)
    goal_colors = np.where(has_goal[:, None], palette(n), 40).astype(np.uint8)
    auction: Participant | None = None  # image scenes: the auction of the shown goal set
    assignment = np.where(has_goal, ids, -1)  # goal index per robot (scene goals: its own)
    velocity = np.zeros((n, 2))
    left, hold_for = np.zeros(n, np.int64), np.full(n, -1)  # eq. 27's hold per robot
    motion: GoalMotion | None = None
    t_start = 0.0  # when the shown step started
    assigned_at: float | None = None  # when the shown goal set was last assigned
    if any(e["kind"] == "fail" for e in scene.events):
        raise ValueError("fail events (agent processes killed) need the distributed engine")
    events = sorted(scene.events, key=lambda e: e["t"])
    last_step = max(len(scene.steps) - 1, 0)
    shown = -1  # the image step whose goal set the auction works on
    rec: dict[str, list] = {"t": [], "pose": [], "velocity": [], "color": [], "goal": [], "assignment": [], "step": []}
    steps = round(scene.duration / params.dt)
    fallbacks, converged_since, end_reason = 0, None, "duration"
    run_dir = RunDir(out)
    clock = clock if clock is not None else StepClock()
    wall0 = last_say = time.time()
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
                shown, auction, assigned_at = k, None, None
                converged_since = None
                hold_for[:] = -1  # every robot's goal is new: a keyframe's hold restarts
                if scene.steps:
                    goal_set, goal_colors = scene_goal_set(scene, k, len(movers.pixels))
                    motion, t_start = goal_motion(scene.steps[k].motion), scene.step_starts[k]
            clock.lap("other")
            measured = tracker.measure(world.poses)
            clock.lap("tracker")
            pending = None  # this tick's auction, running beside the control core
            if scene.steps and (assigned_at is None or t - assigned_at >= params.assign_period - 1e-9):
                # Paper 5.1: re-assign every iteration (every assign_period, as the agents do),
                # warm-started from the previous prices, with the hysteresis Delta C against flip-flops
                # from tracking noise. A moving goal set is auctioned with the positions mapped back
                # to t = 0 (GoalMotion.to_initial_frame).
                bid_from = measured[:, :2] if motion is None else motion.to_initial_frame(measured[:, :2], t - t_start)
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
                    auction = Participant(k, goal_set, pixels, pixels, params.assign_eps, params.assign_hysteresis)
                    assignment = auction_assignment(auction, bid_from)
                else:
                    pending = beside.submit(clock.timed_beside, auction_assignment, auction, bid_from)
                assigned_at = t
            clock.lap("assignment")
            world.check()  # the contacts of the last step
            clock.lap("world")
            nbs = nearest_neighbours(
                measured[:, :2],
                velocity,
                params.radius,
                params.neighbour_dist,
                params.max_neighbours,
                movers.cooperative,
            )
            clock.lap("neighbours")
            if pending is not None and not overlap:
                assignment, pending = pending.result(), None
                clock.lap("assignment")
            # While the auction runs, the control core steps every robot toward the goal it holds: a
            # robot's control depends on its own goal and on the neighbours' last states only, and
            # most robots keep their goals, so only the robots whose goal changed are stepped again.
            plan = _plan(
                scene,
                params,
                k,
                motion,
                t - t_start,
                t,
                measured,
                goal_set,
                goal_colors,
                assignment,
                hold_for,
                left,
                movers,
            )
            clock.lap("preferred")
            res = control_step(
                params,
                ids,
                measured[:, :2],
                measured[:, 2],
                velocity,
                plan.goal,
                nbs,
                segments,
                seed=scene.seed,
                tick=tick,
                preferred=plan.preferred,
                compiled=True,
            )
            clock.lap("control")
            # ... and the world moves on those commands: stepped again from here if the auction changed any
            pose, moving = world.poses, world.velocities  # this tick's, recorded below
            before = world.snapshot()
            velocity_next = _move(world, movers, res, pose, t, params.dt)
            clock.lap("world")
            if pending is not None:
                settled = pending.result()
                clock.lap("assignment")
                if not np.array_equal(settled, assignment):
                    guess, assignment = plan, settled
                    plan = _plan(
                        scene,
                        params,
                        k,
                        motion,
                        t - t_start,
                        t,
                        measured,
                        goal_set,
                        goal_colors,
                        assignment,
                        hold_for,
                        left,
                        movers,
                    )
                    clock.lap("preferred")
                    _step_again(
                        res,
                        _changed_rows(guess, plan),
                        params,
                        ids,
                        measured,
                        velocity,
                        plan,
                        nbs,
                        segments,
                        scene.seed,
                        tick,
                    )
                    clock.lap("control")
                    world.restore(before)
                    velocity_next = _move(world, movers, res, pose, t, params.dt)
                    clock.lap("world")
            goal, color, left, has_goal = plan.goal, plan.color, plan.left, plan.has_goal
            hold_for = assignment.copy()
            rec["t"].append(t)
            rec["pose"].append(pose)
            rec["velocity"].append(moving)
            rec["color"].append(color)
            rec["goal"].append(goal)
            rec["assignment"].append(assignment)
            rec["step"].append(k)
            clock.lap("record")
            err = np.hypot(*(pose[:, :2] - goal).T)
            # Converging ends the run only once the last image is up: earlier images keep their hold.
            if (
                k == last_step
                and scene.ends_on_convergence
                and has_goal.any()
                and np.all(err[has_goal] <= params.goal_tolerance)
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
            velocity = velocity_next
            fallbacks += int(res.fallback.sum())
            clock.lap("other")
            if progress is not None and time.time() - last_say >= 1.0:
                last_say = time.time()
                print(
                    f"[{scene.name}] central t={t:6.1f} s  step {k}  at goal "
                    f"{int(np.sum(err <= params.goal_tolerance))}/{int(has_goal.sum())}  "
                    f"contacts {len(world.contacts)}",
                    file=progress,
                    flush=True,
                )
            clock.lap("other")
        arrays = {k: np.stack(v) if k != "t" else np.array(v) for k, v in rec.items()}
        arrays["color"] = arrays["color"].astype(np.uint8)
        arrays["step"] = arrays["step"].astype(np.int64)
        contacts = [
            {"kind": c.kind, "i": c.i, "j": c.j, "t_start": c.t_start, "t_end": c.t_end, "max_depth": c.max_depth}
            for c in world.contacts
        ]
        return write_run(
            run_dir,
            scene,
            params,
            arrays,
            wall_s=time.time() - wall0,
            contacts=contacts,
            video=video,
            engine="central",
            end_reason=end_reason,
            complete=True,
            orca_fallbacks=fallbacks,
            min_clearance_substep_m=world.min_clearance if np.isfinite(world.min_clearance) else None,
        )
    except BaseException:
        run_dir.abort()
        raise
    finally:
        beside.shutdown()


class Plan(NamedTuple):
    """What one tick's goal assignment asks of the robots (rows by robot)."""

    goal: np.ndarray  # (N, 2) where each robot heads now (NaN: no goal)
    color: np.ndarray  # (N, 3) its LED colour
    preferred: np.ndarray | None  # (N, 2) where eq. 9 does not apply (NaN rows: eq. 9)
    left: np.ndarray  # (N,) iterations left of eq. 27's hold
    has_goal: np.ndarray  # (N,) bool: a pixel with a goal (what convergence is judged on)


def _plan(
    scene: Scene,
    params,
    k: int,
    motion: GoalMotion | None,
    t_rel: float,
    t: float,
    measured: np.ndarray,
    goal_set: np.ndarray,
    goal_colors: np.ndarray,
    assignment: np.ndarray,
    hold_for: np.ndarray,
    left: np.ndarray,
    movers: Movers,
) -> Plan:
    """The goals, colours and preferred velocities that an assignment gives this tick (pure: the
    engine computes it for the assignment held while the auction runs, and again if that changed)."""
    preferred = None
    if scene.steps:
        has_goal = assignment >= 0
        goal = np.where(has_goal[:, None], goal_set[assignment], np.nan)
        color = np.where(has_goal[:, None], goal_colors[assignment], 40).astype(np.uint8)
        preferred, left = _preferred(
            scene, params, k, motion, t_rel, t, measured[:, :2], goal, assignment, hold_for, left
        )
        if motion is not None:
            goal = motion.positions(goal, t_rel)
    else:
        goal, color, has_goal = goal_set, goal_colors, np.isfinite(goal_set).all(axis=1)
    goal, color = movers.goals(goal, color, measured)  # a pursuer heads for its target
    return Plan(goal, color, preferred, left, has_goal)


def _changed_rows(old: Plan, new: Plan) -> np.ndarray:
    """The robots whose goal or preferred velocity differ, to the bit, between two plans."""

    def bits(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=float).view(np.int64)

    changed = (bits(old.goal) != bits(new.goal)).any(axis=1)
    if new.preferred is not None:
        changed |= (bits(old.preferred) != bits(new.preferred)).any(axis=1)
    return np.flatnonzero(changed)


def _move(world, movers: Movers, res, pose: np.ndarray, t: float, dt: float) -> np.ndarray:
    """Command the robots (scripted movers along their script) and step the world; returns the
    collision-free velocities their neighbours hear next tick. The step's contacts are looked for
    while the next auction runs (World.check)."""
    command, velocity = movers.commands(res.command, res.velocity, pose, t, dt)
    world.set_commands(command)
    world.step(dt, check=False)
    return velocity


def _step_again(
    res,
    rows: np.ndarray,
    params,
    ids: np.ndarray,
    measured: np.ndarray,
    velocity: np.ndarray,
    plan: Plan,
    nbs: NeighbourStates,
    segments: np.ndarray,
    seed: int,
    tick: int,
) -> None:
    """Step the control core again for the robots at ``rows`` (their plan changed) and write their
    results into ``res``: per robot, control_step does not depend on the rest of the batch."""
    if rows.size == 0:
        return
    again = control_step(
        params,
        ids[rows],
        measured[rows, :2],
        measured[rows, 2],
        velocity[rows],
        plan.goal[rows],
        nbs.rows(rows),
        segments,
        seed=seed,
        tick=tick,
        preferred=None if plan.preferred is None else plan.preferred[rows],
        compiled=True,
    )
    res.velocity[rows], res.command[rows] = again.velocity, again.command
    res.pref_velocity[rows], res.fallback[rows] = again.pref_velocity, again.fallback


def _preferred(
    scene: Scene,
    params,
    k: int,
    motion: GoalMotion | None,
    t_rel: float,
    t: float,
    position: np.ndarray,
    goal0: np.ndarray,
    assignment: np.ndarray,
    hold_for: np.ndarray,
    left: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Preferred velocities where eq. 9 does not apply (NaN rows), as agent.runtime computes them:
    toward a moving goal v_goal + eq. 9 (eq. 28); in a keyframe eq. 27, held K_f iterations from
    the robot's goal change. Returns (preferred, left)."""
    if motion is not None:
        pref = tracking_velocity(
            position,
            motion.positions(goal0, t_rel),
            motion.velocities(goal0, t_rel),
            params.v_pref,
            params.k_a,
            params.v_max,
        )
        return pref, np.zeros_like(left)
    period = scene.steps[k].frame_period
    iterations = iterations_left(scene.step_starts[k], period, t, params.dt) if period > 0 else 0
    restart = assignment != hold_for
    return frame_hold(position, goal0, restart, np.full(len(position), iterations), left, params.v_max, params.dt)
