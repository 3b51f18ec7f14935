"""The Jacobi rounds of the forward auction (paper 5.1.1) for a host that holds every robot and hears
no message (the central engine's `Participant.settle_alone`), compiled with numba.

A block of epsilon-scaling phases on frozen positions starts with `first_ranking` (every robot's
best goals), then `settle_block` runs per phase the Jacobi rounds until every robot is content.
The rounds, bids and board are those of `Participant.begin`, `bid` and `check_agreement`: every
robot that is not content bids at once on its best goal against the board as the round found it,
releasing the goal it held; per goal the greatest record wins (price, then the lower robot id, then
"released"). The outcome is the protocol's to the bit (tests/test_bidder.py checks it against the
numpy rounds of the agent hosts).

Why compiled: while 1000 robots cross the arena a warm block runs chains of 10,000 and more rounds of
one or two bidders (each outbid robot outbids the next), each round a tenth of its cost in Python. After a round only the bidders and the robots they outbid are looked at again; nobody
else's contentment can have changed (a content robot holds its goal, so only a bid on that goal
changes it, and every other price only rises).

What makes a round cheap is knowing a robot's best goals without scanning every goal:

- **Cached best goal.** Each robot keeps its best goal, its net value (exact when the price of that
  goal is ``seen``) and an upper bound of its second-best value: it is ranked again only if its
  best goal may have changed.
- **Candidate goals** (`Lists`). A ranking over every goal also keeps the robot's K best goals and
  ``bound``, an upper bound of every other goal's value. Prices only rise, so the bound holds while
  the prices change; if the three best candidates beat it, they are the three best goals (ties
  included) and a ranking costs K goals, not all of them.
- **Carried across blocks.** A robot that moved by d since its list was made: the value of goal j
  changed by 2 (g_j - p).d - |d|^2, so the bound moved by at most 2 (h(d) - p.d) - |d|^2 with h the
  goal set's support function (over its convex hull), and by less where the goals off the list are
  near the robot (`moved_bound`). While robots hold their goals the lists survive from control step
  to control step, and a block need not start by scanning every cost.
- **No cost matrix.** Costs are computed where needed, |g_j - p_i|^2 plus the penalties in force, in
  the same float operations as the agent hosts' (agent.core.bidder._squared_distances).
- **Phases with nothing to do** are passed over: a robot content at the smallest slack left is
  content at every larger one, so one scan finds every robot that may bid in any later phase. The
  scan after a phase's rounds looks only at the robots the rounds looked at and at those that
  might bid before: nobody else's goal was bid on, and every other price only rose.
- **No reference counting, no calls in the rounds.** numba counts references to every array a
  function is handed, and a call hands over every field of some thirty arrays. So nothing in the
  rounds allocates: the scratch is made once with the lists (`Rounds`), and the block, its rounds
  and `first_ranking` are compiled without numba's runtime (``_nrt=False``: the compiler refuses
  any that would allocate). The per-robot helpers (`_rank`, `_refresh`, `_content`) are inlined
  into them; only a ranking over every goal is a call (inlined into rounds that count references,
  they would be slower than called).
  ``_cost`` is inlined too; inlined in a loop, its array arguments cost more than its arithmetic,
  so the two loops over goals write it out.

How long the assignment takes per control step: bench/results/large.md.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

NO_OWNER = -1  # as agent.core.auction.NO_OWNER: numba's cache would keep an imported constant stale
BORROWS = {"cache": True, "_nrt": False}  # a helper that allocates nothing and borrows its arrays

# Per robot: its K candidate goals (-1: none), an upper bound of every other goal's value (+inf: no
# list), the value window that list-making aims for (adapted so that about K goals fall in it), and
# where the list was made with the bound it had there (a later block moves the bound from there:
# a robot that jitters in place keeps its list).
Lists = namedtuple("Lists", ["cand", "bound", "width", "made_x", "made_y", "made_bound"])
# Scratch for a ranking over every goal: the values (G,), the goals in the window (4K,) and the
# K + 1 best of them.
Work = namedtuple("Work", ["values", "window_value", "window_goal", "top_value", "top_goal"])
# Scratch for a block's phases and rounds, per robot: the price of its best goal when its value was
# last exact (`seen`), who may bid, who waits, who was looked at since the last scan, and per
# round the queue, the bids (goal, price, the goal's owner before, the bidder's runner-up goal and
# third value, the goal it releases and that goal's price) and the robots looked at.
Rounds = namedtuple(
    "Rounds",
    [
        "seen",
        "may_bid",
        "waiting",
        "touched",
        "queue",
        "unhappy",
        "look",
        "bidders",
        "bid_goal",
        "bid_price",
        "before",
        "runner_up",
        "third",
        "held",
        "held_price",
    ],
)


def new_lists(robots: int, goals: int, k: int) -> tuple[Lists, Work, Rounds]:
    """Empty candidate lists of k goals for each robot, and the scratch to fill them and to settle
    blocks with (made once: the compiled rounds allocate nothing)."""
    ints, floats = (lambda: np.zeros(robots, np.int64)), (lambda: np.zeros(robots))
    return (
        Lists(
            np.full((robots, k), -1, np.int64),
            np.full(robots, np.inf),
            np.ones(robots),
            np.zeros(robots),
            np.zeros(robots),
            np.full(robots, np.inf),
        ),
        Work(np.empty(goals), np.empty(4 * k), np.empty(4 * k, np.int64), np.empty(k + 1), np.empty(k + 1, np.int64)),
        Rounds(
            floats(),
            ints(),
            ints(),
            np.zeros(robots, np.bool_),
            ints(),
            np.zeros(robots, np.bool_),
            np.zeros(2 * robots, np.int64),
            ints(),
            ints(),
            floats(),
            ints(),
            ints(),
            floats(),
            ints(),
            floats(),
        ),
    )


@njit(cache=True, inline="always")
def _cost(i, j, px, py, gx, gy, penalty, has_penalty):
    """c_ij (eq. 7) plus robot i's penalty on goal j, as agent.core.bidder computes it."""
    dx, dy = gx[j] - px[i], gy[j] - py[i]
    c = dx * dx + dy * dy
    if has_penalty:
        c = c + penalty[i, j]
    return c


@njit(cache=True, inline="always")
def _greater(price: float, robot: int, released: bool, b_price: float, b_owner: int, b_released: bool) -> bool:
    """Is the record (price, robot, released) greater than the board's for its goal?"""
    if b_owner == NO_OWNER:
        return True
    if price != b_price:
        return price > b_price
    if robot != b_owner:
        return robot < b_owner
    return released and not b_released


@njit(**BORROWS)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def _rank_all(i, px, py, gx, gy, price, penalty, has_penalty, lists, work):
    """Robot i's best goal and net value, runner-up goal and value, and third-best value over every
    goal (ties: the lower goal index, as numpy's argmax in the agent hosts' rounds). Renews its
    candidates: the best K of the goals worth at least T = third best - width (T is then the bound
    of the others); none when more than 4K fall in the window."""
    values = work.values  # _cost for every goal, in loops that vectorise
    x, y = px[i], py[i]
    for j in range(len(price)):
        dx, dy = gx[j] - x, gy[j] - y
        values[j] = dx * dx + dy * dy
    if has_penalty:
        for j in range(len(price)):
            values[j] += penalty[i, j]
    for j in range(len(price)):
        values[j] = -values[j] - price[j]
    j1, j2 = -1, -1
    v1, v2, v3 = -np.inf, -np.inf, -np.inf
    for j in range(len(price)):
        v = values[j]
        if v > v3:  # most goals fail this one test
            if v > v1:
                j2, v2, v3 = j1, v1, v2
                j1, v1 = j, v
            elif v > v2:
                j2, v3 = j, v2
                v2 = v
            else:
                v3 = v
    # the window, in ascending goal index
    k = lists.cand.shape[1]
    t = v3 - lists.width[i]
    n = 0
    for j in range(len(price)):
        if values[j] >= t:
            if n < len(work.window_goal):
                work.window_value[n], work.window_goal[n] = values[j], j
            n += 1
    if n > len(work.window_goal) or not t > -np.inf:  # no list this time: a narrower window next
        lists.width[i] *= 0.25
        lists.cand[i, :] = -1
        lists.bound[i] = lists.made_bound[i] = np.inf
        return j1, v1, j2, v2, v3
    if n < k:
        lists.width[i] *= 2.0
    elif n > 2 * k:
        lists.width[i] *= 0.5
    top_value, top_goal = work.top_value, work.top_goal  # the k + 1 best of the window
    top_value[:] = -np.inf
    top_goal[:] = -1
    for a in range(n):  # ascending goal index: a strict > keeps the lower index first among equals
        v = work.window_value[a]
        if v > top_value[k]:
            s = k
            while s > 0 and v > top_value[s - 1]:
                top_value[s], top_goal[s] = top_value[s - 1], top_goal[s - 1]
                s -= 1
            top_value[s], top_goal[s] = v, work.window_goal[a]
    for s in range(k):  # (a slice assignment would allocate)
        lists.cand[i, s] = top_goal[s]
    lists.bound[i] = lists.made_bound[i] = max(t, top_value[k])
    lists.made_x[i], lists.made_y[i] = px[i], py[i]
    return j1, v1, j2, v2, v3


@njit(cache=True, inline="always")
def _before(v, j, w, m):
    """Does goal j of value v rank before goal m of value w (value, then the lower index)?"""
    return v > w or (v == w and j < m)


@njit(cache=True, inline="always")  # into rounds compiled without NRT
def _rank(i, px, py, gx, gy, price, penalty, has_penalty, lists, work):
    """`_rank_all`, from robot i's candidates when they provably hold its three best goals."""
    j1, j2, j3 = -1, -1, -1
    v1, v2, v3 = -np.inf, -np.inf, -np.inf
    for s in range(lists.cand.shape[1]):
        j = lists.cand[i, s]
        if j < 0:
            continue
        dx, dy = gx[j] - px[i], gy[j] - py[i]  # _cost, written out (above)
        c = dx * dx + dy * dy
        if has_penalty:
            c = c + penalty[i, j]
        v = -c - price[j]
        if _before(v, j, v3, j3):
            if _before(v, j, v1, j1):
                j3, v3, j2, v2, j1, v1 = j2, v2, j1, v1, j, v
            elif _before(v, j, v2, j2):
                j3, v3, j2, v2 = j2, v2, j, v
            else:
                j3, v3 = j, v
    if v3 > lists.bound[i]:  # ties at the bound: ranked over every goal
        return j1, v1, j2, v2, v3
    return _rank_all(i, px, py, gx, gy, price, penalty, has_penalty, lists, work)


@njit(cache=True, inline="always")  # into rounds compiled without NRT
def _refresh(i, px, py, gx, gy, price, penalty, has_penalty, best, value, second, seen, lists, work) -> None:
    """Make robot i's best goal and value exact: ranked anew only if the price of its best goal
    rose past its second-best value (an upper bound)."""
    b = best[i]
    if not price[b] == seen[i]:  # NaN: rank anew
        now = -_cost(i, b, px, py, gx, gy, penalty, has_penalty) - price[b]
        value[i] = now
        if now > second[i]:
            seen[i] = price[b]
        else:
            j1, v1, j2, v2, _ = _rank(i, px, py, gx, gy, price, penalty, has_penalty, lists, work)
            best[i], value[i] = j1, v1
            second[i] = v2 if j2 >= 0 else -np.inf
            seen[i] = price[j1]


@njit(cache=True, inline="always")  # into rounds compiled without NRT
def _content(
    i,
    px,
    py,
    gx,
    gy,
    price,
    penalty,
    has_penalty,
    owner,
    released,
    goal,
    own_ids,
    best,
    value,
    second,
    seen,
    lists,
    work,
    slack,
    rounding,
) -> bool:
    """Does robot i hold its goal within ``slack`` of its best (agent.core.auction.is_content)?
    A robot that holds none bids next round, which ranks it anyway: its best value is left stale
    (``seen`` says so) rather than ranked twice."""
    g = goal[i]
    if g < 0 or owner[g] != own_ids[i] or released[g]:
        return False
    _refresh(i, px, py, gx, gy, price, penalty, has_penalty, best, value, second, seen, lists, work)
    held = -_cost(i, g, px, py, gx, gy, penalty, has_penalty) - price[g]
    return held >= value[i] - slack - rounding * abs(value[i])


@njit(cache=True, inline="always")
def moved_bound(made, x0, y0, dx, dy, hull_x, hull_y, lowest):
    """An upper bound, now, of the value of every goal off a robot's list, made where it stood at
    (x0, y0) with the bound ``made``, after it moved by D = (dx, dy); ``lowest``: the lowest price.
    Prices and penalties only rose since, and two bounds hold; the lesser is returned:
    - a goal's value changed by 2 (g - p).D - |D|^2 <= 2 (h(D) - p.D) - |D|^2, h the support function
      of the goal set over its hull's vertices (hull_x, hull_y);
    - no goal is worth more than -(its distance)^2 - lowest (penalties are costs, never negative), so
      with u = value + lowest, a goal that had u <= U there has u <= -(sqrt(-U) - |D|)^2 now (0 if
      |D| >= sqrt(-U)): only the goals near the robot count, not the goal set's extent.
    +inf for a robot with no list (made = +inf)."""
    h = -np.inf
    for a in range(len(hull_x)):
        h = max(h, hull_x[a] * dx + hull_y[a] * dy)
    grow = 2.0 * (h - (x0 * dx + y0 * dy)) - (dx * dx + dy * dy)
    moved = made + grow
    if made < np.inf:
        u = made + lowest
        near = max(np.sqrt(-u) - np.sqrt(dx * dx + dy * dy), 0.0) if u < 0.0 else 0.0
        moved = min(moved, -near * near - lowest)
    return moved + 1e-9 * (abs(moved) + abs(made) + abs(grow) + abs(lowest) + 1.0)  # room for rounding


# nogil: it runs beside the control core (sim.central)
@njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def first_ranking(px, py, gx, gy, price, penalty, has_penalty, best, value, second, lists, work, hull_x, hull_y) -> int:
    """Every robot's best goal, value and second-best bound at a block's start, from its candidates
    where they still prove it (moved_bound), else over every goal. Returns how many robots had no
    list to start from."""
    lowest = np.inf
    for j in range(len(price)):
        lowest = min(lowest, price[j])
    none = 0
    for i in range(len(px)):
        x0, y0 = lists.made_x[i], lists.made_y[i]
        lists.bound[i] = moved_bound(lists.made_bound[i], x0, y0, px[i] - x0, py[i] - y0, hull_x, hull_y, lowest)
        none += lists.made_bound[i] == np.inf  # no list: _rank ranks over every goal
        j1, v1, j2, v2, _ = _rank(i, px, py, gx, gy, price, penalty, has_penalty, lists, work)
        best[i], value[i] = j1, v1
        second[i] = v2 if j2 >= 0 else -np.inf
    return none


@njit(**BORROWS)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def jacobi_rounds(
    px,
    py,
    gx,
    gy,
    price,
    penalty,
    has_penalty,
    owner,
    released,
    goal,
    own_ids,
    row_of_id,
    best,
    value,
    second,
    lists,
    work,
    scratch,
    n,
    eps,
    slack,
    rounding,
    max_rounds,
):
    """Bid the first ``n`` robots of ``scratch.waiting`` (rows not content) and those they outbid
    until every robot is content. The board (price, owner, released), the claims ``goal``, the
    cached best goals (best, value, second, and ``scratch.seen``: the price of the best goal when
    its value was last exact) and the candidate lists change in place. ``row_of_id``: each robot
    id's row; ``scratch.touched`` marks every robot the rounds looked at (bidders and the robots
    they outbid). Returns (rounds, bids, robots still waiting)."""
    seen, touched, queue = scratch.seen, scratch.touched, scratch.queue
    unhappy = scratch.unhappy  # looked at this round and not content (False between rounds)
    look = scratch.look  # bidders and the robots they outbid (an id twice is harmless)
    bidders, bid_goal, bid_price = scratch.bidders, scratch.bid_goal, scratch.bid_price
    before = scratch.before  # owner of the goal bid on, as the round found it
    runner_up, third = scratch.runner_up, scratch.third  # the bidder's second-best goal and third-best value
    held, held_price = scratch.held, scratch.held_price  # the goal each bidder releases (-1: none), its price
    for a in range(n):
        queue[a] = scratch.waiting[a]
    rounds, bids = 0, 0
    while n > 0 and rounds < max_rounds:
        for a in range(n):  # ascending rows; mostly one or two bidders: an insertion sort
            q, s = queue[a], a
            while s > 0 and bidders[s - 1] > q:
                bidders[s] = bidders[s - 1]
                s -= 1
            bidders[s] = q
        # every bid against the board as the round found it
        for a in range(n):
            i = bidders[a]
            j1, v1, j2, v2, v3 = _rank(i, px, py, gx, gy, price, penalty, has_penalty, lists, work)
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
            v_bid = -_cost(i, j1, px, py, gx, gy, penalty, has_penalty) - price[j1]
            v_run = -_cost(i, j2, px, py, gx, gy, penalty, has_penalty) - price[j2] if j2 >= 0 else -np.inf
            others = max(v_bid, v3)  # bounds every goal but the runner-up
            if v_run > others and j2 != j1:  # the runner-up is the best now
                best[i], value[i], second[i] = j2, v_run, others
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
            touched[r] = True
            unhappy[r] = not _content(
                r,
                px,
                py,
                gx,
                gy,
                price,
                penalty,
                has_penalty,
                owner,
                released,
                goal,
                own_ids,
                best,
                value,
                second,
                seen,
                lists,
                work,
                slack,
                rounding,
            )
        n = 0  # the next bidders: every robot not content was looked at (it bid or was outbid)
        for a in range(m):
            r = look[a]
            if unhappy[r]:
                queue[n] = r
                n += 1
                unhappy[r] = False  # queued once
    return rounds, bids, n


@njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # numba's stubs lack its _nrt option
def settle_block(
    px,
    py,
    gx,
    gy,
    price,
    penalty,
    has_penalty,
    owner,
    released,
    goal,
    own_ids,
    row_of_id,
    best,
    value,
    second,
    lists,
    work,
    scratch,
    eps,
    slack,
    rounding,
    max_rounds,
):
    """One block of epsilon-scaling phases (``eps``, ``slack``) on frozen positions, warm from the
    board and from `first_ranking`: per phase the Jacobi rounds until every robot is content.
    Leaves every cached best value exact. Returns (rounds, bids, phases settled): fewer than
    len(eps) when a phase ran out of rounds."""
    k = len(goal)
    seen, touched = scratch.seen, scratch.touched
    may_bid = scratch.may_bid  # robots not content at the smallest slack left
    waiting = scratch.waiting
    for i in range(k):
        seen[i] = price[best[i]]
        touched[i] = False  # robots whose contentment may have changed since the last scan
    n_may, scan = 0, True
    rounds, bids = 0, 0
    for phase in range(len(eps)):
        if scan:  # after bids (or at first): who is not content at the smallest slack left
            least = slack[phase]
            for later in range(phase + 1, len(slack)):
                least = min(least, slack[later])
            for a in range(n_may):
                touched[may_bid[a]] = True
            n_may = 0
            for i in range(k):  # in ascending rows, as a scan of every robot
                if phase == 0 or touched[i]:
                    touched[i] = False
                    if not _content(
                        i,
                        px,
                        py,
                        gx,
                        gy,
                        price,
                        penalty,
                        has_penalty,
                        owner,
                        released,
                        goal,
                        own_ids,
                        best,
                        value,
                        second,
                        seen,
                        lists,
                        work,
                        least,
                        rounding,
                    ):
                        may_bid[n_may] = i
                        n_may += 1
        n = 0
        for a in range(n_may):  # who is not content at this phase's slack
            i = may_bid[a]
            if not _content(
                i,
                px,
                py,
                gx,
                gy,
                price,
                penalty,
                has_penalty,
                owner,
                released,
                goal,
                own_ids,
                best,
                value,
                second,
                seen,
                lists,
                work,
                slack[phase],
                rounding,
            ):
                waiting[n] = i
                n += 1
        r, b, left = jacobi_rounds(
            px,
            py,
            gx,
            gy,
            price,
            penalty,
            has_penalty,
            owner,
            released,
            goal,
            own_ids,
            row_of_id,
            best,
            value,
            second,
            lists,
            work,
            scratch,
            n,
            eps[phase],
            slack[phase],
            rounding,
            max_rounds,
        )
        rounds, bids, scan = rounds + r, bids + b, r > 0
        if left:
            return rounds, bids, phase
    for i in range(k):  # every best value exact for the prices as they are now
        _refresh(i, px, py, gx, gy, price, penalty, has_penalty, best, value, second, seen, lists, work)
    return rounds, bids, len(eps)
