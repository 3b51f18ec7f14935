"""The distributed goal auction (paper 5.1.1) as seen by the robots of one agent host: pure logic,
no zenoh and no clock (the runtime passes messages in and takes records out).

The protocol is an asynchronous forward auction (Bertsekas and Castanon 1991) whose prices and owners
are agreed by max-consensus, as in Zavlanos et al. 2008:

- **Board.** Per goal, the greatest record anyone has seen, ordered by price, then the lower robot id,
  then "released" after "claimed". Records only ever merge by this maximum, so duplicated, reordered
  or lost messages can delay agreement but never give a goal two owners; no two records tie.
- **Bids.** A robot that holds no goal, or whose goal was taken by a greater record, bids on its best
  goal: the price rises by the difference between the best and second-best net value plus epsilon.
  Costs are private: squared distance (eq. 7) plus the robot's own deadlock penalties (5.5.5).
  Own robots bid together (Jacobi rounds, vectorised), so a host of hundreds of robots stays fast:
  each robot's best and second-best values are kept between rounds (prices only rise), and only
  the rows that may have changed are ranked anew over every goal. A host that owns every robot (the
  central engine, sim.central) settles each block of phases in-process (``settle_alone``), compiled
  (agent.core.jacobi), to the same board.
- **Instances.** An auction instance runs on positions frozen when it starts, so costs stay fixed
  while prices settle; a deadlock penalty declared meanwhile counts from the next instance (a cost
  that changed after a robot said it was content would break the quiescence argument below). Instance k is *agreed* when every robot of the goal set has published, for k,
  a content record (it holds its goal and no other is better by more than epsilon) on distinct goals,
  all written against the same board (equal digests). Such a snapshot is quiescent: every bid anyone
  made is on that board, so nobody can bid again in instance k. Every agent checks this for itself,
  and a record of instance k+1 from anyone proves k was agreed.
- **Warm start and epsilon scaling.** Instances follow one another, each starting from the prices
  and owners of the last (paper 5.1 re-assigns each iteration); a robot keeps its goal unless
  another is better by more than epsilon plus the hysteresis Delta C. Instances come in blocks, one
  per set of frozen positions, of decreasing epsilon (Bertsekas' epsilon scaling); only the block's
  final phase is agreed by a snapshot. Scaling pays off on warm starts too: once robots have moved,
  the last prices are far from equilibrium, and at epsilon_A alone they settle in a price war.

The agreed assignment costs at most N (epsilon + Delta C) more than the optimum for the frozen
positions and the robots' private costs (epsilon-complementary slackness against one common price
vector); each robot's record carries its total deadlock penalty, so the squared-distance cost can be
checked against the optimum plus the penalties in force.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from transport.codec import AuctionRecord, Bid

from .auction import NO_OWNER, ROUNDING, epsilon_schedule, is_content
from .neighbours import splitmix64

# the auction record's flags (transport.codec.AuctionRecord); SETTLED: content at the final phase's slack,
# so in every phase left
CONTENT, RELEASED, SETTLED = AuctionRecord.CONTENT, AuctionRecord.RELEASED, AuctionRecord.SETTLED
CANDIDATES = 16  # goals a robot ranks in settle_alone's rounds while no other can beat them (agent.core.jacobi)
SMALL = 8  # messages with up to this many records are merged record by record (numpy costs more there)

RECORD = Bid.RECORD  # one robot's word on one goal (goal -1: it holds none yet), as a Bid carries it


def bid_position(position: np.ndarray, goal: np.ndarray, velocity: np.ndarray, lead: float) -> np.ndarray:
    """Where a robot driving to its goal will be ``lead`` seconds on (the host's last delay from
    freezing positions to adopting their agreement): along the straight line to the goal, as far as
    its speed carries it, never past the goal (a blocked robot stays put). Bidding from there
    compensates the auction's latency: an assignment computed from where the robots were when its
    instance began, but adopted seconds later once they have moved on, sends them back, and robots
    then swap goals back and forth for good. For squared distances, robots that have all covered the same fraction of their straight
    way to optimally assigned goals keep that assignment optimal, so leading agrees with the
    assignment being carried out.

    The speed counts, not its component toward the goal: the next block of instances freezes its
    positions right after an agreement, when a robot that got another goal still moves as it did
    for its last one. Counting only the way toward the goal would bid such robots from where they
    were (or from their old goals), and the next agreement would send them back.

    A batch: rows of positions, goals and velocities (one call for a host's robots)."""
    position = np.asarray(position, float)
    to_goal = np.asarray(goal, float) - position
    if lead <= 0:
        return position.copy()
    d = np.hypot(to_goal[..., 0], to_goal[..., 1])
    speed = np.hypot(*np.moveaxis(np.asarray(velocity, float), -1, 0))
    reach = np.minimum(1.0, speed * lead / np.maximum(d, 1e-9))
    return position + to_goal * np.where(d <= 1e-9, 0.0, reach)[..., None]


def frames_close(before: np.ndarray, goals: np.ndarray, previous: np.ndarray) -> bool:
    """Whether consecutive keyframes differ little enough for the auction to start from the carried
    assignment (Participant.carry) at prices zero, when the warm start from the goal sets' matching
    (the WarmStart part of Goals) does not apply (the last auction never agreed, or the robots changed): corresponding goals on average at most one and a half
    typical goal spacings (the median distance from a goal to its nearest neighbour) apart: closer,
    the carried claims agree in fewer rounds than a cold start; further, in more
    (bench/results/carry.md)."""
    goals = np.asarray(goals, float)
    ok = previous >= 0
    if len(goals) < 2 or not ok.any():
        return False
    # Imported here: scipy.spatial slows every agent process's start-up, and only keyframes need it.
    from scipy.spatial import cKDTree

    disparity = float(np.hypot(*(goals[ok] - np.asarray(before, float)[previous[ok]]).T).mean())
    spacing = float(np.median(cKDTree(goals).query(goals, k=2)[0][:, 1]))
    return disparity <= 1.5 * spacing


def _hull_vertices(goals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of points whose support function bounds the goal set's (agent.core.jacobi carries
    candidate lists by it): its convex hull's vertices, or its bounding box's corners when the
    hull is degenerate (goals on a line, fewer than three)."""
    from scipy.spatial import ConvexHull, QhullError

    if len(goals) == 0:
        return np.zeros(0), np.zeros(0)
    try:
        corners = goals[ConvexHull(goals).vertices]
    except (QhullError, ValueError):
        lo, hi = goals.min(axis=0), goals.max(axis=0)
        corners = np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]]])
    return np.ascontiguousarray(corners[:, 0], float), np.ascontiguousarray(corners[:, 1], float)


def records(rows: list[tuple]) -> np.ndarray:
    """Records from (robot, goal, price, flags[, penalty, x, y]) tuples (tests, tools)."""
    full = [tuple(r) + (0.0, 0.0, 0.0)[len(r) - 4 :] for r in rows]
    return np.array(full, RECORD)


ROW_BLOCK = 64  # rows of a (K, G) array worked on at a time: a block stays in cache through its passes


def _squared_distances(position: np.ndarray, goals: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(K, G) |g_j - p_i|^2 (eq. 7), into ``out`` when it has that shape, in blocks of rows (large
    whole arrays do not fit the cache)."""
    k, g = len(position), len(goals)
    if out is None or out.shape != (k, g):
        out = np.empty((k, g))
    gx, gy = np.ascontiguousarray(goals[:, 0]), np.ascontiguousarray(goals[:, 1])
    dy = np.empty((min(ROW_BLOCK, k), g))
    for a in range(0, k, ROW_BLOCK):
        cost, p = out[a : a + ROW_BLOCK], position[a : a + ROW_BLOCK]
        d = dy[: len(cost)]
        np.subtract(gx, p[:, 0, None], out=cost)
        cost *= cost
        np.subtract(gy, p[:, 1, None], out=d)
        d *= d
        cost += d
    return out


class Board:
    """Per goal: the greatest (price, lower robot id, released) record seen."""

    def __init__(self, goals: int) -> None:
        self.price = np.zeros(goals)
        self.owner = np.full(goals, NO_OWNER, dtype=np.int64)
        self.released = np.zeros(goals, bool)
        self.version = 0  # counts changes: cached digests and views key on it
        self._digest: tuple[int, int] | None = None

    def merge(self, goal: np.ndarray, price: np.ndarray, robot: np.ndarray, released: np.ndarray) -> bool:
        """Max-consensus of a batch of records into the board; True when any was new information."""
        goal = np.asarray(goal, np.int64)
        ok = (goal >= 0) & (goal < len(self.price))
        if not ok.any():
            return False
        goal, price = goal[ok], np.asarray(price, float)[ok]
        robot, released = np.asarray(robot, np.int64)[ok], np.asarray(released, bool)[ok]
        # the greatest record per goal in the batch: sorted by (goal, price, -robot, released), last wins
        order = np.lexsort((released, -robot, price, goal))
        g = goal[order]
        last = order[np.append(g[1:] != g[:-1], True)]
        g, p, r, rel = goal[last], price[last], robot[last], released[last]
        bp, bo, br = self.price[g], self.owner[g], self.released[g]
        greater = (bo == NO_OWNER) | (p > bp) | ((p == bp) & ((r < bo) | ((r == bo) & rel & ~br)))
        if not greater.any():
            return False
        g = g[greater]
        self.price[g], self.owner[g], self.released[g] = p[greater], r[greater], rel[greater]
        self.version += 1
        return True

    def merge_one(self, goal: int, price: float, robot: int, released: bool) -> bool:
        """The same for one record (a robot per host: most messages carry one or two records)."""
        if not 0 <= goal < len(self.price):
            return False
        owner = int(self.owner[goal])
        if owner != NO_OWNER and (price, -robot, released) <= (self.price[goal], -owner, bool(self.released[goal])):
            return False
        self.price[goal], self.owner[goal], self.released[goal] = price, robot, released
        self.version += 1
        return True

    def holds(self, robot: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Per (robot, goal) pair: the robot owns the goal on this board and has not released it."""
        goal = np.asarray(goal, np.int64)
        safe = np.minimum(np.maximum(goal, 0), max(len(self.price) - 1, 0))  # np.clip costs 10x more here
        return (goal >= 0) & (self.owner[safe] == robot) & ~self.released[safe]

    def digest(self) -> int:
        """64 bits that tell boards apart: each word of (price, owner, released) hashed with its
        place, XOR-folded (numpy only: hashlib would load OpenSSL into every agent process)."""
        if self._digest is None or self._digest[0] != self.version:
            words = np.concatenate([self.price.view(np.uint64), self.owner.view(np.uint64), self.released])
            place = splitmix64(np.arange(len(words), dtype=np.uint64))
            folded = np.bitwise_xor.reduce(splitmix64(words.astype(np.uint64) ^ place), initial=np.uint64(0))
            self._digest = (self.version, int(folded))
        return self._digest[1]


class Participant:
    """The own robots of one host in the auction of one goal set (epoch)."""

    def __init__(
        self, epoch: int, goals: np.ndarray, robots: list[int], own: list[int], eps: float, hysteresis: float = 0.0
    ) -> None:
        self.epoch = epoch
        self.goals = np.asarray(goals, float)
        self.robots = np.array(sorted(int(r) for r in robots), np.int64)
        self.row_of = {int(r): i for i, r in enumerate(self.robots)}
        members = set(self.robots.tolist())
        self.own = sorted(int(r) for r in own if r in members)
        self.own_ids = np.array(self.own, np.int64)
        self.own_rows = np.searchsorted(self.robots, self.own_ids)  # own robots' rows among all robots
        self.is_own = np.zeros(len(self.robots), bool)
        self.is_own[self.own_rows] = True
        self.is_own_id = np.zeros(int(self.robots.max(initial=0)) + 2, bool)  # by robot id + 1 (owner -1: none)
        self.is_own_id[self.own_ids + 1] = True
        self.schedule = epsilon_schedule(self.goals, eps, factor=10.0)  # fewer phases: each costs a global snapshot
        self.hysteresis = hysteresis
        self.board = Board(len(self.goals))
        self.instance = -1  # not started: waits for the robots' positions
        k, g = len(self.own), len(self.goals)
        self.position = np.zeros((k, 2))  # frozen per instance
        self.cost = np.zeros((k, g))  # c_ij at the frozen positions, eq. 7, plus the penalties in force
        self.penalty = np.zeros((k, g))  # C_d per robot and goal in force this instance (deadlocks)
        self.pending = np.zeros((k, g))  # penalties declared during this instance: in force from the next
        self.goal = np.full(k, -1, np.int64)  # what each own robot claims
        # the newest record of every other robot in the current instance, and the board it was written on
        r = len(self.robots)
        self.heard_instance = np.full(r, -1, np.int64)
        self.heard_serial = np.zeros(r, np.int64)
        self.heard_goal = np.full(r, -1, np.int64)
        self.heard_price = np.zeros(r)
        self.heard_content = np.zeros(r, bool)
        self.heard_digest = np.zeros(r, np.uint64)
        self.heard_version = 0
        self.agreed_instance = -1
        self._agreed: tuple[np.ndarray, dict[int, int] | None] = (np.zeros(0, np.int64), {})  # see agreed
        self.agreed_owner: np.ndarray | None = None  # per goal: its robot in the agreed instance (NO_OWNER: none)
        self.claims_changed = False  # own claims changed since the last publication
        self.published_digest: int | None = None  # the board digest of the last publication
        self.bids = 0
        self.rounds = 0  # Jacobi rounds in which some own robot bid
        self._content_cache: tuple[tuple, np.ndarray] | None = None
        # per own robot: its best goal, that goal's value and its second-best value (see _best_values)
        self._best: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._lists: tuple | None = None  # settle_alone's candidate goals, scratch (agent.core.jacobi), hull, ...
        self.without_list = 0  # robots that had no candidate list at the start of settle_alone's last block
        self._price_seen = np.zeros(len(self.goals))
        self._has_penalty = False  # any penalty in force: costs are more than squared distances
        self._pending_any = False  # penalise() was called since the last begin()
        self._view_cache: dict[bool, tuple[tuple, bool]] = {}

    # --- the epsilon of an instance ----------------------------------------------------------------
    @property
    def phase(self) -> int:
        """Which epsilon-scaling phase the current instance is (instances come in blocks of phases)."""
        return max(self.instance, 0) % self.phases

    @property
    def final_phase(self) -> bool:
        return self.phase == self.phases - 1

    @property
    def eps(self) -> float:
        return self.schedule[self.phase]

    @property
    def slack(self) -> float:
        """How much better another goal must be before a robot bids: the phase's epsilon, and never
        less than the final phase's epsilon_A + Delta C (paper 5.1's hysteresis). A phase tighter
        than the final one would move robots for gains that Delta C is there to ignore."""
        return max(self.eps, self.schedule[-1] + self.hysteresis)

    @property
    def started(self) -> bool:
        return self.instance >= 0

    @property
    def is_agreed(self) -> bool:
        return self.started and self.agreed_instance == self.instance

    # --- instances --------------------------------------------------------------------------------
    @property
    def phases(self) -> int:
        """Instances come in blocks of this many epsilon-scaling phases, on one set of positions."""
        return len(self.schedule)

    def begin(self, instance: int, positions: Mapping[int, np.ndarray] | np.ndarray) -> None:
        """Start an instance, warm from the current board. The first instance of a block of phases
        freezes the positions given (a mapping robot -> (x, y), or an array whose row r is robot r's
        position); the block's other phases share them. Penalties declared during the last instance
        come into force now."""
        self._freeze(instance, positions)
        self.bid()

    def _freeze(self, instance: int, positions: Mapping[int, np.ndarray] | np.ndarray, costs: bool = True) -> None:
        """begin() up to its first round; without ``costs`` the caller computes them (settle_alone)."""
        if self.started and not self.is_agreed and instance > self.instance:
            self.adopt_if_settled()  # someone reached a later instance: ours was agreed
        new_block = not self.started or instance // self.phases != self.instance // self.phases
        if new_block and self.own:
            if isinstance(positions, np.ndarray):
                self.position = np.asarray(positions, float)[self.own_ids].reshape(-1, 2)
            else:
                self.position = np.array([positions[r] for r in self.own], float).reshape(-1, 2)
        penalised = self._pending_any and bool(self.pending.any())  # a flag first: any() reads K x G
        if penalised:
            self.penalty += self.pending
            self.pending[:] = 0.0
            self._pending_any = False
            self._has_penalty = True
        # The costs change only with the positions (a new block) or a penalty: the other phases of a
        # block keep them, and the best values too (prices only rise, _best_values follows them).
        if (new_block or penalised) and costs:
            self.cost = _squared_distances(
                self.position, self.goals, out=self.cost
            )  # the last block's costs are done with
            if self._has_penalty:
                self.cost += self.penalty
            self._best = None  # costs changed: every best value is recomputed
        self.instance = instance
        self.claims_changed = True  # the new instance's records are news
        self._content_cache = None

    def carry(
        self,
        before: Participant,
        previous: np.ndarray,
        claim: bool = True,
        current: Mapping[int, int] | None = None,
        prices: np.ndarray | None = None,
    ) -> dict[int, int]:
        """The assignment of the previous keyframe carried over by the goals' correspondence (paper
        6.1; ``previous[j]``: the goal of ``before`` that goal j continues, -1 none): a robot driving to
        goal i there gets i's successor. ``current``: each own robot's goal in ``before`` (the one it
        drives to: agreed, or itself carried when that auction never agreed); by default its goal in
        ``before``'s last agreed instance, or its claim on the board when none was agreed. Returns
        the own robots' carried goals (robot -> goal), which they drive to until this auction agrees.

        With ``claim`` the auction also starts from it: each robot claims its carried goal at price
        zero where ``before``'s last agreed board says it owns the goal it continues. Every host
        adopted that board alike; the live one may be in the middle of the next instance (paper 5.1
        re-assigns every iteration), and claims from it agree later. When the frames differ little most robots are then content at once, and agreement
        takes a few message rounds instead of a cold start's many; when they differ much, the claims
        skip the coarse epsilon phases that build the prices, and the fine ones fight a price war that costs more than a cold
        start (bench/bench_carry.py; see frames_close). Carrying the prices too costs more in both
        cases: they are in equilibrium for the old costs only. ``prices`` (with ``claim``): prices in
        equilibrium for the new goals (Goals.warm_start.prices) to start from instead of zero. Call before the
        first instance."""
        previous = np.asarray(previous, np.int64)
        if self.started or not before.started or len(previous) != len(self.goals):
            return {}
        j = np.flatnonzero((previous >= 0) & (previous < len(before.goals)))
        successor = np.full(len(before.goals), -1, np.int64)
        successor[previous[j]] = j
        if current is None:
            current = before.agreed or {r: int(g) for r, g in zip(before.own, before.goal.tolist())}
        carried = {
            r: int(successor[g])
            for r, g in current.items()
            if r in self.own and 0 <= g < len(successor) and successor[g] >= 0
        }
        if claim:
            i = previous[j]
            last = before.agreed_owner  # every host adopted the same board; the live one may be mid-instance
            if last is None:
                last = np.where(before.board.released, NO_OWNER, before.board.owner)
            held = np.isin(last[i], self.robots)
            owner = np.full(len(self.goals), NO_OWNER, np.int64)
            owner[j[held]] = last[i[held]]
            self.board.owner[:] = owner
            if prices is not None:
                self.board.price[:] = prices
            self.board.version += 1
            for k, r in enumerate(self.own):
                g = carried.get(r, -1)
                self.goal[k] = g if g >= 0 and owner[g] == r else -1
        return carried

    def adopt_if_settled(self) -> None:
        """Adopt the current instance if every robot is content on one board (someone reached a later one)."""
        if self.final_phase and self._content_all().all():
            self._adopt()

    # --- bidding ----------------------------------------------------------------------------------
    def _values(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Net values -c_ij - b_j of own robots (their private costs include deadlock penalties)."""
        values = -self.cost[rows]
        values -= self.board.price[None, :]  # in place: one (rows, G) array, not three
        return values

    def _best_values(self) -> np.ndarray:
        """(K,) each own robot's best net value max_j (-c_ij - b_j), kept up to date cheaply. Prices
        only rise, so values only fall: a robot's best goal can change only when its price rose, and
        it stays the best (the same argmax) while its value now still beats the robot's second-best
        value as last ranked, which bounds the second best now from above. Only the other rows are
        ranked anew over every goal."""
        price = self.board.price
        if self._best is None:
            k = len(self.own)
            self._best = (np.zeros(k, np.int64), np.zeros(k), np.full(k, np.inf))
            self._rank(np.arange(k))
        else:
            rose = price != self._price_seen
            best, value, second = self._best
            stale = np.flatnonzero(rose[best]) if rose.any() else ()
            if len(stale):
                g = best[stale]
                now = -self.cost[stale, g] - price[g]
                value[stale] = now
                lost = stale[~(now > second[stale])]  # another goal may be as good now
                if len(lost):
                    self._rank(lost)
        self._price_seen = price.copy()
        return self._best[1]

    def _rank(self, rows: np.ndarray, third: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Rank these own robots' net values over every goal: their best goal and value, and their
        second-best value, into the cache. Returns the runner-up goal and, with ``third``, the
        third-best value (-inf where there is none). In blocks of rows that stay in cache."""
        if len(rows) == 1 and not third:
            return self._rank_one(int(rows[0]))
        if len(rows) <= ROW_BLOCK:
            return self._rank_block(rows, third)
        runner_up, third_value = np.zeros(len(rows), np.int64), np.full(len(rows), -np.inf)
        for a in range(0, len(rows), ROW_BLOCK):
            block = slice(a, a + ROW_BLOCK)
            runner_up[block], third_value[block] = self._rank_block(rows[block], third)
        return runner_up, third_value

    def _ranking(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cache _rank fills (made by _best_values or settle_alone before any ranking)."""
        if self._best is None:
            raise RuntimeError("no ranking cache yet")
        return self._best

    def _rank_one(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """_rank_block for one row without the third-best value, in scalars (the common case)."""
        best, value, second = self._ranking()
        values = -self.cost[i]
        values -= self.board.price
        first = int(values.argmax())  # ties: lowest goal index, the same everywhere
        best[i], value[i] = first, values[first]
        runner_up = first
        if len(values) > 1:
            values[first] = -np.inf
            runner_up = int(values.argmax())
            second[i] = values[runner_up]
        else:
            second[i] = -np.inf
        return np.array([runner_up]), np.array([-np.inf])

    def _rank_block(self, rows: np.ndarray, third: bool) -> tuple[np.ndarray, np.ndarray]:
        best, value, second = self._ranking()
        values = self._values(rows)
        at = np.arange(len(rows))
        first = np.argmax(values, axis=1)  # ties: lowest goal index, the same everywhere
        best[rows], value[rows] = first, values[at, first]
        runner_up, third_value = first, np.full(len(rows), -np.inf)
        if values.shape[1] > 1:
            values[at, first] = -np.inf
            runner_up = np.argmax(values, axis=1)
            second[rows] = values[at, runner_up]
            if third and values.shape[1] > 2:
                values[at, runner_up] = -np.inf
                third_value = values.max(axis=1)
        else:
            second[rows] = -np.inf
        return runner_up, third_value

    def _after_bids(self, bidders: np.ndarray, bid_on: np.ndarray, runner_up: np.ndarray, third: np.ndarray) -> None:
        """The bidders' best goals once their bids are merged, from the ranking they bid on: the goal
        bid on rose in price, so the runner-up is the best now if it beats that goal's value now and
        the third-best value (an upper bound) outright; otherwise the row is ranked anew when next
        needed (second = inf, and the goal bid on counts as risen since _price_seen)."""
        best, value, second = self._ranking()
        price = self.board.price
        v_bid = -self.cost[bidders, bid_on] - price[bid_on]
        v_run = -self.cost[bidders, runner_up] - price[runner_up]
        bound = np.maximum(v_bid, third)
        moved = (v_run > bound) & (runner_up != bid_on)
        best[bidders] = np.where(moved, runner_up, bid_on)
        value[bidders] = np.where(moved, v_run, v_bid)
        second[bidders] = np.where(moved, bound, np.inf)

    def _content_all(self) -> np.ndarray:
        """(K,) bool: each own robot holds its goal and no goal is better by more than the slack."""
        key = (self.board.version, self.instance, self.goal.tobytes())
        if self._content_cache is not None and self._content_cache[0] == key:
            return self._content_cache[1]
        if not self.own or not len(self.goals):
            content = np.zeros(len(self.own), bool)
        else:
            holds = self.board.holds(self.own_ids, self.goal)
            g = np.maximum(self.goal, 0)
            held = -self.cost[np.arange(len(self.own)), g] - self.board.price[g]
            content = holds & is_content(held, self._best_values(), self.slack)
        self._content_cache = (key, content)
        return content

    def bid(self) -> bool:
        """One Jacobi round: every own robot that is not content bids on its best goal at once; per goal
        the greatest bid wins, by the same max-consensus as messages. True if any robot bid."""
        if not self.started:
            return False
        bidders = np.flatnonzero(~self._content_all())
        if len(bidders) == 0:
            return False
        self._bid_rows(bidders)
        return True

    def _bid_rows(self, bidders: np.ndarray) -> np.ndarray:
        """These own robots (rows, none of them content) bid on their best goals at once; returns the
        robots that lost to these bids a goal they owned."""
        runner_up, third = self._rank(bidders, third=True)  # the same best as _content_all's
        best, value, second = self._ranking()
        best, v_best = best[bidders], value[bidders]
        if len(self.goals) > 1:
            second = second[bidders]
        else:
            second = v_best - self.eps
        price = self.board.price[best] + (v_best - second) + self.eps
        robot = self.own_ids[bidders]
        held = self.goal[bidders]
        gives_up = self.board.holds(robot, held)  # it gives its goal up for a better one
        g_rel = held[gives_up]
        owner = self.board.owner[best]  # a copy: who owned the goals bid on
        # releases and bids merge in one batch: max-consensus does not care about order
        # (np.concatenate: np.r_ costs several times more on these short arrays, every round)
        self.board.merge(
            np.concatenate([g_rel, best]),
            np.concatenate([self.board.price[g_rel], price]),
            np.concatenate([robot[gives_up], robot]),
            np.concatenate([np.ones(len(g_rel), bool), np.zeros(len(best), bool)]),
        )
        self._after_bids(bidders, best, runner_up, third)
        self.goal[bidders] = best
        self.bids += len(bidders)
        self.rounds += 1
        self.claims_changed = True
        return owner[(owner != self.board.owner[best]) & (owner != NO_OWNER)]

    def bid_until_quiet(self, max_rounds: int = 100_000) -> int:
        """Rounds until no own robot wants to bid (own robots outbid each other without messages)."""
        rounds = 0
        while rounds < max_rounds and self.bid():
            rounds += 1
        return rounds

    def settle_alone(
        self, positions: Mapping[int, np.ndarray] | np.ndarray, max_rounds: int = 100_000, candidates: int = CANDIDATES
    ) -> np.ndarray:
        """For a host that owns every robot of the goal set (the central engine): begin the next
        block of phases on these positions, warm from the board, and bid it through its phases to
        an agreed final phase. Nobody else bids, so no message is needed: every phase's snapshot is
        this host's own board, and a phase is over when every robot is content. Returns each own
        robot's agreed goal, in the order of ``own``.

        The block runs compiled (agent.core.jacobi): the same costs, rounds, bids and board as
        begin(), bid() and check_agreement() give, far faster (while they cross the arena a warm
        block runs chains of thousands of rounds of one or two bidders).
        Each robot ranks only its ``candidates`` best goals while no other goal can beat them
        (prices only rise), and the lists carry over to the next block where the robot's motion
        cannot have changed that: the same ranking, a fraction of the scan.
        The compiled rounds compute costs where needed and leave ``cost`` as it was: a participant
        that settles alone is settled alone, not also with bid().
        Imported here, not at the top: agent hosts never settle alone and need not load numba."""
        from .jacobi import first_ranking, new_lists, settle_block

        if len(self.own) != len(self.robots):
            raise ValueError("settle_alone needs a host that owns every robot of the goal set")
        if candidates < 3:
            raise ValueError("settle_alone ranks at least 3 candidate goals per robot")
        first = (self.instance // self.phases + 1) * self.phases if self.started else 0
        self._freeze(first, positions, costs=False)  # costs are computed where needed
        k, board = len(self.own), self.board
        if self._best is None:
            self._best = (np.zeros(k, np.int64), np.zeros(k), np.full(k, np.inf))
        best, value, second = self._best
        if self._lists is None or self._lists[0].cand.shape[1] != candidates:
            row_of_id = np.full(int(self.own_ids.max(initial=0)) + 1, -1, np.int64)
            row_of_id[self.own_ids] = np.arange(k)
            eps = np.array(self.schedule)
            slack = np.maximum(eps, eps[-1] + self.hysteresis)  # as self.slack, phase by phase
            gx, gy = np.ascontiguousarray(self.goals[:, 0]), np.ascontiguousarray(self.goals[:, 1])
            self._lists = (
                *new_lists(k, len(self.goals), candidates),
                _hull_vertices(self.goals),
                (gx, gy),
                row_of_id,
                eps,
                slack,
            )
        lists, work, scratch, (hull_x, hull_y), (gx, gy), row_of_id, eps, slack = self._lists
        px, py = np.ascontiguousarray(self.position[:, 0]), np.ascontiguousarray(self.position[:, 1])
        self.without_list = first_ranking(
            px,
            py,
            gx,
            gy,
            board.price,
            self.penalty,
            self._has_penalty,
            best,
            value,
            second,
            lists,
            work,
            hull_x,
            hull_y,
        )
        rounds, bids, settled = settle_block(
            px,
            py,
            gx,
            gy,
            board.price,
            self.penalty,
            self._has_penalty,
            board.owner,
            board.released,
            self.goal,
            self.own_ids,
            row_of_id,
            best,
            value,
            second,
            lists,
            work,
            scratch,
            eps,
            slack,
            ROUNDING,
            max_rounds,
        )
        self.instance = first + min(settled, self.phases - 1)
        board.version += 1
        self.bids, self.rounds, self.claims_changed = self.bids + bids, self.rounds + rounds, True
        self._price_seen = board.price.copy()  # every cached best value is exact now
        if settled < self.phases:
            raise RuntimeError(f"auction instance {self.instance} did not settle")
        self._content_cache = ((board.version, self.instance, self.goal.tobytes()), np.ones(k, bool))
        self._adopt()
        return self.goal.copy()

    # --- lock-step rounds ----------------------------------------------------------------------------
    def begin_block(self, positions: Mapping[int, np.ndarray] | np.ndarray) -> None:
        """Lock-step: begin the next block of phases on these positions, warm from the board, as
        settle_alone does, but bid nothing yet: every host bids in round 1 against the same board."""
        first = (self.instance // self.phases + 1) * self.phases if self.started else 0
        self._freeze(first, positions)

    def round_records(self) -> np.ndarray:
        """Lock-step: one round's records, after the own robots' bids: records(), each claim flagged
        SETTLED when its robot is content at the final phase's slack (the least: no later phase
        would have it bid)."""
        recs = self.records()
        if len(self.own) and len(self.goals):
            holds = self.board.holds(self.own_ids, self.goal)
            g = np.maximum(self.goal, 0)
            held = -self.cost[np.arange(len(self.own)), g] - self.board.price[g]
            settled = holds & is_content(held, self._best_values(), self.schedule[-1] + self.hysteresis)
            recs["flags"][: len(self.own)] |= np.where(settled, SETTLED, 0).astype(np.uint8)
        return recs

    def close_round(self, unchanged: bool, settled: bool) -> bool:
        """Lock-step: every host's records of a round are merged. A round that changed nothing on the
        board (nobody bid) ends its phase: the next phase begins or, in the final phase or when every
        robot said it is ``settled`` (then the phases left would pass without a bid, as
        settle_alone passes them), the block is agreed (True). Every host merged the same records
        onto the same board, so all of them decide alike, at the same round."""
        if not unchanged:
            return False
        if not (self.final_phase or settled):
            self._freeze(self.instance + 1, {})
            return False
        self.instance = (self.instance // self.phases + 1) * self.phases - 1  # the block's final phase
        self._content_cache = None
        self._adopt()
        return True

    def penalise(self, robot: int, goal: int, cost: float) -> None:
        """Deadlock (5.5.5): the robot's cost of this goal rises by C_d for good, from the next instance."""
        if robot in self.own and 0 <= goal < len(self.goals):
            self.pending[self.own.index(robot), goal] += cost
            self._pending_any = True

    # --- messages ---------------------------------------------------------------------------------
    @property
    def has_news(self) -> bool:
        """Own claims changed, or the board did since the last publication (others need our digest)."""
        return self.started and (self.claims_changed or self.board.digest() != self.published_digest)

    def outgoing(self) -> tuple[int, np.ndarray]:
        """The digest and records to publish now (marks them published)."""
        self.claims_changed = False
        self.published_digest = self.board.digest()
        return self.published_digest, self.records()

    def records(self) -> np.ndarray:
        """What the own robots say now: a claim each, and the goals they released that still carry
        their release on the board (so that others learn the price even if a message was lost)."""
        holds = self.board.holds(self.own_ids, self.goal)
        claims = np.zeros(len(self.own), RECORD)
        claims["robot"] = self.own_ids
        claims["goal"] = np.where(holds, self.goal, -1)
        claims["price"] = np.where(holds, self.board.price[np.maximum(self.goal, 0)], 0.0)
        claims["flags"] = np.where(self._content_all(), CONTENT, 0)
        claims["penalty"] = self.penalty.sum(axis=1)
        claims["x"], claims["y"] = self.position[:, 0], self.position[:, 1]
        rel = np.flatnonzero(self.board.released & self.is_own_id[self.board.owner + 1])
        releases = np.zeros(len(rel), RECORD)
        releases["robot"], releases["goal"] = self.board.owner[rel], rel
        releases["price"], releases["flags"] = self.board.price[rel], RELEASED
        return np.concatenate([claims, releases])

    def absorb(self, instance: int, serial: int, digest: int, recs: np.ndarray) -> bool:
        """Merge another host's records; True when the board changed. Records of the current instance
        are remembered per robot (the newest by serial) for the agreement check."""
        recs = np.asarray(recs, RECORD)
        if len(recs) <= SMALL:
            return self._absorb_each(instance, serial, digest, recs.tolist())
        robot = recs["robot"].astype(np.int64)
        released = (recs["flags"] & RELEASED) != 0
        changed = self.board.merge(recs["goal"], recs["price"], robot, released)
        if instance != self.instance or len(self.robots) == 0:
            return changed
        row = np.searchsorted(self.robots, robot)
        known = (row < len(self.robots)) & (self.robots[np.minimum(row, len(self.robots) - 1)] == robot)
        row = np.minimum(row, len(self.robots) - 1)
        newer = (self.heard_instance[row] < instance) | (serial > self.heard_serial[row])
        take = known & ~released & ~self.is_own[row] & newer
        if take.any():
            r, rec = row[take], recs[take]
            self.heard_instance[r], self.heard_serial[r] = instance, serial
            self.heard_goal[r], self.heard_price[r] = rec["goal"], rec["price"]
            self.heard_content[r] = (rec["flags"] & CONTENT) != 0
            self.heard_digest[r] = np.uint64(digest)
            self.heard_version += 1
        return changed

    def _absorb_each(self, instance: int, serial: int, digest: int, recs: list[tuple]) -> bool:
        """absorb() record by record: cheaper than array operations for a few records."""
        changed = False
        for robot, goal, price, flags, _, _, _ in recs:
            released = bool(flags & RELEASED)
            changed |= self.board.merge_one(goal, price, robot, released)
            row = self.row_of.get(robot)
            if instance != self.instance or released or row is None or self.is_own[row]:
                continue
            if self.heard_instance[row] < instance or serial > self.heard_serial[row]:
                self.heard_instance[row], self.heard_serial[row] = instance, serial
                self.heard_goal[row], self.heard_price[row] = goal, price
                self.heard_content[row] = bool(flags & CONTENT)
                self.heard_digest[row] = digest
                self.heard_version += 1
        return changed

    def _settled_view(self, same_board: bool) -> bool:
        """Every robot content on a distinct goal, as far as this host knows: own robots now, the
        others by their newest records of this instance, which still hold on our board (and, with
        ``same_board``, were written against a board with our digest)."""
        if not self.started:
            return False
        key = (self.board.version, self.heard_version, self.instance, self.goal.tobytes())
        cached = self._view_cache.get(same_board)
        if cached is not None and cached[0] == key:
            return cached[1]
        self._view_cache[same_board] = (key, settled := self._compute_settled(same_board))
        return settled

    def _compute_settled(self, same_board: bool) -> bool:
        if not self._content_all().all():
            return False
        others = ~self.is_own
        ok = (self.heard_instance[others] == self.instance) & self.heard_content[others]
        if same_board:
            ok &= self.heard_digest[others] == np.uint64(self.board.digest())
        if not ok.all():
            return False
        goal, price, robot = self.heard_goal[others], self.heard_price[others], self.robots[others]
        if not (self.board.holds(robot, goal).all() and (self.board.price[goal] == price).all()):
            return False
        taken = np.concatenate([self.goal, goal])
        return len(set(taken.tolist())) == len(taken)

    def view_complete(self) -> bool:
        """Nobody is bidding as far as we know: the moment to tell others our board's digest (earlier,
        while bids fly, digests would be stale at once)."""
        return self._settled_view(same_board=False)

    def check_agreement(self) -> bool:
        """True (once per instance) when this host sees instance k agreed; sets ``agreed``.

        A phase before the final one moves on to the next, smaller epsilon as soon as this host sees
        nobody bidding (no common snapshot: the phases only speed the auction up, the guarantee comes
        from the final phase's snapshot), and others follow when they hear of the later instance."""
        if self.started and not self.final_phase:
            if self._settled_view(same_board=False):
                self.begin(self.instance + 1, {})
            return False
        if self.is_agreed or not self._settled_view(same_board=True):
            return False
        self._adopt()
        return True

    @property
    def agreed(self) -> dict[int, int]:
        """Own robot -> its goal in the agreed instance (made when first asked for: the central
        engine settles every control step and never asks)."""
        goal, made = self._agreed
        if made is None:
            made = dict(zip(self.own, goal.tolist()))
            self._agreed = (goal, made)
        return made

    def _adopt(self) -> None:
        """The current instance is agreed: note the own robots' goals and every goal's owner in it."""
        self.agreed_instance = self.instance
        self._agreed = (self.goal.copy(), None)
        self.agreed_owner = np.where(self.board.released, NO_OWNER, self.board.owner)
