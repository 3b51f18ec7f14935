"""The goal auction's bidding and assignment rounds (paper 5.1.1: Bertsekas' forward auction with
epsilon scaling), compiled once for every engine: a robot's bid depends only on its costs and the
board it bids against, so every engine reaches the same board, bit for bit. Terms and what keeps a
round cheap (cached rankings, candidate goals, the goal tree): docs/architecture.md, "Goal assignment".
"""

# cython: language_level=3

from libc.math cimport INFINITY, NAN, fabs, isnan, rint, sqrt
from libc.stdint cimport int32_t, int64_t, uint8_t, uint16_t, uint64_t
from libc.string cimport memcpy
from posix.time cimport CLOCK_MONOTONIC, clock_gettime, timespec

from agent.core.crew cimport (
    pthread_cond_broadcast,
    pthread_cond_destroy,
    pthread_cond_init,
    pthread_cond_t,
    pthread_cond_wait,
    pthread_create,
    pthread_join,
    pthread_mutex_destroy,
    pthread_mutex_init,
    pthread_mutex_lock,
    pthread_mutex_t,
    pthread_mutex_unlock,
    pthread_t,
    working_beside,
)
from agent.core.splitmix cimport splitmix64

import numpy as np

from transport.codec import AuctionRecord, Bid

NO_OWNER = -1  # a goal nobody claimed
cdef int64_t NOBODY = -1
cdef uint8_t RELEASED = AuctionRecord.RELEASED  # a record's flags
cdef uint8_t CONTENT = AuctionRecord.CONTENT, SETTLED = AuctionRecord.SETTLED
# relative slack for a bid's rounding: a robot an ulp short of content with the goal it just won would
# release it and bid again, feeding a price war at large warm prices
cdef double ROUNDING = 1e-12
cdef double FIXED = 2.0**32  # tilt_prices sums the robots' moves as whole multiples of 1 / FIXED m
# the most a robot's move counts in tilt_prices (m): 65,536 robots' sum in fixed point stays within an int64,
# whatever position a damaged record carries
cdef double MOST_MOVE = 2.0**14


cdef enum Job:  # the state of settle_beside's thread
    IDLE, ASKED, DONE, STOP


cdef inline bint greater(double price, int64_t robot, bint released, double b_price, int64_t b_owner,
                         bint b_released) noexcept nogil:
    """Is the record (price, robot, released) greater than the board's for its goal?"""
    if b_owner == NOBODY:
        return True
    if price != b_price:
        return price > b_price
    if robot != b_owner:
        return robot < b_owner
    return released and not b_released


cdef inline bint is_content(double held, double best, double slack) noexcept nogil:
    """The held goal's net value is within ``slack`` of the best, up to the rounding of a bid."""
    return held >= best - slack - ROUNDING * fabs(best)


cdef inline double bid_price(double price, double best, double second, double eps) noexcept nogil:
    """The price a bid offers for the best goal (second: the second-best value, or best - eps)."""
    return price + (best - second) + eps


cdef inline bint before(double v, int64_t j, double w, int64_t m) noexcept nogil:
    """Does goal j of value v rank before goal m of value w (value, then the lower index)?"""
    return v > w or (v == w and j < m)


ctypedef struct Ranking:
    int64_t first, runner_up, third_goal  # the best, second and third goals (-1: none)
    double best, second, third  # their values (-inf: none)


cdef inline Ranking unranked() noexcept nogil:
    cdef Ranking r
    r.first, r.runner_up, r.third_goal = -1, -1, -1
    r.best, r.second, r.third = -INFINITY, -INFINITY, -INFINITY
    return r


cdef inline void rank_in(Ranking* r, int64_t j, double v) noexcept nogil:
    """Goal j of value v into the ranking, if among its three best (by value, then the lower index)."""
    if not before(v, j, r.third, r.third_goal):  # most goals fail this test
        return
    if before(v, j, r.best, r.first):
        r.third_goal, r.third, r.runner_up, r.second, r.first, r.best = r.runner_up, r.second, r.first, r.best, j, v
    elif before(v, j, r.second, r.runner_up):
        r.third_goal, r.third, r.runner_up, r.second = r.runner_up, r.second, j, v
    else:
        r.third_goal, r.third = j, v


cdef packed struct Record:  # transport.codec.Bid.RECORD, one robot's word on one goal as the wire carries it
    uint16_t robot
    int32_t goal
    double price
    uint8_t flags
    float penalty, x, y


cdef inline Py_ssize_t row_among(const int64_t[::1] robots, int64_t robot) noexcept nogil:
    """The robot's row among the sorted ``robots`` (-1: not among them)."""
    cdef Py_ssize_t lo = 0, hi = robots.shape[0], mid
    while lo < hi:
        mid = (lo + hi) // 2
        if robots[mid] < robot:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < robots.shape[0] and robots[lo] == robot else -1


cdef class Heard:
    """Other hosts' records merged into a Participant's board (max-consensus), each other robot's
    newest claim of the current instance noted for the agreement check (the arrays are shared)."""

    cdef double[::1] price, heard_price
    cdef int64_t[::1] owner, robots, heard_instance, heard_serial, heard_goal
    cdef uint8_t[::1] released, is_own, heard_flags
    cdef uint64_t[::1] heard_digest

    def __init__(self, part):
        self.price, self.owner, self.released = part.board.price, part.board.owner, part.board.released.view(np.uint8)
        self.robots, self.is_own = part.robots, part.is_own.view(np.uint8)
        self.heard_instance, self.heard_serial = part.heard_instance, part.heard_serial
        self.heard_goal, self.heard_price = part.heard_goal, part.heard_price
        self.heard_flags, self.heard_digest = part.heard_flags, part.heard_digest

    def absorb(self, const Record[::1] recs, int64_t instance, bint current, int64_t serial,
               uint64_t digest) -> tuple[bool, bool]:
        """Merge the records (of ``instance``: the ``current`` one or not); returns (the board
        changed, a claim was noted)."""
        cdef bint changed = False, heard = False, rel
        cdef Py_ssize_t a, row
        cdef int64_t j
        for a in range(recs.shape[0]):
            j, rel = recs[a].goal, (recs[a].flags & RELEASED) != 0
            if 0 <= j < self.price.shape[0] and greater(recs[a].price, recs[a].robot, rel, self.price[j],
                                                        self.owner[j], self.released[j]):
                self.price[j], self.owner[j], self.released[j] = recs[a].price, recs[a].robot, rel
                changed = True
            row = row_among(self.robots, recs[a].robot)
            if not current or rel or row < 0 or self.is_own[row]:
                continue
            if self.heard_instance[row] < instance or serial > self.heard_serial[row]:
                self.heard_instance[row], self.heard_serial[row] = instance, serial
                self.heard_goal[row], self.heard_price[row] = j, recs[a].price
                self.heard_flags[row] = recs[a].flags
                self.heard_digest[row] = digest
                heard = True
        return changed, heard


cpdef double moved_bound(double made, double x0, double y0, double dx, double dy, const double[::1] hull_x,
                         const double[::1] hull_y, double lowest) noexcept nogil:
    """An upper bound now of every goal's value off a robot's list, made at (x0, y0) with bound
    ``made``, after it moved by D = (dx, dy) (prices only rose; ``lowest``: the lowest price): the
    lesser of made + 2 (h(D) - p.D) - |D|^2, h the hull's support function, and -(sqrt(-u) - |D|)^2 -
    lowest with u = made + lowest < 0 (only near goals count). +inf without a list or hull points."""
    cdef double h = -INFINITY, grow, moved, u, near
    cdef Py_ssize_t a
    if hull_x.shape[0] == 0:
        return INFINITY
    for a in range(hull_x.shape[0]):
        h = max(h, hull_x[a] * dx + hull_y[a] * dy)
    grow = 2.0 * (h - (x0 * dx + y0 * dy)) - (dx * dx + dy * dy)
    moved = made + grow
    if made < INFINITY:
        u = made + lowest
        near = max(sqrt(-u) - sqrt(dx * dx + dy * dy), 0.0) if u < 0.0 else 0.0
        moved = min(moved, -near * near - lowest)
    return moved + 1e-9 * (fabs(moved) + fabs(made) + fabs(grow) + fabs(lowest) + 1.0)  # room for rounding


LEAF = 16  # goals per leaf of the goal tree


def goal_tree(goals, int leaf=LEAF):
    """A k-d tree of the goals (G, 2) in preorder, split at the median of the wider side: (order,
    left, right, start, end, box); a node's goals are order[start:end], -1 children: a leaf."""
    goals = np.asarray(goals, float).reshape(-1, 2)
    order = np.arange(len(goals), dtype=np.int64)
    left, right, start, end, box = [], [], [], [], []

    def build(lo, hi):
        node = len(start)
        pts = goals[order[lo:hi]]
        start.append(lo), end.append(hi), left.append(-1), right.append(-1)
        if hi > lo:
            box.append((pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()))
        else:
            box.append((INFINITY, -INFINITY, INFINITY, -INFINITY))
        if hi - lo > leaf:
            axis = int(np.argmax(np.ptp(pts, axis=0)))
            order[lo:hi] = order[lo:hi][np.argsort(pts[:, axis], kind="stable")]
            mid = (lo + hi) // 2
            left[node] = build(lo, mid)
            right[node] = build(mid, hi)
        return node

    build(0, len(goals))
    ints = [np.array(a, np.int64) for a in (left, right, start, end)]
    return order, *ints, np.array(box, float).reshape(-1, 4)


cdef class Bidders:
    """A host's own robots (rows) bidding on one goal set's board, with their cached rankings and
    candidates, and the scratch of a round (made once: nothing in the rounds allocates)."""

    cdef Py_ssize_t k, g
    cdef double[::1] px, py, gx, gy, hull_x, hull_y
    cdef double[::1] price  # the board's (shared with agent.core.bidder.Board)
    cdef int64_t[::1] owner
    cdef uint8_t[::1] released
    cdef int64_t[::1] goal  # each robot's claim (shared with the Participant)
    cdef int64_t[::1] robot  # each row's robot id
    cdef int64_t[::1] row_of_id
    # C_d in force (deadlocks, rare): robot i's are on goals penalty_goal[penalty_start[i]:penalty_start[i + 1]]
    cdef int64_t[::1] penalty_start, penalty_goal
    cdef double[::1] penalty_cost
    cdef readonly bint has_penalty
    # the cached ranking: best goal, its value (exact while its price is ``seen``), second-best bound
    cdef int64_t[::1] best
    cdef double[::1] value, second, seen
    # K candidate goals per robot (-1: none) and their costs c_ij this block, a bound of every other goal
    # (+inf: no list), where made
    cdef int64_t[:, ::1] cand
    cdef double[:, ::1] cand_cost
    cdef double[::1] bound, made_x, made_y, made_bound
    # the goal tree, per node a lower bound of its prices and a plane under them, and the least penalty
    cdef int64_t[::1] order, node_left, node_right, node_start, node_end, node_parent, leaf_of
    cdef double[::1] node_x0, node_x1, node_y0, node_y1, node_price, plane_a, plane_bx, plane_by
    cdef double least_penalty
    # scratch of a ranking anew: its K + 1 best goals so far
    cdef double[::1] top_value
    cdef int64_t[::1] top_goal
    cdef int64_t[::1] seeded  # per goal, the rank_all that took it into ``top`` before its search
    cdef int64_t seed_mark
    # scratch of a block: who may bid, waits, is queued, was looked at, and per bid what it bid and released
    cdef int64_t[::1] may_bid, waiting, queue, look, bidders, bid_goal, owner_before, runner_up, held
    cdef double[::1] offer, third, held_price
    cdef uint8_t[::1] touched, unhappy
    # settle_beside's block and outcome; its thread, made at the first block, sleeps on job_wake between
    cdef const double[::1] job_eps, job_slack
    cdef int64_t job_max_rounds, job_rounds, job_bids
    cdef Py_ssize_t job_settled, job_without
    cdef readonly double job_seconds  # the wall time of the last block on the thread
    cdef pthread_t job_thread
    cdef pthread_mutex_t job_lock
    cdef pthread_cond_t job_wake
    cdef Job job
    cdef bint has_thread
    cdef readonly bint settling

    def __init__(self, board, goals, robot, goal, hull, int candidates):
        """``board``: price, owner, released of the goals (G, 2); ``robot``: each row's id; ``goal``:
        the claims, shared and changed in place."""
        goals = np.asarray(goals, float).reshape(-1, 2)
        self.k, self.g = len(robot), len(goals)
        k, g = self.k, self.g
        self.gx, self.gy = np.ascontiguousarray(goals[:, 0]), np.ascontiguousarray(goals[:, 1])
        self.hull_x = np.ascontiguousarray(hull[0], float)
        self.hull_y = np.ascontiguousarray(hull[1], float)
        self.price, self.owner, self.released = board.price, board.owner, board.released.view(np.uint8)
        self.robot = np.ascontiguousarray(robot, np.int64)
        row_of_id = np.full(int(np.max(robot, initial=0)) + 1, -1, np.int64)
        row_of_id[np.asarray(robot, np.int64)] = np.arange(k)
        self.row_of_id = row_of_id
        self.goal = goal
        self.set_penalties(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
        self.px, self.py = np.zeros(k), np.zeros(k)
        self.best, self.value = np.zeros(k, np.int64), np.zeros(k)
        self.second, self.seen = np.full(k, INFINITY), np.full(k, NAN)
        if candidates < 2:
            raise ValueError("a robot ranks at least 2 candidate goals")
        self.cand = np.full((k, candidates), -1, np.int64)
        self.cand_cost = np.zeros((k, candidates))
        self.bound = np.full(k, INFINITY)
        self.made_x, self.made_y, self.made_bound = np.zeros(k), np.zeros(k), np.full(k, INFINITY)
        self.order, self.node_left, self.node_right, self.node_start, self.node_end, box = goal_tree(goals)
        self.node_x0, self.node_x1 = np.ascontiguousarray(box[:, 0]), np.ascontiguousarray(box[:, 1])
        self.node_y0, self.node_y1 = np.ascontiguousarray(box[:, 2]), np.ascontiguousarray(box[:, 3])
        self.node_price = np.full(len(box), -INFINITY)  # renewed by first_ranking
        self.plane_a, self.plane_bx, self.plane_by = np.full(len(box), -INFINITY), np.zeros(len(box)), np.zeros(len(box))
        parent, leaf_of = np.full(len(box), -1, np.int64), np.zeros(g, np.int64)
        inner = np.flatnonzero(np.asarray(self.node_left) >= 0)
        parent[np.asarray(self.node_left)[inner]] = parent[np.asarray(self.node_right)[inner]] = inner
        for node in np.flatnonzero(np.asarray(self.node_left) < 0):
            leaf_of[self.order[self.node_start[node]:self.node_end[node]]] = node
        self.node_parent, self.leaf_of = parent, leaf_of
        self.top_value, self.top_goal = np.empty(candidates + 1), np.empty(candidates + 1, np.int64)
        self.seeded, self.seed_mark = np.zeros(g, np.int64), 0
        self.may_bid, self.waiting, self.queue = np.zeros(k, np.int64), np.zeros(k, np.int64), np.zeros(k, np.int64)
        self.look, self.bidders, self.bid_goal = np.zeros(2 * k, np.int64), np.zeros(k, np.int64), np.zeros(k, np.int64)
        self.owner_before, self.runner_up, self.held = np.zeros(k, np.int64), np.zeros(k, np.int64), np.zeros(k, np.int64)
        self.offer, self.third, self.held_price = np.zeros(k), np.zeros(k), np.zeros(k)
        self.touched, self.unhappy = np.zeros(k, np.uint8), np.zeros(k, np.uint8)

    @property
    def candidates(self) -> int:
        return self.cand.shape[1]

    def set_penalties(self, rows, goals, costs) -> None:
        """The penalties in force: row rows[a] pays costs[a] more for goals[a] (sorted by row)."""
        rows = np.ascontiguousarray(rows, np.int64)
        self.penalty_start = np.searchsorted(rows, np.arange(self.k + 1)).astype(np.int64)
        self.penalty_goal = np.ascontiguousarray(goals, np.int64)
        self.penalty_cost = np.ascontiguousarray(costs, float)
        self.has_penalty = len(rows) > 0
        self.least_penalty = min(float(np.min(self.penalty_cost, initial=0.0)), 0.0)

    cdef inline double penalty(self, Py_ssize_t i, int64_t j) noexcept nogil:
        cdef Py_ssize_t a
        for a in range(self.penalty_start[i], self.penalty_start[i + 1]):
            if self.penalty_goal[a] == j:
                return self.penalty_cost[a]
        return 0.0

    def tilt_prices(self, const float[:, ::1] before, const float[:, ::1] last) -> bool:
        """Raise the prices by 2 d . g_j less their least, d the robots' mean move from ``before`` to
        ``last`` (positions by robot row, as the records carry them; NaN: not heard), each within
        MOST_MOVE, summed in whole units of 1 / FIXED m so that every host gets the same bits. True: a
        price changed."""
        cdef int64_t sx = 0, sy = 0, heard = 0
        cdef double dx, dy, tilt, least = INFINITY, most = -INFINITY
        cdef Py_ssize_t i, j
        for i in range(last.shape[0]):
            dx = <double>last[i, 0] - <double>before[i, 0]
            dy = <double>last[i, 1] - <double>before[i, 1]
            if not isnan(dx):  # heard in both blocks
                sx += <int64_t>rint(min(max(dx, -MOST_MOVE), MOST_MOVE) * FIXED)
                sy += <int64_t>rint(min(max(dy, -MOST_MOVE), MOST_MOVE) * FIXED)
                heard += 1
        if heard == 0:
            return False
        dx, dy = sx / (FIXED * heard), sy / (FIXED * heard)
        for j in range(self.g):
            tilt = 2.0 * (self.gx[j] * dx + self.gy[j] * dy)
            least, most = min(least, tilt), max(most, tilt)
        if not most > least:  # every goal raised alike: no price changes
            return False
        for j in range(self.g):
            self.price[j] += 2.0 * (self.gx[j] * dx + self.gy[j] * dy) - least
        return True

    def freeze(self, position) -> None:
        """The robots' positions (K, 2) for the block."""
        position = np.asarray(position, float).reshape(-1, 2)
        self.px, self.py = np.ascontiguousarray(position[:, 0]), np.ascontiguousarray(position[:, 1])

    # --- ranking ------------------------------------------------------------------------------------
    cdef inline double cost(self, Py_ssize_t i, int64_t j) noexcept nogil:
        """c_ij: eq. 7 plus robot i's penalties."""
        cdef double dx = self.gx[j] - self.px[i], dy = self.gy[j] - self.py[i]
        cdef double c = dx * dx + dy * dy
        if self.has_penalty:
            c = c + self.penalty(i, j)
        return c

    cdef inline double net_value(self, Py_ssize_t i, int64_t j) noexcept nogil:
        """-c_ij - b_j."""
        return -self.cost(i, j) - self.price[j]

    cdef inline void cost_candidates(self, Py_ssize_t i) noexcept nogil:
        """Robot i's candidates' costs, kept while the positions and penalties hold (a block, or its
        phases until a penalty comes into force): a ranking then reads only their prices anew."""
        cdef Py_ssize_t s
        for s in range(self.cand.shape[1]):
            if self.cand[i, s] >= 0:
                self.cand_cost[i, s] = self.cost(i, self.cand[i, s])

    cdef inline double box_distance2(self, int64_t node, double x, double y) noexcept nogil:
        """The squared distance from (x, y) to the nearest point of the node's box."""
        cdef double dx = max(max(self.node_x0[node] - x, x - self.node_x1[node]), 0.0)
        cdef double dy = max(max(self.node_y0[node] - y, y - self.node_y1[node]), 0.0)
        return dx * dx + dy * dy

    cdef inline double node_bound(self, int64_t node, double x, double y) noexcept nogil:
        """An upper bound of every node goal's value to a robot at p = (x, y): the lesser of the box's
        nearest point at its least price, and by the plane b_j >= a + beta . g_j under its prices,
        -|g_j - q|^2 - a - beta . p + |beta|^2 / 4 with q = p - beta / 2 (tighter where prices climb)."""
        cdef double flat = (-self.box_distance2(node, x, y) - self.node_price[node]) - self.least_penalty
        cdef double bx = self.plane_bx[node], by = self.plane_by[node], d2, lift, tilted
        if (bx == 0.0 and by == 0.0) or not flat > -INFINITY:  # no slope, or no goal
            return flat
        d2 = self.box_distance2(node, x - 0.5 * bx, y - 0.5 * by)
        lift = 0.25 * (bx * bx + by * by)
        tilted = -d2 - self.plane_a[node] - bx * x - by * y + lift - self.least_penalty
        tilted += 1e-9 * (d2 + fabs(self.plane_a[node]) + fabs(bx * x) + fabs(by * y) + lift + 1.0)
        return min(flat, tilted)

    cdef void search(self, Py_ssize_t i, int64_t node, double bound) noexcept nogil:
        """Robot i's K + 1 best goals of the node into ``top``, passing over nodes that cannot hold one;
        renews the least prices it looks at."""
        cdef Py_ssize_t kk = self.cand.shape[1], a
        cdef int64_t j, near, far
        cdef double least = INFINITY, b_near, b_far
        if bound < self.top_value[kk]:  # equal: a goal of the node may tie and rank first by index
            return
        if self.node_left[node] < 0:
            for a in range(self.node_start[node], self.node_end[node]):
                j = self.order[a]
                least = min(least, self.price[j])
                if self.seeded[j] != self.seed_mark:
                    self.into_top(j, self.net_value(i, j))
            self.node_price[node] = least
            return
        near, far = self.node_left[node], self.node_right[node]
        b_near, b_far = self.node_bound(near, self.px[i], self.py[i]), self.node_bound(far, self.px[i], self.py[i])
        if b_far > b_near:
            near, far, b_near, b_far = far, near, b_far, b_near
        self.search(i, near, b_near)
        self.search(i, far, b_far)
        self.node_price[node] = min(self.node_price[near], self.node_price[far])

    cdef inline void into_top(self, int64_t j, double v) noexcept nogil:
        """Goal j of value v into ``top``, if among its K + 1 best."""
        cdef Py_ssize_t s = self.cand.shape[1]
        if before(v, j, self.top_value[s], self.top_goal[s]):
            while s > 0 and before(v, j, self.top_value[s - 1], self.top_goal[s - 1]):
                self.top_value[s], self.top_goal[s] = self.top_value[s - 1], self.top_goal[s - 1]
                s -= 1
            self.top_value[s], self.top_goal[s] = v, j

    cdef Ranking rank_all(self, Py_ssize_t i) noexcept nogil:
        """Robot i's three best goals by a search of the goal tree; renews its K candidates and
        ``bound``, the next one's value."""
        cdef Py_ssize_t s, kk = self.cand.shape[1]
        cdef int64_t j
        cdef Ranking r = unranked()
        for s in range(kk + 1):
            self.top_value[s], self.top_goal[s] = -INFINITY, -1
        self.seed_mark += 1  # its last candidates first: the search then passes over more of the tree
        for s in range(kk):
            j = self.cand[i, s]
            if j >= 0:
                self.seeded[j] = self.seed_mark
                self.into_top(j, -self.cand_cost[i, s] - self.price[j])
        self.search(i, 0, self.node_bound(0, self.px[i], self.py[i]))
        r.first, r.best = self.top_goal[0], self.top_value[0]
        r.runner_up, r.second = self.top_goal[1], self.top_value[1]
        r.third_goal, r.third = self.top_goal[2], self.top_value[2]  # K >= 2: top holds three
        for s in range(kk):
            self.cand[i, s] = j = self.top_goal[s]
            if j >= 0:
                self.cand_cost[i, s] = self.cost(i, j)
        self.bound[i] = self.made_bound[i] = self.top_value[kk]
        self.made_x[i], self.made_y[i] = self.px[i], self.py[i]
        return r

    cdef void price_rose(self, int64_t j) noexcept nogil:
        """Goal j's price rose: renew its leaf's least price, and its ancestors' while theirs rise."""
        cdef int64_t node = self.leaf_of[j], up
        cdef Py_ssize_t a
        cdef double least = INFINITY
        for a in range(self.node_start[node], self.node_end[node]):
            least = min(least, self.price[self.order[a]])
        while least > self.node_price[node]:
            self.node_price[node] = least
            up = self.node_parent[node]
            if up < 0:
                return
            least = min(self.node_price[self.node_left[up]], self.node_price[self.node_right[up]])
            node = up

    cdef void fit_price_planes(self) noexcept nogil:
        """Per node a plane under its prices, b_j >= a + beta . g_j: the least-squares slope lowered
        onto the lowest (prices only rise until the next fit, at a block's start)."""
        cdef Py_ssize_t node, a, lo, hi
        cdef int64_t j
        cdef double n, mx, my, mb, sxx, sxy, syy, sxb, syb, det, bx, by, least, u, ux, uy
        for node in range(self.node_price.shape[0]):
            lo, hi = self.node_start[node], self.node_end[node]
            bx = by = 0.0
            if hi - lo >= 3:
                n, mx, my, mb = hi - lo, 0.0, 0.0, 0.0
                for a in range(lo, hi):
                    j = self.order[a]
                    mx, my, mb = mx + self.gx[j], my + self.gy[j], mb + self.price[j]
                mx, my, mb = mx / n, my / n, mb / n
                sxx = sxy = syy = sxb = syb = 0.0
                for a in range(lo, hi):
                    j = self.order[a]
                    ux, uy, u = self.gx[j] - mx, self.gy[j] - my, self.price[j] - mb
                    sxx, sxy, syy = sxx + ux * ux, sxy + ux * uy, syy + uy * uy
                    sxb, syb = sxb + ux * u, syb + uy * u
                det = sxx * syy - sxy * sxy
                if det > 1e-9 * sxx * syy:  # goals not on a line
                    bx, by = (syy * sxb - sxy * syb) / det, (sxx * syb - sxy * sxb) / det
            least = INFINITY
            for a in range(lo, hi):
                j = self.order[a]
                ux, uy = bx * self.gx[j], by * self.gy[j]
                u = self.price[j] - ux - uy
                least = min(least, u - 1e-9 * (fabs(self.price[j]) + fabs(ux) + fabs(uy) + 1.0))
            self.plane_a[node], self.plane_bx[node], self.plane_by[node] = least, bx, by

    cdef void renew_prices(self) noexcept nogil:
        """Every node's least price as the board stands (children come after their parent)."""
        cdef Py_ssize_t node, a
        cdef double least
        for node in range(self.node_price.shape[0] - 1, -1, -1):
            if self.node_left[node] >= 0:
                least = min(self.node_price[self.node_left[node]], self.node_price[self.node_right[node]])
            else:
                least = INFINITY
                for a in range(self.node_start[node], self.node_end[node]):
                    least = min(least, self.price[self.order[a]])
            self.node_price[node] = least

    cdef Ranking rank(self, Py_ssize_t i, bint runner_up) noexcept nogil:
        """Robot i's best goal, and its ``runner_up`` (what a bid needs), exact; the values after them
        only bounded (any goal's but those ranked is at most the third's): from its candidates when
        they provably hold those goals, else rank_all."""
        cdef Ranking r = unranked()
        cdef Py_ssize_t s
        cdef int64_t j
        for s in range(self.cand.shape[1]):
            j = self.cand[i, s]
            if j >= 0:
                rank_in(&r, j, -self.cand_cost[i, s] - self.price[j])
        if (r.second if runner_up else r.best) > self.bound[i]:  # ties at the bound: ranked over every goal
            r.third = max(r.third, self.bound[i])
            if not runner_up:
                r.second = max(r.second, self.bound[i])
            return r
        return self.rank_all(i)

    cdef inline void remember(self, Py_ssize_t i, Ranking r) noexcept nogil:
        """Robot i's ranking into the cache: its best goal and value, exact for the prices as they are,
        and a bound of every other goal's value."""
        self.best[i], self.value[i] = r.first, r.best
        self.second[i] = r.second
        self.seen[i] = self.price[r.first]

    cdef inline void refresh(self, Py_ssize_t i) noexcept nogil:
        """Make robot i's best goal and value exact (ranked anew only if it fell to its second-best bound)."""
        cdef int64_t b = self.best[i]
        cdef double now
        if not self.price[b] == self.seen[i]:  # NaN: rank anew
            now = self.net_value(i, b)
            self.value[i] = now
            if now > self.second[i]:
                self.seen[i] = self.price[b]
            else:
                self.remember(i, self.rank(i, False))

    cdef bint content(self, Py_ssize_t i, double slack) noexcept nogil:
        """Does robot i hold its goal within ``slack`` of its best? (One holding none is not ranked.)"""
        cdef int64_t g = self.goal[i]
        if g < 0 or self.owner[g] != self.robot[i] or self.released[g]:
            return False
        self.refresh(i)
        return is_content(self.net_value(i, g), self.value[i], slack)

    def first_ranking(self) -> int:
        """Every robot's ranking at a block's start (or once penalties rose), from its candidates where
        moved_bound proves them; returns how many had no list."""
        cdef Py_ssize_t none
        with nogil:
            none = self.rank_first()
        return none

    cdef Py_ssize_t rank_first(self) noexcept nogil:
        """first_ranking's work."""
        cdef double lowest = INFINITY, x0, y0
        cdef Py_ssize_t i, j, none = 0
        if self.g == 0:
            return self.k
        self.renew_prices()  # prices may have been set anew between blocks (a carried board)
        self.fit_price_planes()
        for j in range(self.g):
            lowest = min(lowest, self.price[j])
        for i in range(self.k):
            x0, y0 = self.made_x[i], self.made_y[i]
            self.bound[i] = moved_bound(self.made_bound[i], x0, y0, self.px[i] - x0, self.py[i] - y0,
                                        self.hull_x, self.hull_y, lowest)
            if self.bound[i] == INFINITY:
                self.made_bound[i] = INFINITY  # no list: rank_all searches the goal tree
            none += self.made_bound[i] == INFINITY
            self.cost_candidates(i)  # positions or penalties new: every ranking from here reads these
            self.remember(i, self.rank(i, False))
        return none

    def ranking(self) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's best goal and net value, exact for the board as it is (copies)."""
        cdef Py_ssize_t i
        if self.g:
            for i in range(self.k):
                self.refresh(i)
        return np.asarray(self.best).copy(), np.asarray(self.value).copy()

    def contentment(self, double slack) -> np.ndarray:
        """(K,) bool: each robot holds its goal and no goal is better by more than ``slack``."""
        out = np.zeros(self.k, bool)
        cdef uint8_t[::1] o = out.view(np.uint8)
        cdef Py_ssize_t i
        if self.g:
            for i in range(self.k):
                o[i] = self.content(i, slack)
        return out

    def records(self, const double[:, ::1] position, double slack, bint settled, double final_slack) -> np.ndarray:
        """Participant.records: a claim each (goal held, else -1), CONTENT at ``slack``, SETTLED (if
        ``settled``) at ``final_slack``, penalties' sum and position; then the releases, by goal."""
        cdef Py_ssize_t i, j, a, k = self.k, released = 0, n
        cdef int64_t g
        cdef double penalty
        for j in range(self.g):
            released += self.released_by_own(j)
        out = np.zeros(k + released, Bid.RECORD)
        cdef Record[::1] r = out
        for i in range(k):
            g = self.goal[i]
            r[i].robot = <uint16_t>self.robot[i]
            r[i].goal = -1
            if 0 <= g < self.g and self.owner[g] == self.robot[i] and not self.released[g]:
                r[i].goal, r[i].price = <int32_t>g, self.price[g]
            penalty = 0.0
            for a in range(self.penalty_start[i], self.penalty_start[i + 1]):
                penalty += self.penalty_cost[a]
            r[i].penalty, r[i].x, r[i].y = <float>penalty, <float>position[i, 0], <float>position[i, 1]
        if self.g:  # every robot's CONTENT before any SETTLED: content() renews the robot's ranking
            for i in range(k):
                r[i].flags = CONTENT if self.content(i, slack) else 0
            for i in range(k if settled else 0):
                if self.content(i, final_slack):
                    r[i].flags |= SETTLED
        n = k
        for j in range(self.g):
            if self.released_by_own(j):
                r[n].robot, r[n].goal, r[n].price, r[n].flags = <uint16_t>self.owner[j], <int32_t>j, self.price[j], RELEASED
                n += 1
        return out

    cdef inline bint released_by_own(self, Py_ssize_t j) noexcept nogil:
        """Goal j carries a release, by one of these robots, on the board."""
        cdef int64_t owner = self.owner[j]
        return self.released[j] and 0 <= owner < self.row_of_id.shape[0] and self.row_of_id[owner] >= 0

    # --- rounds -------------------------------------------------------------------------------------
    cdef Py_ssize_t jacobi_round(self, Py_ssize_t n, double eps) noexcept nogil:
        """The first ``n`` rows of ``bidders`` (ascending) bid at once; fills ``look`` with the bidders
        and the robots they outbid, returns how many."""
        cdef Py_ssize_t a, m = 0
        cdef int64_t i, h, j, o, r2
        cdef Ranking r
        cdef double v_bid, v_run, others
        for a in range(n):  # every bid against the board as the round found it
            i = self.bidders[a]
            r = self.rank(i, True)
            if r.runner_up < 0:  # one goal: the bid rises by epsilon twice
                r.second = r.best - eps
            self.bid_goal[a], self.owner_before[a] = r.first, self.owner[r.first]
            self.offer[a] = bid_price(self.price[r.first], r.best, r.second, eps)
            self.runner_up[a], self.third[a] = r.runner_up, r.third
            h = self.goal[i]  # the goal it gives up, at the price the round found
            if h >= 0 and self.owner[h] == self.robot[i] and not self.released[h]:
                self.held[a], self.held_price[a] = h, self.price[h]
            else:
                self.held[a] = -1
        for a in range(n):  # max-consensus: the order of the merges does not matter
            i = self.bidders[a]
            h = self.held[a]
            if h >= 0 and greater(self.held_price[a], self.robot[i], True, self.price[h], self.owner[h], self.released[h]):
                self.price[h], self.owner[h], self.released[h] = self.held_price[a], self.robot[i], True
            j = self.bid_goal[a]
            if greater(self.offer[a], self.robot[i], False, self.price[j], self.owner[j], self.released[j]):
                self.price[j], self.owner[j], self.released[j] = self.offer[a], self.robot[i], False
                self.price_rose(j)
        for a in range(n):
            i = self.bidders[a]
            # the runner-up is the best now if it beats the dearer goal bid on and the third's bound, else rank anew
            j, r2 = self.bid_goal[a], self.runner_up[a]
            v_bid = self.net_value(i, j)
            v_run = self.net_value(i, r2) if r2 >= 0 else -INFINITY
            others = max(v_bid, self.third[a])  # bounds every goal but the runner-up
            if v_run > others and r2 != j:
                self.best[i], self.value[i], self.second[i] = r2, v_run, others
                self.seen[i] = self.price[r2]
            else:
                self.best[i], self.value[i], self.second[i] = j, v_bid, INFINITY
                self.seen[i] = NAN
            self.goal[i] = j
            self.look[m] = i
            m += 1
            o = self.owner_before[a]
            if o != NOBODY and self.owner[j] != o:
                self.look[m] = self.row_of_id[o]
                m += 1
        return m

    def bid(self, double eps, double slack) -> int:
        """One Jacobi round: every robot not content at ``slack`` bids. Returns how many bid."""
        cdef Py_ssize_t i, n = 0
        if self.g == 0:
            return 0
        with nogil:
            for i in range(self.k):
                if not self.content(i, slack):
                    self.bidders[n] = i
                    n += 1
            if n:
                self.jacobi_round(n, eps)
        return n

    cdef (int64_t, int64_t, Py_ssize_t) rounds(self, Py_ssize_t n, double eps, double slack,
                                              int64_t max_rounds) noexcept nogil:
        """Bid ``waiting``'s first ``n`` and those they outbid until all are content at ``slack``,
        marking ``touched``; returns (rounds, bids, robots still waiting)."""
        cdef Py_ssize_t a, s, m
        cdef int64_t q, rounds = 0, bids = 0, r
        for a in range(n):
            self.queue[a] = self.waiting[a]
        while n > 0 and rounds < max_rounds:
            for a in range(n):  # ascending rows; mostly one or two bidders: an insertion sort
                q, s = self.queue[a], a
                while s > 0 and self.bidders[s - 1] > q:
                    self.bidders[s] = self.bidders[s - 1]
                    s -= 1
                self.bidders[s] = q
            m = self.jacobi_round(n, eps)
            bids += n
            rounds += 1
            for a in range(m):
                r = self.look[a]
                self.touched[r] = True
                self.unhappy[r] = not self.content(r, slack)
            n = 0  # the next bidders: every robot not content was looked at (it bid or was outbid)
            for a in range(m):
                r = self.look[a]
                if self.unhappy[r]:
                    self.queue[n] = r
                    n += 1
                    self.unhappy[r] = False  # queued once
        return rounds, bids, n

    def settle_block(self, eps, slack, int64_t max_rounds) -> tuple[int, int, int, int, float]:
        """A block of epsilon-scaling phases: its first ranking, then per phase Jacobi rounds until all
        are content. Returns (rounds, bids, phases settled, robots without a list, wall seconds)."""
        self.ask(eps, slack, max_rounds)
        with nogil:
            self.settle_timed()
        return self.outcome()

    def settle_beside(self, eps, slack, int64_t max_rounds) -> None:
        """settle_block on a thread that never takes the GIL, so the central engine steps meanwhile; it
        sleeps for the next block. Touch nothing of these bidders until ``settled`` has returned."""
        if self.settling:
            raise RuntimeError("a block is settling already")
        self.ask(eps, slack, max_rounds)
        if not self.has_thread:
            pthread_mutex_init(&self.job_lock, NULL)
            pthread_cond_init(&self.job_wake, NULL)
            self.job = IDLE
            if pthread_create(&self.job_thread, NULL, settle_thread, <void*>self) != 0:
                pthread_cond_destroy(&self.job_wake)
                pthread_mutex_destroy(&self.job_lock)
                raise OSError("no thread to settle the block on")
            self.has_thread = True
        with nogil:
            pthread_mutex_lock(&self.job_lock)
            self.job = ASKED
            pthread_cond_broadcast(&self.job_wake)
            pthread_mutex_unlock(&self.job_lock)
        self.settling = True

    def settled(self) -> tuple[int, int, int, int, float]:
        """Wait for the block of settle_beside; what settle_block returns."""
        if not self.settling:
            raise RuntimeError("no block is settling")
        with nogil:
            pthread_mutex_lock(&self.job_lock)
            while self.job != DONE:
                pthread_cond_wait(&self.job_wake, &self.job_lock)
            self.job = IDLE
            pthread_mutex_unlock(&self.job_lock)
        self.settling = False
        return self.outcome()

    cdef void ask(self, eps, slack, int64_t max_rounds):
        """The block's phases and round bound, for settle_timed."""
        self.job_eps = np.ascontiguousarray(eps, float)
        self.job_slack = np.ascontiguousarray(slack, float)
        self.job_max_rounds = max_rounds

    cdef tuple outcome(self):
        return self.job_rounds, self.job_bids, self.job_settled, self.job_without, self.job_seconds

    def __dealloc__(self):
        if not self.has_thread:
            return
        with nogil:  # a block under way is finished first
            pthread_mutex_lock(&self.job_lock)
            while self.job == ASKED:
                pthread_cond_wait(&self.job_wake, &self.job_lock)
            self.job = STOP
            pthread_cond_broadcast(&self.job_wake)
            pthread_mutex_unlock(&self.job_lock)
            pthread_join(self.job_thread, NULL)
        pthread_cond_destroy(&self.job_wake)
        pthread_mutex_destroy(&self.job_lock)

    cdef void serve(self) noexcept nogil:
        """settle_beside's thread: each block asked for, until told to stop."""
        pthread_mutex_lock(&self.job_lock)
        while True:
            while self.job != ASKED and self.job != STOP:
                pthread_cond_wait(&self.job_wake, &self.job_lock)
            if self.job == STOP:
                break
            pthread_mutex_unlock(&self.job_lock)
            working_beside(1)  # the crew sharing the engine's rows leaves this block a core
            self.settle_timed()
            working_beside(-1)
            pthread_mutex_lock(&self.job_lock)
            self.job = DONE
            pthread_cond_broadcast(&self.job_wake)
        pthread_mutex_unlock(&self.job_lock)

    cdef void settle_job(self) noexcept nogil:
        """The phases of ``job_eps``, ``job_slack`` after the first ranking, into job_*."""
        cdef const double[::1] eps = self.job_eps
        cdef const double[::1] slack = self.job_slack
        cdef Py_ssize_t i, a, phase, later, n, n_may = 0, k = self.k
        cdef bint scan = True
        cdef int64_t rounds = 0, bids = 0, r, b, left
        cdef double least
        cdef Py_ssize_t settled = eps.shape[0]
        for i in range(k):
            self.seen[i] = self.price[self.best[i]]
            self.touched[i] = False  # robots whose contentment may have changed since the last scan
        for phase in range(eps.shape[0]):
            if scan:  # after bids (or at first): who is not content at the least slack left
                least = slack[phase]
                for later in range(phase + 1, slack.shape[0]):
                    least = min(least, slack[later])
                for a in range(n_may):
                    self.touched[self.may_bid[a]] = True
                n_may = 0
                for i in range(k):  # in ascending rows, as a scan of every robot
                    if phase == 0 or self.touched[i]:
                        self.touched[i] = False
                        if not self.content(i, least):
                            self.may_bid[n_may] = i
                            n_may += 1
            n = 0
            for a in range(n_may):  # who is not content at this phase's slack
                i = self.may_bid[a]
                if not self.content(i, slack[phase]):
                    self.waiting[n] = i
                    n += 1
            r, b, left = self.rounds(n, eps[phase], slack[phase], self.job_max_rounds)
            rounds, bids, scan = rounds + r, bids + b, r > 0
            if left:
                settled = phase
                break
        if settled == eps.shape[0]:
            for i in range(k):  # every best value exact for the prices as they are now
                self.refresh(i)
        self.job_rounds, self.job_bids, self.job_settled = rounds, bids, settled

    cdef void settle_timed(self) noexcept nogil:
        """The block's first ranking, then its phases, timed (settle_block's work)."""
        cdef timespec t0, t1
        clock_gettime(CLOCK_MONOTONIC, &t0)
        self.job_without = self.rank_first()
        self.settle_job()
        clock_gettime(CLOCK_MONOTONIC, &t1)
        self.job_seconds = (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec)


cdef void* settle_thread(void* bidders) noexcept nogil:
    """The thread of Bidders.settle_beside."""
    (<Bidders>bidders).serve()
    return NULL


def bid_on_own_boards(boards, const int64_t[::1] rows, const double[::1] slack, const double[::1] eps,
                      const uint8_t[:, ::1] taken) -> np.ndarray:
    """LocalAuction's bids: each robot of ``rows`` not content at its ``slack`` bids at its ``eps`` on
    its own board (goals ``taken`` by unknown robots cost more); returns the rows that bid."""
    cdef double[:, ::1] cost = boards.cost, price = boards.price
    cdef double[::1] taken_cost = boards.taken_cost
    cdef int64_t[:, ::1] owner = boards.owner
    cdef uint8_t[:, ::1] released = boards.released.view(np.uint8)
    cdef int64_t[::1] goal = boards.goal
    cdef const int64_t[::1] robot = boards.own_ids
    cdef Py_ssize_t g_count = cost.shape[1]
    values_array = np.empty(g_count)
    cdef double[::1] values = values_array
    out = np.empty(rows.shape[0], np.int64)
    cdef int64_t[::1] bid = out
    cdef Py_ssize_t a, j, n = 0
    cdef int64_t i, h
    cdef Ranking r
    cdef bint holds
    for a in range(rows.shape[0]):
        i = rows[a]
        r = unranked()
        for j in range(g_count):
            values[j] = -cost[i, j] - price[i, j] - taken[a, j] * taken_cost[i]
            rank_in(&r, j, values[j])
        h = goal[i]
        holds = h >= 0 and owner[i, h] == robot[i] and not released[i, h]
        if holds and is_content(values[h], r.best, slack[a]):
            continue
        if holds:
            released[i, h] = True  # it gives its goal up for a better one
        if g_count < 2:
            r.second = r.best - eps[a]
        price[i, r.first] = bid_price(price[i, r.first], r.best, r.second, eps[a])
        owner[i, r.first] = robot[i]
        released[i, r.first] = False
        goal[i] = r.first
        bid[n] = i
        n += 1
    return out[:n]


def hear_words(boards, const int64_t[::1] rows, words, int64_t r) -> tuple[np.ndarray, np.ndarray]:
    """LocalAuction.hear: each robot of ``rows`` hears the other robots' ``words`` within reach (block
    ended, latest phase, known robots, latest change). Returns per row whether its phase moved on or
    its known set grew, and which words told it a board (len(rows), M)."""
    cdef const double[:, ::1] xy = boards.xy
    cdef const int64_t[::1] robot = boards.own_ids
    cdef int64_t[::1] phase = boards.phase, last = boards.last, grew = boards.grew
    cdef uint8_t[::1] ended = boards.ended.view(np.uint8)
    cdef uint8_t[:, ::1] known = boards.known.view(np.uint8)
    cdef const double[:, ::1] w_xy = np.ascontiguousarray(words.xy, float)
    cdef const int64_t[::1] w_robot = np.ascontiguousarray(words.robot, np.int64)
    cdef const int64_t[::1] w_phase = np.ascontiguousarray(words.phase, np.int64)
    cdef const int64_t[::1] w_last = np.ascontiguousarray(words.last, np.int64)
    cdef const uint8_t[::1] w_ended = np.ascontiguousarray(words.ended, bool).view(np.uint8)
    cdef const uint8_t[::1] w_fresh = np.ascontiguousarray(words.fresh, bool).view(np.uint8)
    cdef const uint8_t[::1] w_grown = np.ascontiguousarray(words.grown, bool).view(np.uint8)
    cdef const uint8_t[:, ::1] w_known = np.ascontiguousarray(words.known, bool).view(np.uint8)
    cdef double reach2 = boards.reach * boards.reach, dx, dy
    out, told_array = np.zeros(rows.shape[0], bool), np.zeros((rows.shape[0], w_robot.shape[0]), np.uint8)
    cdef uint8_t[::1] changed = out.view(np.uint8)
    cdef uint8_t[:, ::1] told = told_array
    cdef Py_ssize_t a, b, n
    cdef int64_t i, later, latest
    cdef bint grown
    for a in range(rows.shape[0]):
        i = rows[a]
        later, latest, grown = -1, 0, False
        for b in range(w_robot.shape[0]):
            dx, dy = xy[i, 0] - w_xy[b, 0], xy[i, 1] - w_xy[b, 1]
            if not dx * dx + dy * dy <= reach2 or w_robot[b] == robot[i]:
                continue
            if w_ended[b]:
                ended[i] = True  # the final phase proved over
            later, latest = max(later, w_phase[b]), max(latest, w_last[b])
            if w_grown[b]:
                for n in range(known.shape[1]):
                    if w_known[b, n] and not known[i, n]:
                        known[i, n], grown = True, True
            told[a, b] = w_fresh[b]
        if later > phase[i]:  # a later phase: its sender proved ours over
            phase[i], changed[a] = later, True
        if grown:  # the goals it may take changed (LocalAuction._bid)
            grew[i], changed[a] = r, True
        last[i] = max(last[i], latest)
    return out, told_array


def merge_boards(boards, const int64_t[::1] rows, const uint8_t[:, ::1] told, words) -> np.ndarray:
    """LocalAuction's max-consensus: the boards in ``words`` each row was ``told`` merged into its own;
    returns where a row's board changed."""
    out = np.zeros(rows.shape[0], bool)
    cdef uint8_t[::1] changed = out.view(np.uint8)
    cdef double[:, ::1] price = boards.price
    cdef int64_t[:, ::1] owner = boards.owner
    cdef uint8_t[:, ::1] released = boards.released.view(np.uint8)
    cdef const double[:, ::1] w_price = np.ascontiguousarray(words.price, float)
    cdef const int64_t[:, ::1] w_owner = np.ascontiguousarray(words.owner, np.int64)
    cdef const uint8_t[:, ::1] w_released = np.ascontiguousarray(words.released, bool).view(np.uint8)
    cdef Py_ssize_t a, b, j
    cdef int64_t i
    for a in range(rows.shape[0]):
        i = rows[a]
        for b in range(told.shape[1]):
            if not told[a, b]:
                continue
            for j in range(price.shape[1]):
                if w_owner[b, j] != NOBODY and greater(w_price[b, j], w_owner[b, j], w_released[b, j], price[i, j],
                                                       owner[i, j], released[i, j]):
                    price[i, j], owner[i, j], released[i, j] = w_price[b, j], w_owner[b, j], w_released[b, j]
                    changed[a] = 1
    return out


def board_digest(const double[::1] price, const int64_t[::1] owner, const uint8_t[::1] released) -> int:
    """64 bits that tell boards apart: each word hashed with its place, XOR-folded (hashlib would load
    OpenSSL into every agent process)."""
    cdef uint64_t folded = 0, bits
    cdef Py_ssize_t j, g = price.shape[0]
    cdef double p
    with nogil:
        for j in range(g):  # places: the prices 0..G-1, then the owners, then the released flags
            p = price[j]
            memcpy(&bits, &p, sizeof(bits))  # the float's bits (a cast would break strict aliasing)
            folded ^= splitmix64(bits ^ splitmix64(j))
            folded ^= splitmix64(<uint64_t>owner[j] ^ splitmix64(g + j))
            folded ^= splitmix64(<uint64_t>released[j] ^ splitmix64(2 * g + j))
    return folded
