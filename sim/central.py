"""The central engine: every robot stepped by the same control core in one call, perfect information.

No messages: each tick every robot sees every neighbour's current state (tracked position, its
collision-free velocity, age zero), as RVO2 does. It is the reference against which decentralisation
is studied (`--engine central` against `--engine distributed`), and the fast path for large swarms.

Image scenes play their steps: at time t the robots are auctioned (paper 5.1) onto the goal set of
the step whose hold contains t; the `step` array records which one, tick by tick.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import TextIO

import numpy as np
from scipy.spatial import cKDTree

from agent.core.auction import solve
from agent.core.step import NeighbourStates, control_step, static_segments
from coordinator.scene import Scene, scene_goal_set
from coordinator.service import palette

from .output import write_run
from .rundir import RunDir
from .tracker import tracker_of, world_of



def nearest_neighbours(position: np.ndarray, velocity: np.ndarray, radius: float, reach: float,
                       max_neighbours: int) -> NeighbourStates:
    """Every robot's nearest neighbours within reach, from one snapshot (perfect information)."""
    n = len(position)
    m = min(max_neighbours, n - 1)
    out = NeighbourStates.empty(n, m)
    if m <= 0:
        return out
    dist, idx = cKDTree(position).query(position, k=m + 1, distance_upper_bound=reach)
    dist, idx = dist[:, 1:], idx[:, 1:]  # drop self
    valid = np.isfinite(dist)
    safe = np.where(valid, idx, 0)
    out.position[:] = position[safe]
    out.velocity[:] = velocity[safe]
    out.radius[:] = radius
    out.valid[:] = valid
    return out


def run_central(scene: Scene, out: Path, *, video: bool = True, progress: TextIO | None = sys.stderr) -> Path:
    params, world = world_of(scene)
    tracker = tracker_of(scene)
    segments = static_segments(scene.arena, scene.obstacles)
    n = scene.robots
    ids = np.arange(n)
    goal = scene.goal_positions
    has_goal = np.isfinite(goal).all(axis=1)
    color = np.where(has_goal[:, None], palette(n), 40).astype(np.uint8)
    view = None  # image scenes: the robots' assignment to the goal set, re-auctioned every iteration
    assignment = np.where(has_goal, ids, -1)  # goal index per robot (scene goals: its own)
    velocity = np.zeros((n, 2))
    if any(e["kind"] == "fail" for e in scene.events):
        raise ValueError("fail events (agent processes killed) need the distributed engine")
    events = sorted(scene.events, key=lambda e: e["t"])
    last_step = max(len(scene.steps) - 1, 0)
    shown = -1  # the image step whose goal set the auction works on
    rec: dict[str, list] = {"t": [], "pose": [], "velocity": [], "color": [], "goal": [], "assignment": [],
                            "step": []}
    steps = round(scene.duration / params.dt)
    fallbacks, converged_since, end_reason = 0, None, "duration"
    run_dir = RunDir(out)
    wall0 = last_say = time.time()
    try:
        for tick in range(steps + 1):
            t = tick * params.dt
            while events and events[0]["t"] <= t + 1e-9:
                ev = events.pop(0)
                world.teleport(ev["robot"], tuple(ev["pose"]))
            k = scene.step_at(t)
            if k != shown:  # a new image: its goal set, and a fresh auction (the old prices mean nothing)
                shown, view = k, None
                converged_since = None
                if scene.steps:
                    goal_set, goal_colors = scene_goal_set(scene, k, n)
            measured = tracker.measure(world.poses)
            if scene.steps:
                # Paper 5.1: re-assign every iteration, warm-started from the previous prices, with
                # the hysteresis Delta C against flip-flops from tracking noise.
                view, _ = solve({i: measured[i, :2] for i in range(n)}, goal_set, params.assign_eps,
                                view=view, hysteresis=params.assign_hysteresis)
                owner = view.owner
                assignment = np.full(n, -1)
                assignment[owner[owner >= 0]] = np.flatnonzero(owner >= 0)
                has_goal = assignment >= 0
                goal = np.where(has_goal[:, None], goal_set[assignment], np.nan)
                color = np.where(has_goal[:, None], goal_colors[assignment], 40).astype(np.uint8)
            rec["t"].append(t)
            rec["pose"].append(world.poses)
            rec["velocity"].append(world.velocities)
            rec["color"].append(color)
            rec["goal"].append(goal)
            rec["assignment"].append(assignment)
            rec["step"].append(k)
            err = np.hypot(*(world.poses[:, :2] - goal).T)
            # Converging ends the run only once the last image is up: earlier images keep their hold.
            if k == last_step and has_goal.any() and np.all(err[has_goal] <= params.goal_tolerance):
                converged_since = t if converged_since is None else converged_since
                if t - converged_since >= scene.converge_hold:
                    end_reason = "converged"
                    break
            else:
                converged_since = None
            if tick == steps:
                break
            nbs = nearest_neighbours(measured[:, :2], velocity, params.radius, params.neighbour_dist,
                                     params.max_neighbours)
            res = control_step(params, ids, measured[:, :2], measured[:, 2], velocity, goal, nbs, segments,
                               seed=scene.seed, tick=tick)
            velocity = res.velocity
            fallbacks += int(res.fallback.sum())
            for i in range(n):
                world.set_command(i, float(res.command[i, 0]), float(res.command[i, 1]))
            world.step(params.dt)
            if progress is not None and time.time() - last_say >= 1.0:
                last_say = time.time()
                print(f"[{scene.name}] central t={t:6.1f} s  step {k}  at goal "
                      f"{int(np.sum(err <= params.goal_tolerance))}/{int(has_goal.sum())}  "
                      f"contacts {len(world.contacts)}", file=progress, flush=True)
        arrays = {k: np.stack(v) if k != "t" else np.array(v) for k, v in rec.items()}
        arrays["color"] = arrays["color"].astype(np.uint8)
        arrays["step"] = arrays["step"].astype(np.int64)
        contacts = [{"kind": c.kind, "i": c.i, "j": c.j, "t_start": c.t_start, "t_end": c.t_end,
                     "max_depth": c.max_depth} for c in world.contacts]
        return write_run(run_dir, scene, params, arrays, wall_s=time.time() - wall0, contacts=contacts, video=video,
                         engine="central", end_reason=end_reason, complete=True, orca_fallbacks=fallbacks,
                         min_clearance_substep_m=world.min_clearance if np.isfinite(world.min_clearance) else None)
    except BaseException:
        run_dir.abort()
        raise
