"""The robot policy: what a batch of robots decides in one tick, through ``intend`` then ``act`` in every engine.

Per robot the result depends only on its row. The stages are apart so the central engine can redo ``act`` for
the robots whose goal an auction changed while ``intend`` ran.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .animation import frame_hold, iterations_left
from .control import blocked
from .goal_motion import GoalMotion, tracking_velocity
from .params import RobotParams
from .step import NeighbourStates, OwnStates, Rows, StepResult, Surroundings, control_step

NO_GOAL = -1  # goal index of a robot that holds no goal of a goal set


def no_goal_keys(batch: int) -> np.ndarray:
    """(batch, 2) int64 goal keys (epoch, goal) of robots that hold no goal yet: (0, NO_GOAL)."""
    return np.tile(np.array([0, NO_GOAL], np.int64), (batch, 1))


@dataclass(frozen=True)
class GoalTiming:
    """What a goal set's message says about time: when its step began, an animation keyframe's
    K_f dt (0: a still image) and a dynamic image's motion (None: the goals stand still)."""

    t_start: float = 0.0
    frame_period: float = 0.0
    motion: GoalMotion | None = None


@dataclass
class Memory(Rows):
    """What a batch of robots carries from tick to tick (rows = robots)."""

    velocity: np.ndarray  # (B,2) v_cf of the last tick: ORCA's v_opt, and what neighbours heard
    hold_left: np.ndarray  # (B,) iterations eq. 27's hold still lasts
    hold_for: np.ndarray  # (B,2) (epoch, goal index) the hold was started for
    blocked: np.ndarray  # (B,) consecutive blocked iterations (deadlock detection)
    latency: np.ndarray  # (B,) s: how old the freshest neighbour state was when last heard (heard_speed_limit)
    # (B,2) v_cf as ORCA last chose it on a pose the robot trusted (agent.loop.tick keeps it through a brake):
    # whether it barely moves (the standoff's turn right) reads this, so a brake on a tracker glitch is no standoff
    chosen: np.ndarray

    @classmethod
    def new(cls, batch: int, latency: float = 0.0) -> Memory:
        hold_for = no_goal_keys(batch)
        return cls(
            np.zeros((batch, 2)),
            np.zeros(batch, np.int64),
            hold_for,
            np.zeros(batch, np.int64),
            np.full(batch, latency),
            np.zeros((batch, 2)),
        )


@dataclass
class Intent(Rows):
    """Where a batch heads this tick (stage one of the policy)."""

    key: np.ndarray  # (B,2) (epoch, goal index) of each robot's goal (goal index NO_GOAL: none)
    goal: np.ndarray  # (B,2) the goal now (NaN: none)
    preferred: np.ndarray  # (B,2) preferred velocity where eq. 9 does not apply (NaN rows: eq. 9)
    hold_left: np.ndarray  # (B,) the hold's memory after this tick
    hold_for: np.ndarray  # (B,2)


@dataclass
class Decision(Rows):
    """A batch's tick: its intent, the control step, its memory for the next tick, and deadlocks."""

    intent: Intent
    step: StepResult
    memory: Memory
    deadlocked: np.ndarray  # (B,) bool: raise this robot's cost of its goal by C_d


def intend(
    params: RobotParams,
    position: np.ndarray,
    stamp: float,
    goal0: np.ndarray,
    key: np.ndarray,
    timing: Mapping[int, GoalTiming],
    memory: Memory,
) -> Intent:
    """Stage one at display time ``stamp``: where each robot heads, and its preferred velocity where eq. 9
    does not apply (eq. 27, eq. 28). ``goal0`` (B,2): goals as published (NaN: none); ``key`` (B,2):
    their (epoch, goal index); ``timing``: by epoch (a goal set not in it: eq. 9 toward goal0)."""
    b = len(position)
    key = np.asarray(key, np.int64).reshape(b, 2)
    goal = np.array(goal0, float).reshape(b, 2)
    preferred = np.full((b, 2), np.nan)
    of_set = np.where(key[:, 1] >= 0, key[:, 0], NO_GOAL)
    keyframe = np.zeros(b, bool)
    t_start, period = np.zeros(b), np.zeros(b)
    # the goal sets whose goals move or are keyframes (a still image's robots need nothing here)
    for epoch, gs in timing.items():
        if epoch == NO_GOAL or not (gs.motion is not None or gs.frame_period > 0):
            continue
        rows = of_set == epoch
        if not rows.any():
            continue
        if gs.motion is not None:  # eq. 28: the goal moves, its velocity is fed forward
            t = stamp - gs.t_start
            goal[rows] = gs.motion.positions(goal0[rows], t)
            velocity = gs.motion.velocities(goal0[rows], t)
            preferred[rows] = tracking_velocity(
                position[rows], goal[rows], velocity, params.v_pref, params.k_a, params.v_max
            )
        else:  # a keyframe (the filter above)
            keyframe[rows] = True
            t_start[rows], period[rows] = gs.t_start, gs.frame_period
    hold_left, hold_for = memory.hold_left.copy(), memory.hold_for.copy()
    if keyframe.any() or hold_left.any():
        # a new goal restarts the hold: over what is left of its keyframe, or (not a keyframe) ends it
        restart = (key != hold_for).any(axis=1)
        iterations = np.where(keyframe, iterations_left(t_start, period, stamp, params.dt), 0)
        pref, hold_left = frame_hold(position, goal, restart, iterations, hold_left, params.v_max, params.dt)
        hold_for = np.where(restart[:, None], key, hold_for)
        preferred = np.where(np.isfinite(pref), pref, preferred)
    return Intent(key, goal, preferred, hold_left, hold_for)


def act(
    params: RobotParams,
    robot_ids: np.ndarray,
    position: np.ndarray,
    heading: np.ndarray,
    intent: Intent,
    memory: Memory,
    neighbours: NeighbourStates,
    around: Surroundings,
) -> Decision:
    """Stage two: collision-free velocity and command (agent.core.step), and deadlock detection (5.5.5)."""
    latency, reach, cap = memory.latency, around.reach, None
    if np.isfinite(reach):
        ages = np.where(neighbours.valid, neighbours.age, np.inf)
        freshest = ages.min(axis=1, initial=np.inf)
        latency = np.where(np.isfinite(freshest), np.maximum(freshest, 0.0), memory.latency)
        # for the preferred velocity and ORCA's (avoiding, it may choose one faster than the preferred)
        cap = heard_speed_limit(params, reach, latency)
    own = OwnStates(robot_ids, position, heading, memory.velocity, intent.goal, intent.preferred, cap, memory.chosen)
    res = control_step(params, own, neighbours, around)
    counts, deadlocked = memory.blocked, np.zeros(len(position), bool)
    if around.watch_deadlocks and params.deadlock_cost > 0:
        to_goal = intent.goal - position
        to_goal[intent.key[:, 1] < 0] = np.nan  # a goal of no goal set (sent, not auctioned): no deadlock there
        now = blocked(params, to_goal, res.pref_velocity, res.velocity)
        counts, deadlocked = count_blocked(counts, now, params.deadlock_iterations)
    new_memory = Memory(res.velocity.copy(), intent.hold_left, intent.hold_for, counts, latency, res.velocity.copy())
    return Decision(intent, res, new_memory, deadlocked)


def heard_speed_limit(params: RobotParams, reach: float, latency: np.ndarray) -> np.ndarray:
    """The fastest a robot may drive hearing others only within ``reach``, ``latency`` s late: two meeting
    head-on keep a gap after one hears the other and a tick passes (overload degrades to slow)."""
    gap = max(reach - 2.0 * params.radius - params.noise_bound, 0.0)
    return gap / (2.0 * (np.asarray(latency, float) + 2.0 * params.dt))


def count_blocked(counts: np.ndarray, now_blocked: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Paper 5.5.5: consecutive blocked iterations (control.blocked) per robot; returns (new counts, deadlocked
    now). A declared deadlock restarts the count, so a robot still stuck is penalised again N_d later."""
    counts = np.where(now_blocked, counts + 1, 0)
    deadlocked = counts >= iterations
    return np.where(deadlocked, 0, counts), deadlocked
