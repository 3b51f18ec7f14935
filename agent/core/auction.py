"""The goal auction (paper 5.1.1) in its synchronous distributed form, as pure functions.

Every robot holds the same view of the goal set's prices and owners. In each round every robot
that owns no goal bids for its best goal (Bertsekas' forward auction: raise the price by the
difference between the best and second-best net value, plus epsilon); every robot announces its
bid or the goal it holds. Everybody merges the same announcements the same way (per goal: the
highest price wins, ties to the lower robot id), so every view stays identical and no goal can have
two owners. Costs are private (squared distance, eq. 7, plus a robot's own deadlock penalties):
only prices and owners travel.

Warm start (paper 5.1: re-assign every iteration): prices and owners carry over to the next control
iteration; a robot gives up its goal only when another goal is better by more than epsilon plus the
hysteresis Delta C. Epsilon scaling (cold start): phases with decreasing epsilon, prices kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NO_OWNER = -1


@dataclass
class Bid:
    robot: int
    goal: int
    price: float
    holds: bool  # True: "I keep the goal I own"; False: a new bid


@dataclass
class AuctionView:
    """Prices and owners of a goal set, identical in every robot that saw the same rounds."""

    prices: np.ndarray  # (G,)
    owner: np.ndarray  # (G,) robot id or NO_OWNER

    @classmethod
    def fresh(cls, goals: int) -> AuctionView:
        return cls(np.zeros(goals), np.full(goals, NO_OWNER, dtype=np.int64))

    def goal_of(self, robot: int) -> int:
        held = np.flatnonzero(self.owner == robot)
        return int(held[0]) if len(held) else -1

    def copy(self) -> AuctionView:
        return AuctionView(self.prices.copy(), self.owner.copy())


def net_values(
    position: np.ndarray, goals: np.ndarray, prices: np.ndarray, penalty: np.ndarray | None = None
) -> np.ndarray:
    """-c_ij - b_j for one robot: c_ij = |g_j - p_i|^2 (eq. 7) plus its own deadlock penalty C_d."""
    d = goals - position
    cost = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    if penalty is not None:
        cost = cost + penalty
    return -cost - prices


# Relative slack for the rounding of a bid. A bid leaves its robot's value of the goal exactly epsilon
# below its next-best value in real numbers; in floats, price + (v1 - v2) + eps then -cost - price can
# land an ulp short, the robot is not content with the goal it just won, gives it up and bids again.
# Each such bid releases a goal, and at large warm prices the releases feed a price war that never ends.
ROUNDING = 1e-12


def is_content(held: np.ndarray | float, best: np.ndarray | float, slack: float) -> np.ndarray | bool:
    """The held goal's net value is within ``slack`` of the best (epsilon-complementary slackness, with
    the hysteresis Delta C: Participant.slack), up to the rounding of the bid that set it."""
    return held >= best - slack - ROUNDING * np.abs(best)


def make_bid(
    robot: int,
    position: np.ndarray,
    goals: np.ndarray,
    view: AuctionView,
    eps: float,
    hysteresis: float = 0.0,
    penalty: np.ndarray | None = None,
) -> Bid:
    """What one robot announces this round: hold its goal (eps-complementary slackness still holds,
    with the hysteresis Delta C as extra slack) or bid for its best goal."""
    values = net_values(position, goals, view.prices, penalty)
    best = int(np.argmax(values))  # ties: lowest goal index, the same in every process
    held = view.goal_of(robot)
    if held >= 0 and is_content(values[held], values[best], eps + hysteresis):
        return Bid(robot, held, float(view.prices[held]), True)
    if len(values) == 1:
        return Bid(robot, best, float(view.prices[best] + eps), False)
    second = float(np.max(np.delete(values, best)))
    return Bid(robot, best, float(view.prices[best] + (values[best] - second) + eps), False)


def merge(view: AuctionView, bids: list[Bid]) -> tuple[AuctionView, int]:
    """Apply one round's announcements; returns the new view and how many bids changed an owner.

    Per goal the highest bid wins (ties to the lower robot id); the outbid owner loses the goal.
    A robot that bid gives up what it held before (it only bids when it holds nothing or releases).
    """
    out = view.copy()
    new_bids = [b for b in bids if not b.holds]
    for b in new_bids:  # a bidder releases whatever it owned
        out.owner[out.owner == b.robot] = NO_OWNER
    winners: dict[int, Bid] = {}
    for b in new_bids:
        cur = winners.get(b.goal)
        if cur is None or b.price > cur.price or (b.price == cur.price and b.robot < cur.robot):
            winners[b.goal] = b
    changes = 0
    for goal, b in sorted(winners.items()):
        if b.price > out.prices[goal] or out.owner[goal] == NO_OWNER:
            out.prices[goal] = max(out.prices[goal], b.price)
            out.owner[goal] = b.robot
            changes += 1
    return out, changes


def is_complete(view: AuctionView, robots: list[int]) -> bool:
    """Every robot owns a goal (there are at least as many goals as robots)."""
    owned = set(view.owner[view.owner != NO_OWNER].tolist())
    return all(r in owned for r in robots)


def epsilon_schedule(goals: np.ndarray, eps_final: float, factor: float = 5.0) -> list[float]:
    """Decreasing epsilons for a cold start: from a fraction of the squared extent of the goal set
    down to eps_final (Bertsekas' epsilon scaling)."""
    extent = float(np.max(np.ptp(goals, axis=0))) if len(goals) > 1 else 0.0
    eps = max(eps_final, extent * extent / 10.0)
    out = []
    while eps > eps_final * 1.0001:
        out.append(eps)
        eps /= factor
    out.append(eps_final)
    return out


def solve(
    positions: dict[int, np.ndarray],
    goals: np.ndarray,
    eps_final: float,
    view: AuctionView | None = None,
    hysteresis: float = 0.0,
    max_rounds: int = 100_000,
    penalties: dict[int, np.ndarray] | None = None,
) -> tuple[AuctionView, int]:
    """Run the synchronous protocol in one process (every robot's bid computed here): the reference
    for tests and for the central engine. Cold start with epsilon scaling when no view is given."""
    robots = sorted(positions)
    penalties = penalties or {}
    rounds = 0
    if view is None:
        phases = epsilon_schedule(goals, eps_final)
        view = AuctionView.fresh(len(goals))
    else:
        phases = [eps_final]
    for eps in phases:
        # A new phase releases only the robots whose goal violates eps-CS for the smaller epsilon.
        while rounds < max_rounds:
            # no phase tighter than the final one (Participant.slack)
            bids = [
                make_bid(r, positions[r], goals, view, eps, max(phases[-1] + hysteresis - eps, 0.0), penalties.get(r))
                for r in robots
            ]
            rounds += 1
            view, _ = merge(view, bids)
            if all(b.holds for b in bids) and is_complete(view, robots):
                break
    return view, rounds
