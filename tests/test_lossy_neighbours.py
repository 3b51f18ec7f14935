"""ORCA on lost and late neighbour states (issue 3), without the bus: every robot steps in one loop,
each hearing each neighbour's state of the tick before unless a seeded draw loses it or makes it a tick
late, as an agent under ``--faults state:drop=...,delay=...`` does (it does not wait for states then).
Deterministic and a few seconds per run; the end-to-end twin over zenoh is in test_collision_avoidance.

The crowd at the circle's centre is where it matters: with the old hard lines, a neighbour heard late
(radius grown by how far it may have strayed) could make them infeasible, and robots touched.
"""
from __future__ import annotations

import numpy as np
import pytest

from agent.core.step import NeighbourStates, control_step
from coordinator.scene import load_scene
from sim.tracker import tracker_of, world_of

UNHEARD = -(10**9)


def run_lossy(scene_path, drop: float, late: float, seed: int) -> tuple[int, float]:
    """(contacts, smallest clearance in metres) of the scene with states lost with probability
    ``drop`` and a tick late with probability ``late`` (independently per sender and receiver)."""
    scene = load_scene(str(scene_path), seed=seed)
    params, world = world_of(scene)
    tracker = tracker_of(scene)
    n, m = scene.robots, params.max_neighbours
    ids, goal = np.arange(n), scene.goal_positions
    rng = np.random.default_rng(seed)
    velocity = np.zeros((n, 2))
    heard_tick = np.full((n, n), UNHEARD)  # [receiver, sender]: tick of the newest state heard
    heard_pos, heard_vel = np.zeros((n, n, 2)), np.zeros((n, n, 2))
    sent: list[tuple[np.ndarray, np.ndarray]] = []  # states broadcast at each tick: positions, velocities
    late_ones = np.zeros((n, n), bool)
    for tick in range(round(scene.duration / params.dt)):
        measured = tracker.measure(world.poses)
        for age, arrive in ((2, late_ones), (1, None)):  # the late ones of tick-2 first, then tick-1's
            if tick < age:
                continue
            if arrive is None:
                u = rng.random((n, n))
                arrive, late_ones = u >= drop + late, (u >= drop) & (u < drop + late)
            pos, vel = sent[tick - age]
            heard_tick = np.where(arrive, tick - age, heard_tick)
            heard_pos = np.where(arrive[..., None], pos[None], heard_pos)
            heard_vel = np.where(arrive[..., None], vel[None], heard_vel)
        nb = NeighbourStates.empty(n, m)
        for i in range(n):
            d = np.hypot(*(heard_pos[i] - measured[i, :2]).T)
            cand = np.flatnonzero((heard_tick[i] > UNHEARD) & (ids != i) & (d <= params.neighbour_dist))
            cand = cand[np.argsort(d[cand], kind="stable")[:m]]
            k = len(cand)
            nb.position[i, :k], nb.velocity[i, :k] = heard_pos[i, cand], heard_vel[i, cand]
            nb.radius[i, :k], nb.valid[i, :k] = params.radius, True
            nb.age[i, :k] = (tick - heard_tick[i, cand]) * params.dt
        res = control_step(params, ids, measured[:, :2], measured[:, 2], velocity, goal, nb, None,
                           seed=scene.seed, tick=tick)
        velocity = res.velocity
        sent.append((measured[:, :2].copy(), velocity.copy()))
        world.set_commands(res.command)
        world.step(params.dt)
    return len(world.contacts), float(world.min_clearance)


def circle_scene(tmp_path, robots: int, kinematics: str) -> str:
    path = tmp_path / "circle.toml"
    path.write_text(f'robots = {robots}\nduration = 25\n[robot]\nkinematics = "{kinematics}"\n'
                    '[layout]\nkind = "circle"\nspacing = 0.2\n[goals]\nkind = "antipodal"\n')
    return path


@pytest.mark.parametrize("kinematics, robots, drop, late, seed", [
    ("holonomic", 50, 0.1, 0.5, 0), ("holonomic", 50, 0.1, 0.5, 1), ("holonomic", 50, 0.3, 0.5, 4),
    ("diffdrive", 30, 0.3, 0.5, 0)])
def test_lost_and_late_states_cause_no_contact(tmp_path, kinematics, robots, drop, late, seed):
    contacts, clearance = run_lossy(circle_scene(tmp_path, robots, kinematics), drop, late, seed)
    assert contacts == 0 and clearance > 0, (contacts, clearance)
