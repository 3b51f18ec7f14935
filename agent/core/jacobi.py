"""The Jacobi rounds of the forward auction (paper 5.1.1) for a host that holds every robot and hears
no message (the central engine's `Participant.settle_alone`), compiled with numba.

`settle_block` runs one block of epsilon-scaling phases: the costs (eq. 7) on the frozen positions,
then per phase `jacobi_rounds` until every robot is content. The rounds, bids and board are those
of `Participant.begin`, `bid` and `check_agreement`: every robot that is not content bids at once on
its best goal against the board as the round found it, releasing the goal it held; per goal the
greatest record wins (price, then the lower robot id, then "released"). The outcome is the
protocol's to the bit (tests/test_bidder.py checks it against the numpy rounds of the agent hosts).

Why compiled: while 1000 robots cross the arena a warm block runs chains of 10,000 and more rounds of
one or two bidders (each outbid robot outbids the next). Each round is a scan over the goals for one
robot: about a microsecond compiled, 10 us in Python (bench/results/large.md). After a round only the
bidders and the robots they outbid are looked at again; nobody else's contentment can have changed
(a content robot holds its goal, so only a bid on that goal changes it, and every other price only
rises).

Each robot keeps its best goal, its net value (exact when the price of that goal is ``seen``) and
an upper bound of its second-best value, as the numpy rounds do: a robot looked at again is ranked
over every goal only if its best goal may have changed.
"""
from __future__ import annotations

import numpy as np
from numba import njit

NO_OWNER = -1  # as agent.core.auction.NO_OWNER: numba's cache would keep an imported constant stale


@njit(cache=True)
def _greater(price: float, robot: int, released: bool, b_price: float, b_owner: int, b_released: bool) -> bool:
    """Is the record (price, robot, released) greater than the board's for its goal?"""
    if b_owner == NO_OWNER:
        return True
    if price != b_price:
        return price > b_price
    if robot != b_owner:
        return robot < b_owner
    return released and not b_released


@njit(cache=True)
def _rank(cost_row: np.ndarray, price: np.ndarray) -> tuple[int, float, int, float, float]:
    """A robot's best goal and net value, runner-up goal and value, and third-best value over every
    goal (ties: the lowest goal index, as numpy's argmax)."""
    j1, j2 = -1, -1
    v1, v2, v3 = -np.inf, -np.inf, -np.inf
    for j in range(len(price)):
        v = -cost_row[j] - price[j]  # finite: costs and prices are
        if v > v3:  # v3 <= v2 <= v1: most goals fail this one test
            if v > v1:
                j2, v2, v3 = j1, v1, v2
                j1, v1 = j, v
            elif v > v2:
                j2, v3 = j, v2
                v2 = v
            else:
                v3 = v
    return j1, v1, j2, v2, v3


@njit(cache=True)
def _refresh(i: int, cost: np.ndarray, price: np.ndarray, best: np.ndarray, value: np.ndarray,
             second: np.ndarray, seen: np.ndarray) -> None:
    """Make robot row i's best goal and value exact: ranked anew over every goal only if the price
    of its best goal rose past its second-best value (an upper bound)."""
    b = best[i]
    if not price[b] == seen[i]:  # NaN: rank anew
        now = -cost[i, b] - price[b]
        value[i] = now
        if now > second[i]:
            seen[i] = price[b]
        else:
            j1, v1, j2, v2, _ = _rank(cost[i], price)
            best[i], value[i] = j1, v1
            second[i] = v2 if j2 >= 0 else -np.inf
            seen[i] = price[j1]


@njit(cache=True)
def _content(i: int, cost: np.ndarray, price: np.ndarray, owner: np.ndarray, released: np.ndarray,
             goal: np.ndarray, own_ids: np.ndarray, best: np.ndarray, value: np.ndarray, second: np.ndarray,
             seen: np.ndarray, slack: float, rounding: float) -> bool:
    """Does robot row i hold its goal within ``slack`` of its best (agent.core.auction.is_content)?
    A robot that holds none bids next round, which ranks it anyway: its best value is left stale
    (``seen`` says so) rather than ranked twice (while 1000 robots cross the arena most bids are
    by robots just outbid)."""
    g = goal[i]
    if g < 0 or owner[g] != own_ids[i] or released[g]:
        return False
    _refresh(i, cost, price, best, value, second, seen)
    return -cost[i, g] - price[g] >= value[i] - slack - rounding * abs(value[i])


@njit(cache=True)
def jacobi_rounds(cost: np.ndarray, price: np.ndarray, owner: np.ndarray, released: np.ndarray,
                  goal: np.ndarray, own_ids: np.ndarray, row_of_id: np.ndarray, best: np.ndarray,
                  value: np.ndarray, second: np.ndarray, seen: np.ndarray, waiting: np.ndarray, eps: float,
                  slack: float, rounding: float, max_rounds: int) -> tuple[int, int, int]:
    """Bid the robots in ``waiting`` (rows not content, ascending) and those they outbid until every
    robot is content. The board (price, owner, released), the claims ``goal`` and the cached best
    goals (best, value, second, and ``seen``: the price of the best goal when its value was last
    exact) change in place. ``row_of_id``: each robot id's row. Returns (rounds, bids, robots still
    waiting)."""
    k = len(goal)
    queue = np.empty(k, np.int64)
    n = len(waiting)
    queue[:n] = waiting
    unhappy = np.zeros(k, np.bool_)  # scratch: looked at this round and not content
    look = np.empty(2 * k, np.int64)  # bidders and the robots they outbid (an id twice is harmless)
    bid_goal = np.empty(k, np.int64)
    bid_price = np.empty(k)
    before = np.empty(k, np.int64)  # owner of the goal bid on, as the round found it
    runner_up = np.empty(k, np.int64)  # the bidder's second-best goal and third-best value
    third = np.empty(k)
    held = np.empty(k, np.int64)  # the goal each bidder releases (-1: none) and its price
    held_price = np.empty(k)
    rounds, bids = 0, 0
    while n > 0 and rounds < max_rounds:
        bidders = np.sort(queue[:n])
        # every bid against the board as the round found it
        for a in range(n):
            i = bidders[a]
            j1, v1, j2, v2, v3 = _rank(cost[i], price)
            if j2 < 0:  # one goal: the bid rises by epsilon
                v2 = v1 - eps
            bid_goal[a], bid_price[a], before[a] = j1, price[j1] + (v1 - v2) + eps, owner[j1]
            runner_up[a], third[a] = j2, v3
            h = goal[i]  # the goal it gives up, at the price the round found
            if h >= 0 and owner[h] == own_ids[i] and not released[h]:
                held[a], held_price[a] = h, price[h]
            else:
                held[a] = -1
        for a in range(n):  # max-consensus: the order of the merges does not matter
            i = bidders[a]
            h = held[a]
            if h >= 0 and _greater(held_price[a], own_ids[i], True, price[h], owner[h], released[h]):
                price[h], owner[h], released[h] = held_price[a], own_ids[i], True
            j = bid_goal[a]
            if _greater(bid_price[a], own_ids[i], False, price[j], owner[j], released[j]):
                price[j], owner[j], released[j] = bid_price[a], own_ids[i], False
        m = 0
        for a in range(n):
            i = bidders[a]
            # the cache from the bid's ranking (Participant._after_bids)
            j1, j2, v3 = bid_goal[a], runner_up[a], third[a]
            v_bid = -cost[i, j1] - price[j1]
            v_run = -cost[i, j2] - price[j2] if j2 >= 0 else -np.inf
            bound = max(v_bid, v3)
            if v_run > bound and j2 != j1:  # the runner-up is the best now
                best[i], value[i], second[i] = j2, v_run, bound
                seen[i] = price[j2]
            else:  # ranked anew when next looked at
                best[i], value[i], second[i] = j1, v_bid, np.inf
                seen[i] = np.nan
            goal[i] = j1
            look[m] = i
            m += 1
            o = before[a]
            if o != NO_OWNER and owner[j1] != o:
                look[m] = row_of_id[o]
                m += 1
        bids += n
        rounds += 1
        for a in range(m):
            r = look[a]
            unhappy[r] = not _content(r, cost, price, owner, released, goal, own_ids, best, value, second,
                                      seen, slack, rounding)
        n = 0  # the next bidders: every robot not content was looked at (it bid or was outbid)
        for a in range(m):
            r = look[a]
            if unhappy[r]:
                queue[n] = r
                n += 1
                unhappy[r] = False  # queued once
    return rounds, bids, n


@njit(cache=True)
def settle_block(position: np.ndarray, goals: np.ndarray, penalty: np.ndarray, has_penalty: bool,
                 cost: np.ndarray, price: np.ndarray, owner: np.ndarray, released: np.ndarray, goal: np.ndarray,
                 own_ids: np.ndarray, row_of_id: np.ndarray, best: np.ndarray, value: np.ndarray,
                 second: np.ndarray, eps: np.ndarray, slack: np.ndarray, rounding: float,
                 max_rounds: int) -> tuple[int, int, int]:
    """One block of epsilon-scaling phases on frozen positions, warm from the board: the costs
    (eq. 7, |g_j - p_i|^2 in the same float operations as agent.core.bidder, plus the penalties in
    force) into ``cost``, every robot ranked over every goal, then per phase (``eps``, ``slack``)
    the Jacobi rounds until every robot is content. Leaves every cached best value exact. Returns
    (rounds, bids, phases settled): fewer than len(eps) when a phase ran out of rounds."""
    k, g = cost.shape
    gx, gy = goals[:, 0].copy(), goals[:, 1].copy()
    for i in range(k):
        px, py = position[i, 0], position[i, 1]
        row = cost[i]
        for j in range(g):  # apart from the ranking, so that it vectorises
            dx, dy = gx[j] - px, gy[j] - py
            row[j] = dx * dx + dy * dy
        if has_penalty:
            row += penalty[i]
        j1, v1, j2, v2, _ = _rank(cost[i], price)
        best[i], value[i] = j1, v1
        second[i] = v2 if j2 >= 0 else -np.inf
    seen = np.empty(k)
    for i in range(k):
        seen[i] = price[best[i]]
    waiting = np.empty(k, np.int64)
    rounds, bids = 0, 0
    for phase in range(len(eps)):
        n = 0
        for i in range(k):  # who is not content at this phase's slack
            if not _content(i, cost, price, owner, released, goal, own_ids, best, value, second, seen,
                            slack[phase], rounding):
                waiting[n] = i
                n += 1
        r, b, left = jacobi_rounds(cost, price, owner, released, goal, own_ids, row_of_id, best, value, second,
                                   seen, waiting[:n], eps[phase], slack[phase], rounding, max_rounds)
        rounds, bids = rounds + r, bids + b
        if left:
            return rounds, bids, phase
    for i in range(k):  # every best value exact for the prices as they are now
        _refresh(i, cost, price, best, value, second, seen)
    return rounds, bids, len(eps)
