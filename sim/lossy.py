"""Lost and late neighbour states without the bus: a study tool for what message loss does to ORCA.

Every robot steps in one loop (like the central engine), but each robot hears each neighbour's
state of the tick before only if a seeded draw neither loses it (``drop``) nor makes it a tick late
(``late``, heard at the tick after). That is what an agent under ``--faults state:drop=P,delay=S``
lives with (it does not wait for states then), made deterministic and fast: seconds per run instead
of minutes, so sweeps over loss rates and seeds are cheap (bench/bench_loss.py). Each robot keeps the
newest state it heard of each neighbour and its age, exactly as agent.neighbour_table does, and
the control step is the agents' own (agent.core.step.control_step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.core.step import NeighbourStates, control_step
from coordinator.scene import Scene, scene_from_dict

from .tracker import tracker_of, world_of

_UNHEARD = -(10**9)


@dataclass
class LossyResult:
    contacts: int  # pair-contact events (true poses, world sub-steps)
    min_clearance: float  # m, smallest gap between bodies over the run (negative: overlap)
    fallbacks: int  # robot-ticks where ORCA's program was infeasible
    robot_ticks: int
    heard_on_time: float  # share of (receiver, sender) states heard at the next tick


def circle_crossing(robots: int, kinematics: str, seed: int, duration: float = 25.0) -> Scene:
    """The study's case: robots on a circle (0.2 m apart) crossing to the antipodal point, through
    the crowd at the centre, where lost states matter most; 25 s takes them past it."""
    return scene_from_dict(
        {
            "robots": robots,
            "duration": duration,
            "robot": {"kinematics": kinematics},
            "layout": {"kind": "circle", "spacing": 0.2},
            "goals": {"kind": "antipodal"},
        },
        source="circle-crossing",
        seed=seed,
    )


def run_lossy(scene: Scene, drop: float, late: float, seed: int = 0) -> LossyResult:
    """Step the scene's robots to its duration toward their scene goals with states lost with
    probability ``drop`` and a tick late with probability ``late`` (per sender and receiver)."""
    if not (0.0 <= drop and 0.0 <= late and drop + late <= 1.0):
        raise ValueError(f"drop and late must be probabilities with drop + late <= 1, not {drop}, {late}")
    params, world = world_of(scene)
    tracker = tracker_of(scene)
    n, m = scene.robots, params.max_neighbours
    ids, goal = np.arange(n), scene.goal_positions
    rng = np.random.default_rng(seed)
    velocity = np.zeros((n, 2))
    heard_tick = np.full((n, n), _UNHEARD)  # [receiver, sender]: tick of the newest state heard
    heard_pos, heard_vel = np.zeros((n, n, 2)), np.zeros((n, n, 2))
    sent: list[tuple[np.ndarray, np.ndarray]] = []  # per tick: broadcast positions and velocities
    delayed = np.zeros((n, n), bool)  # states of the tick before last that arrive now
    fallbacks, on_time, draws = 0, 0, 0
    for tick in range(round(scene.duration / params.dt)):
        measured = tracker.measure(world.poses)
        for age in (2, 1):  # the late states of tick-2 first, so tick-1's overwrite them
            if tick < age:
                continue
            if age == 1:
                u = rng.random((n, n))
                arrive, delayed = u >= drop + late, (u >= drop) & (u < drop + late)
                on_time, draws = on_time + int(arrive.sum()), draws + n * n
            else:
                arrive = delayed
            pos, vel = sent[tick - age]
            heard_tick = np.where(arrive, tick - age, heard_tick)
            heard_pos = np.where(arrive[..., None], pos[None], heard_pos)
            heard_vel = np.where(arrive[..., None], vel[None], heard_vel)
        nb = _nearest_heard(measured[:, :2], heard_tick, heard_pos, heard_vel, tick, params, m)
        res = control_step(
            params, ids, measured[:, :2], measured[:, 2], velocity, goal, nb, None, seed=scene.seed, tick=tick
        )
        velocity = res.velocity
        fallbacks += int(res.fallback.sum())
        sent.append((measured[:, :2].copy(), velocity.copy()))
        world.set_commands(res.command)
        world.step(params.dt)
    ticks = round(scene.duration / params.dt)
    return LossyResult(len(world.contacts), float(world.min_clearance), fallbacks, ticks * n, on_time / max(draws, 1))


def _nearest_heard(position, heard_tick, heard_pos, heard_vel, tick, params, m) -> NeighbourStates:
    """Each robot's nearest ``m`` neighbours within reach, as it last heard them."""
    n = len(position)
    nb = NeighbourStates.empty(n, m)
    for i in range(n):
        d = np.hypot(*(heard_pos[i] - position[i]).T)
        cand = np.flatnonzero((heard_tick[i] > _UNHEARD) & (np.arange(n) != i) & (d <= params.neighbour_dist))
        cand = cand[np.argsort(d[cand], kind="stable")[:m]]
        k = len(cand)
        nb.position[i, :k], nb.velocity[i, :k] = heard_pos[i, cand], heard_vel[i, cand]
        nb.radius[i, :k], nb.valid[i, :k] = params.radius, True
        nb.age[i, :k] = (tick - heard_tick[i, cand]) * params.dt
    return nb
