"""The one tick loop of every engine (agent, host, central, loss study): they differ only in its seams."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from .core.params import RobotParams
from .core.policy import Decision, GoalTiming, Intent, Memory, Surroundings, act, intend
from .core.step import NeighbourStates


@dataclass
class Sensed:
    """What a batch of robots knows at a tick before it hears its neighbours (params grown when late)."""

    ids: np.ndarray
    position: np.ndarray  # (B,2)
    heading: np.ndarray  # (B,)
    tick: int
    stamp: float
    params: RobotParams
    braking: np.ndarray  # (B,) bool: a pose it cannot trust (agent.pose_trust): the robot stands


class Link(Protocol):
    """How robots hear each other and where their commands go."""

    def neighbours(self, sensed: Sensed) -> NeighbourStates: ...

    def send(self, sensed: Sensed, decision: Decision) -> None: ...


class Auction(Protocol):
    """The goal auction's step of a tick (paper 5.1) and where deadlocks are charged (5.5.5)."""

    @property
    def active(self) -> bool: ...  # an auction is under way: deadlocks are watched for it

    def step(self, sensed: Sensed) -> None: ...

    def settled_beside(self) -> bool: ...

    def penalise(self, robot: int, epoch: int, goal: int) -> None: ...


class Robots(Protocol):
    """What the robots carry from tick to tick: the goals they hold and the policy's memory."""

    policy_memory: Memory  # rows: the robots as ``rows`` numbers them

    @property
    def timing(self) -> Mapping[int, GoalTiming]: ...

    def rows(self, ids: np.ndarray) -> np.ndarray | slice: ...  # slice(None): every robot, in order

    def goals(self, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]: ...  # goal0 (B,2), key (B,2)


@dataclass
class Seams:
    """What one engine plugs into the loop; ``lap`` marks the end of a part of the tick (timing)."""

    link: Link
    auction: Auction
    segments: np.ndarray | None
    seed: int
    reach: float = np.inf
    lap: Callable[[str], None] = lambda part: None
    threads: int = 1  # threads sharing the batch's control step (agent.core.step.Surroundings)


def tick(robots: Robots, sensed: Sensed, seams: Seams) -> Decision:
    """One tick of a batch: the auction's step, the states heard, the policy, deadlocks charged, commands out."""
    seams.auction.step(sensed)
    heard = seams.link.neighbours(sensed)
    rows = robots.rows(sensed.ids)
    memory = robots.policy_memory.rows(rows)
    intent = _intend(robots, sensed, memory)
    seams.lap("preferred")
    decision = _act(sensed, intent, memory, heard, seams)
    seams.lap("control")
    if seams.auction.settled_beside():  # an auction beside the policy changed goals: those robots decide again
        again = _intend(robots, sensed, memory)
        seams.lap("preferred")
        decide = lambda b: _act(_rows(sensed, b), again.rows(b), memory.rows(b), heard.rows(b), seams)
        step_again(decision, changed_rows(intent, again), again, decide)
        seams.lap("control")
    for b in np.flatnonzero(decision.deadlocked).tolist():  # paper 5.5.5: C_d on this goal for good
        epoch, goal = decision.intent.key[b].tolist()
        seams.auction.penalise(int(sensed.ids[b]), epoch, goal)
    braked = sensed.braking  # it stands: its v_opt is zero, yet it chose no standstill (its last choice stays)
    decision.memory.velocity[braked], decision.memory.chosen[braked] = 0.0, memory.chosen[braked]
    robots.policy_memory.put(rows, decision.memory)
    seams.link.send(sensed, decision)
    return decision


def _intend(robots: Robots, sensed: Sensed, memory: Memory) -> Intent:
    goal0, key = robots.goals(sensed)
    return intend(sensed.params, sensed.position, sensed.stamp, goal0, key, robots.timing, memory)


def _act(sensed: Sensed, intent: Intent, memory: Memory, heard: NeighbourStates, seams: Seams) -> Decision:
    around = Surroundings(seams.segments, seams.seed, sensed.tick, seams.auction.active, seams.reach, seams.threads)
    return act(sensed.params, sensed.ids, sensed.position, sensed.heading, intent, memory, heard, around)


def _rows(s: Sensed, b: np.ndarray) -> Sensed:
    return replace(s, ids=s.ids[b], position=s.position[b], heading=s.heading[b], braking=s.braking[b])


def changed_rows(old: Intent, new: Intent) -> np.ndarray:
    """The robots whose goal, its key or preferred velocity differ, to the bit, between two intents."""

    bits = lambda a: np.ascontiguousarray(a, dtype=float).view(np.int64)
    changed = (bits(old.goal) != bits(new.goal)).any(axis=1) | (old.key != new.key).any(axis=1)
    changed |= (bits(old.preferred) != bits(new.preferred)).any(axis=1)
    return np.flatnonzero(changed)


def step_again(decision: Decision, rows: np.ndarray, intent: Intent, decide: Callable[[np.ndarray], Decision]) -> None:
    """The robots at ``rows`` decide again; the decision takes the new intent (the others' is the same, to the bit)."""
    if rows.size:
        decision.put(rows, decide(rows))
    decision.intent = intent
    decision.memory.hold_left, decision.memory.hold_for = intent.hold_left, intent.hold_for
