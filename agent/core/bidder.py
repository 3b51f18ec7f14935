"""The distributed goal auction (paper 5.1.1) as seen by the robots of one agent host: pure logic, no zenoh, no clock.

As docs/architecture.md ("Goal assignment") says; the Jacobi rounds are compiled (agent.core.bidding): an agent
host bids a round at a time between messages (``bid``), the central engine settles a block alone (``settle_alone``).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Mapping

import numpy as np

from transport.codec import AuctionRecord, Bid

from .bidding import NO_OWNER, Bidders, Heard, board_digest

# the auction record's flags (transport.codec.AuctionRecord); SETTLED: content at the final phase's slack
CONTENT, RELEASED, SETTLED = AuctionRecord.CONTENT, AuctionRecord.RELEASED, AuctionRecord.SETTLED
CANDIDATES = 16  # goals a robot ranks while no other can beat them (agent.core.bidding)
ROUNDS_PER_ROBOT = 100  # settle_alone's bound on a phase's rounds, per robot, and at least 100,000
SMALL = 8  # members_only looks up the records of messages up to this size one by one (numpy costs more there)

RECORD = Bid.RECORD  # one robot's word on one goal (goal -1: it holds none yet), as a Bid carries it


def epsilon_schedule(goals: np.ndarray, eps_final: float) -> list[float]:
    """Decreasing epsilons (epsilon scaling, which warm starts need too against price wars): from a tenth
    of the goal set's squared extent down to eps_final, by 10 (few phases: each costs a snapshot)."""
    extent = float(np.max(np.ptp(goals, axis=0))) if len(goals) > 1 else 0.0
    eps = max(eps_final, extent * extent / 10.0)
    out = []
    while eps > eps_final * 1.0001:
        out.append(eps)
        eps /= 10.0
    out.append(eps_final)
    return out


def _hull_vertices(goals: np.ndarray, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of points whose support function bounds the goal set's: its hull's vertices, or its box's
    corners if the hull is degenerate or not ``exact`` (an agent process need not load scipy.spatial)."""
    if len(goals) == 0:
        return np.zeros(0), np.zeros(0)
    lo, hi = goals.min(axis=0), goals.max(axis=0)
    corners = np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]]])
    if exact:
        from scipy.spatial import ConvexHull, QhullError

        try:
            corners = goals[ConvexHull(goals).vertices]
        except (QhullError, ValueError):
            pass
    return np.ascontiguousarray(corners[:, 0], float), np.ascontiguousarray(corners[:, 1], float)


def frozen_positions(positions: Mapping[int, np.ndarray] | np.ndarray, own: list[int] | np.ndarray) -> np.ndarray:
    """The ``own`` robots' positions (K, 2) from a mapping robot -> (x, y) or rows by robot id."""
    if isinstance(positions, np.ndarray) and len(own) == len(positions):  # own: sorted, distinct: every row
        return np.array(positions, float).reshape(-1, 2)
    if isinstance(positions, np.ndarray):
        return np.asarray(positions, float)[np.asarray(own, np.int64)].reshape(-1, 2)
    return np.array([positions[r] for r in own], float).reshape(-1, 2)


class Board:
    """Per goal: the greatest (price, lower robot id, released) record seen."""

    def __init__(self, goals: int) -> None:
        self.price = np.zeros(goals)
        self.owner = np.full(goals, NO_OWNER, dtype=np.int64)
        self.released = np.zeros(goals, bool)
        self.version = 0  # counts changes: cached digests and views key on it
        self._digest: tuple[int, int] | None = None

    def holds(self, robot: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Per (robot, goal) pair: the robot owns the goal on this board and has not released it."""
        goal = np.asarray(goal, np.int64)
        safe = np.minimum(np.maximum(goal, 0), max(len(self.price) - 1, 0))  # np.clip costs more here
        return (goal >= 0) & (self.owner[safe] == robot) & ~self.released[safe]

    def digest(self) -> int:
        """64 bits that tell boards apart (agent.core.bidding.board_digest), cached per version."""
        if self._digest is None or self._digest[0] != self.version:
            self._digest = (self.version, board_digest(self.price, self.owner, self.released.view(np.uint8)))
        return self._digest[1]


class Auction:
    """What the auctions of one goal set (epoch) share: goals, robots, this host's own robots, the
    epsilon schedule (Participant: one board for all; LocalAuction: a board per robot)."""

    pending: defaultdict[tuple[int, int], float] | np.ndarray  # C_d per (own row, goal) declared, not in force yet

    def __init__(
        self, epoch: int, goals: np.ndarray, robots: list[int], own: list[int], eps: float, hysteresis: float
    ) -> None:
        self.epoch = epoch
        self.goals = np.asarray(goals, float)
        self.robots = np.array(sorted(int(r) for r in robots), np.int64)
        members = set(self.robots.tolist())
        self.own = sorted({int(r) for r in own} & members)
        self.own_ids = np.array(self.own, np.int64)
        self.own_rows = np.searchsorted(self.robots, self.own_ids)  # own robots' rows among all robots
        self.schedule = epsilon_schedule(self.goals, eps)
        # per phase, how much better another goal must be before a robot bids: >= epsilon_A + Delta C (5.1)
        self.slacks = np.maximum(self.schedule, self.schedule[-1] + hysteresis)
        self.agreed_instance = -1
        self.bids = 0

    @property
    def phases(self) -> int:
        """Instances come in blocks of this many epsilon-scaling phases, on one set of positions."""
        return len(self.schedule)

    def penalise(self, robot: int, goal: int, cost: float) -> None:
        """Deadlock (paper 5.5.5): the robot's cost of this goal rises by C_d for good, from the next
        instance (a Participant) or block (a LocalAuction)."""
        if robot in self.own and 0 <= goal < len(self.goals):
            self.pending[self.own.index(robot), goal] += cost


class Participant(Auction):
    """The own robots of one host in the auction of one goal set (epoch), on one board (attributes flat:
    the compiled and lock-step rounds use them by name)."""

    def __init__(
        self, epoch: int, goals: np.ndarray, robots: list[int], own: list[int], eps: float, hysteresis: float = 0.0
    ) -> None:
        super().__init__(epoch, goals, robots, own, eps, hysteresis)
        self.row_of = {int(r): i for i, r in enumerate(self.robots)}
        self.is_own = np.isin(self.robots, self.own_ids)
        self._member = np.zeros(np.iinfo(RECORD["robot"]).max + 1, bool)  # by any robot id a record can carry
        self._member[self.robots] = True
        self.board = Board(len(self.goals))
        self.instance = -1  # not started: waits for the robots' positions
        k = len(self.own)
        self.position = np.zeros((k, 2))  # frozen per block of instances
        # C_d per (own row, goal) in force this instance (few: no K x G array), and declared, from the next
        self.penalty: dict[tuple[int, int], float] = {}
        self.pending: defaultdict[tuple[int, int], float] = defaultdict(float)
        self.goal = np.full(k, -1, np.int64)  # what each own robot claims
        # the newest record of every robot in the current instance, and the board it was written on
        r = len(self.robots)
        self.heard_instance = np.full(r, -1, np.int64)
        self.heard_serial = np.zeros(r, np.int64)
        self.heard_goal = np.full(r, -1, np.int64)
        self.heard_price = np.zeros(r)
        self.heard_flags = np.zeros(r, np.uint8)
        self.heard_digest = np.zeros(r, np.uint64)
        self.heard_version = 0
        self._heard = Heard(self)  # absorb's merges, compiled
        self._agreed: tuple[np.ndarray, dict[int, int] | None] = (np.zeros(0, np.int64), {})  # see agreed
        self.agreed_owner: np.ndarray | None = None  # per goal: its robot in the agreed instance (NO_OWNER: none)
        self.start_owner: np.ndarray | None = None  # per goal: its robot on the board a warm start began from
        self.claims_changed = False  # own claims changed since the last publication
        self.published_digest: int | None = None  # the board digest of the last publication
        self.rounds = 0  # Jacobi rounds in which some own robot bid
        # the compiled rounds (agent.core.bidding) over the board, the claims and the penalties
        self._bidders = self._new_bidders(CANDIDATES, exact_hull=False)
        self._exact_hull = False
        # the last two blocks' positions of every robot as its first round's records carry them (float32;
        # NaN: not heard): the tilt the next block's prices start from (``begin_block``)
        self.block_positions: list[np.ndarray] = []
        self.without_list = 0  # robots that had no candidate list at the start of the last block
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
        return float(self.slacks[self.phase])

    @property
    def started(self) -> bool:
        return self.instance >= 0

    @property
    def common_owner(self) -> np.ndarray | None:
        """Per goal its robot on the last board every host holds alike: the agreed one, else the warm
        start's (driven to until the first agreement). None: neither."""
        return self.agreed_owner if self.agreed_owner is not None else self.start_owner

    @property
    def is_agreed(self) -> bool:
        return self.started and self.agreed_instance == self.instance

    # --- instances --------------------------------------------------------------------------------
    def begin(self, instance: int, positions: Mapping[int, np.ndarray] | np.ndarray) -> None:
        """Start an instance, warm from the current board, and bid its first round (see _freeze). A host
        that holds every robot knows every position: its blocks start tilted as lock-step ones do."""
        alone = len(self.own) == len(self.robots)
        if self._freeze(instance, positions, tilt=alone) and alone:
            self.note_block_positions(self.own_ids, self.position)
        self.bid()

    def _new_bidders(self, candidates: int, exact_hull: bool) -> Bidders:
        """The own robots' compiled rounds; ``exact_hull`` for a host that settles alone."""
        hull = _hull_vertices(self.goals, exact=exact_hull)
        bidders = Bidders(self.board, self.goals, self.own_ids, self.goal, hull, candidates)
        bidders.set_penalties(*self._penalties())
        return bidders

    def _penalties(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The penalties in force as (rows, goals, costs), sorted by row, then goal."""
        keys = sorted(self.penalty)
        rows = np.array([r for r, _ in keys], np.int64)
        goals = np.array([g for _, g in keys], np.int64)
        return rows, goals, np.array([self.penalty[key] for key in keys], float)

    def _freeze(
        self, instance: int, positions: Mapping[int, np.ndarray] | np.ndarray, rank: bool = True, tilt: bool = False
    ) -> bool:
        """begin() up to its first round: a block's first instance freezes the positions (``tilt``: the
        prices first, _tilt_prices), declared penalties come into force (from the next instance:
        quiescence). ``rank=False``: the caller ranks. True: a new block began."""
        if self.started and not self.is_agreed and instance > self.instance:
            self.adopt_if_settled()  # someone reached a later instance: ours was agreed
        new_block = not self.started or instance // self.phases != self.instance // self.phases
        if new_block and tilt:
            self._tilt_prices()
        if new_block and self.own:
            self.position = frozen_positions(positions, self.own_ids if isinstance(positions, np.ndarray) else self.own)
        penalised = any(cost != 0.0 for cost in self.pending.values())
        if penalised:
            for key, cost in self.pending.items():
                self.penalty[key] = self.penalty.get(key, 0.0) + cost
            self._bidders.set_penalties(*self._penalties())
        self.pending = defaultdict(float)
        # costs (and so rankings) change only with a new block or a penalty
        if new_block or penalised:
            self._bidders.freeze(self.position)
            if rank:
                self.without_list = self._bidders.first_ranking()
        self.instance = instance
        self.claims_changed = True  # the new instance's records are news
        return new_block

    def carry(
        self,
        before: Participant,
        previous: np.ndarray,
        claim: bool = True,
        current: Mapping[int, int] | None = None,
        prices: np.ndarray | None = None,
    ) -> dict[int, int]:
        """The previous goal set's assignment carried over (paper 6.1; ``previous[j]``: the goal of
        ``before`` that goal j continues, -1 none; ``current``: own robots' goals there, default agreed
        else claimed); ``claim``: the auction starts from it, at ``prices``. Returns robot -> goal."""
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
            last = before.common_owner  # the same on every host; the live board may be mid-instance
            if last is None:
                last = np.where(before.board.released, NO_OWNER, before.board.owner)
            held = np.isin(last[i], self.robots)
            owner = np.full(len(self.goals), NO_OWNER, np.int64)
            owner[j[held]] = last[i[held]]
            self.board.owner[:] = owner
            self.start_owner = owner.copy()
            if prices is not None:
                self.board.price[:] = prices
            self.board.version += 1
            for k, r in enumerate(self.own):
                g = carried.get(r, -1)
                self.goal[k] = g if g >= 0 and owner[g] == r else -1
        return carried

    def start_from(self, owner: np.ndarray, prices: np.ndarray) -> dict[int, int]:
        """The first goal set's warm start: goal j claimed by ``owner[j]`` at ``prices[j]``, on every
        host alike. Returns robot -> goal."""
        owner = np.asarray(owner, np.int64)
        if self.started or len(owner) != len(self.goals) or len(prices) != len(self.goals):
            return {}
        self.board.owner[:] = owner
        self.board.price[:] = prices
        self.board.version += 1
        self.start_owner = owner.copy()
        goal_of = {r: j for j, r in enumerate(owner.tolist())}
        self.goal[:] = [goal_of.get(r, -1) for r in self.own]
        return {r: goal_of[r] for r in self.own if r in goal_of}

    def adopt_if_settled(self) -> None:
        """Adopt the current instance if every robot is content on one board (someone reached a later one)."""
        if self.final_phase and self._bidders.contentment(self.slack).all():
            self._adopt()

    # --- bidding ----------------------------------------------------------------------------------
    def ranking(self) -> tuple[np.ndarray, np.ndarray]:
        """Each own robot's best goal and net value max_j (-c_ij - b_j) on the board as it is."""
        return self._bidders.ranking()

    def bid(self) -> bool:
        """One Jacobi round of the own robots not content (max-consensus per goal); True if any bid."""
        if not self.started:
            return False
        bidders = self._bidders.bid(self.eps, self.slack)
        if not bidders:
            return False
        self.board.version += 1
        self.bids += bidders
        self.rounds += 1
        self.claims_changed = True
        return True

    def bid_until_quiet(self, max_rounds: int = 100_000) -> int:
        """Rounds until no own robot wants to bid (own robots outbid each other without messages)."""
        rounds = 0
        while rounds < max_rounds and self.bid():
            rounds += 1
        return rounds

    def settle_alone(
        self, positions: Mapping[int, np.ndarray] | np.ndarray, candidates: int = CANDIDATES
    ) -> np.ndarray:
        """A host that owns every robot (the central engine): the next block on these positions, warm,
        bid to agreement by bid()'s rounds. Returns each own robot's goal; RuntimeError past
        ROUNDS_PER_ROBOT rounds a robot (at least 100,000) in a phase."""
        block = self._block_to_settle(positions, candidates)  # first: it may make new bidders
        return self._adopt_settled(self._bidders.settle_block(*block))

    def settle_beside(self, positions: Mapping[int, np.ndarray] | np.ndarray, candidates: int = CANDIDATES) -> None:
        """settle_alone's block on a thread without the GIL; touch nothing but ``penalise`` until ``settled``."""
        block = self._block_to_settle(positions, candidates)  # first: it may make new bidders
        self._bidders.settle_beside(*block)

    def settled(self) -> np.ndarray:
        """The block of settle_beside, agreed: each own robot's goal, in the order of ``own``."""
        return self._adopt_settled(self._bidders.settled())

    def _block_to_settle(
        self, positions: Mapping[int, np.ndarray] | np.ndarray, candidates: int
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """The next block begun for the compiled rounds: its epsilons, slacks and rounds a phase may take."""
        if len(self.own) != len(self.robots):
            raise ValueError("settle_alone needs a host that owns every robot of the goal set")
        if candidates < 3:
            raise ValueError("settle_alone ranks at least 3 candidate goals per robot")
        if not self._exact_hull or self._bidders.candidates != candidates:
            self._bidders, self._exact_hull = self._new_bidders(candidates, exact_hull=True), True
        self.begin_block(positions, rank=False)
        self.note_block_positions(self.own_ids, self.position)  # every robot's own: its round 1, heard at once
        return np.array(self.schedule), self.slacks, max(100_000, ROUNDS_PER_ROBOT * len(self.robots))

    def _adopt_settled(self, outcome: tuple[int, int, int, int, float]) -> np.ndarray:
        """A settled block's outcome (Bidders.settle_block) adopted: each own robot's goal."""
        rounds, bids, settled, self.without_list, _ = outcome
        self.instance += min(settled, self.phases - 1)
        self.board.version += 1
        self.bids, self.rounds, self.claims_changed = self.bids + bids, self.rounds + rounds, True
        if settled < self.phases:
            raise RuntimeError(f"auction instance {self.instance} did not settle")
        self._adopt()
        return self.goal.copy()

    @property
    def settling(self) -> bool:
        """A block of settle_beside is under way (``settled`` not called yet)."""
        return self._bidders.settling

    @property
    def beside_seconds(self) -> float:
        """The wall seconds the last block of settle_beside took on its thread."""
        return self._bidders.job_seconds

    # --- lock-step rounds ----------------------------------------------------------------------------
    def begin_block(self, positions: Mapping[int, np.ndarray] | np.ndarray, rank: bool = True) -> None:
        """Begin the next block on these positions, warm, bidding nothing yet (lock-step: every host bids
        in round 1 against the same board)."""
        first = (self.instance // self.phases + 1) * self.phases if self.started else 0
        self._freeze(first, positions, rank, tilt=True)

    def note_block_positions(self, robots: np.ndarray, position: np.ndarray) -> None:
        """The current block's first round heard: these robots' frozen positions, as records carry them."""
        if robots is self.own_ids and len(self.own) == len(self.robots):  # every robot, by row
            block = np.array(position, np.float32).reshape(-1, 2)
        else:
            block = np.full((len(self.robots), 2), np.nan, np.float32)  # NaN: not heard
            block[self.own_rows if robots is self.own_ids else np.searchsorted(self.robots, robots)] = position
        self.block_positions = [*self.block_positions[-1:], block]

    def _tilt_prices(self) -> None:
        """Raise the prices by 2 d . g_j (less their least), d the robots' mean move between the last two
        blocks: a swarm that moves on as it moved shifts every robot's values so, and prices that follow
        spare the auction re-pricing goal by goal (docs/architecture.md, "Goal assignment"). Every host
        computes it alike, from the records' positions (Bidders.tilt_prices)."""
        if len(self.block_positions) == 2 and self._bidders.tilt_prices(*self.block_positions):
            self.board.version += 1

    def round_records(self) -> np.ndarray:
        """Lock-step: records(), SETTLED where content at the final (least) slack."""
        return self._bidders.records(self.position, self.slack, True, float(self.slacks[-1]))

    def close_round(self, unchanged: bool, settled: Callable[[], bool]) -> bool:
        """Lock-step (every host decides alike): a round that changed nothing ends its phase; the block
        is agreed (True) in the final phase or when all are ``settled()`` (the phases left pass)."""
        if not unchanged:
            return False
        if not (self.final_phase or settled()):
            self._freeze(self.instance + 1, {})
            return False
        self.instance = (self.instance // self.phases + 1) * self.phases - 1  # the block's final phase
        self._adopt()
        return True

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
        """A claim per own robot, and the releases still on the board (a lost message's price is learnt)."""
        return self._bidders.records(self.position, self.slack, False, 0.0)

    def members_only(self, recs: np.ndarray) -> np.ndarray:
        """Another host's records of this goal set's robots only (a damaged id must not index a row)."""
        recs = np.asarray(recs, RECORD)
        if len(recs) <= SMALL:  # a robot per host: a set lookup costs less than np.isin
            ids = recs["robot"].tolist()
            return recs if all(r in self.row_of for r in ids) else recs[[r in self.row_of for r in ids]]
        return recs[self._member[recs["robot"]]]

    def absorb(self, instance: int, serial: int, digest: int, recs: np.ndarray) -> bool:
        """Merge another host's records (members_only first); True when the board changed. The current
        instance's newest record per robot is kept for the agreement check."""
        recs = np.ascontiguousarray(recs, RECORD)
        changed, heard = self._heard.absorb(recs, instance, instance == self.instance, serial, digest)
        self.board.version += changed
        self.heard_version += heard
        return changed

    def _settled_view(self, same_board: bool) -> bool:
        """Every robot content on a distinct goal as far as we know: others by their newest records still
        holding on our board (``same_board``: written against our digest)."""
        if not self.started:
            return False
        key = (self.board.version, self.heard_version, self.instance, self.goal.tobytes())
        cached = self._view_cache.get(same_board)
        if cached is not None and cached[0] == key:
            return cached[1]
        self._view_cache[same_board] = (key, False)
        if not self._bidders.contentment(self.slack).all():
            return False
        others = ~self.is_own
        ok = (self.heard_instance[others] == self.instance) & ((self.heard_flags[others] & CONTENT) != 0)
        if same_board:
            ok &= self.heard_digest[others] == np.uint64(self.board.digest())
        if not ok.all():
            return False
        goal, price, robot = self.heard_goal[others], self.heard_price[others], self.robots[others]
        if not (self.board.holds(robot, goal).all() and (self.board.price[goal] == price).all()):
            return False
        taken = np.concatenate([self.goal, goal])
        self._view_cache[same_board] = (key, len(set(taken.tolist())) == len(taken))
        return self._view_cache[same_board][1]

    def view_complete(self) -> bool:
        """Nobody is bidding as far as we know: the moment to tell others our digest (not stale at once)."""
        return self._settled_view(same_board=False)

    def check_agreement(self) -> bool:
        """True (once per instance) when this host sees it agreed; sets ``agreed``. Earlier phases move
        on as soon as nobody bids (no snapshot: only the final phase's guarantees)."""
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
        """Own robot -> its goal in the agreed instance (made when first asked for)."""
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
