"""What every pose source hands out: each robot's newest pose, when it was measured and how old it is;
and which poses it takes, by their stamps (StampGate)."""

import math
from collections import Counter
from typing import NamedTuple

# s a stamp may lie ahead of the clock judging it (NTP keeps a lab's clocks within ms): further ahead is a
# bad clock or a forged message, and taken it would make every true pose after it look old
FUTURE_MARGIN = 1.0
# s with none taken for a robot after which an older stamp is taken anyway (its source restarted); a replay
# beside a live source is never taken, as the live source's poses keep being taken
RESTART_AFTER = 0.5
STAMP_DROPS = ("stale", "future")  # the reasons a pose is dropped for its stamp


class PoseSample(NamedTuple):
    x: float  # m
    y: float  # m
    theta: float  # rad
    stamp: float  # s, when it was measured, on the source's clock (a message header, a camera frame)
    age: float  # s since it reached this process (this machine's clock; the stamp's clock may differ)


class StampGate:
    """Per robot, which poses a source takes: one stamped later than the newest taken, and not ahead
    of the clock by more than FUTURE_MARGIN; after RESTART_AFTER s with none taken, any
    pose not from the future (a restarted source). Not thread-safe: its source holds its lock."""

    def __init__(self) -> None:
        self._newest: dict[int, tuple[float, float]] = {}  # robot -> stamp taken, when it arrived
        self._counts = {reason: Counter[int]() for reason in (*STAMP_DROPS, "restarts")}

    def admit(self, robot: int, stamp: float, now: float, arrival: float) -> bool:
        """Whether to take a pose of ``robot`` stamped ``stamp``, judged against ``now`` on the stamp's
        clock; ``arrival`` is when it arrived (s on any monotonic clock, the same for every call)."""
        if stamp > now + FUTURE_MARGIN:
            self._counts["future"][robot] += 1
            return False
        newest = self._newest.get(robot)
        if newest is not None and stamp <= newest[0]:
            if arrival - newest[1] < RESTART_AFTER:
                self._counts["stale"][robot] += 1
                return False
            self._counts["restarts"][robot] += 1
        self._newest[robot] = (stamp, arrival)
        return True

    def robot_stats(self, robot: int) -> dict[str, int]:
        """Poses of one robot dropped as stale or future, and restarts taken."""
        return {reason: counts[robot] for reason, counts in self._counts.items()}

    def stats(self) -> dict[str, int]:
        """The same, summed over every robot."""
        return {reason: counts.total() for reason, counts in self._counts.items()}


class OneSource:
    """Per robot, whether its poses come from one publisher. Two within RESTART_AFTER of each other (or one
    whose sequence numbers go back: its id copied) cannot both be its tracker, and which is cannot be told:
    its poses are doubted, none taken, until RESTART_AFTER after the last clash, so its drive stops it as
    for a lost pose. A tracker that restarted under a new id, the old one silent that long, is taken at once."""

    def __init__(self) -> None:
        self._heard: dict[int, dict[object, tuple[float, int]]] = {}  # robot -> source -> (arrival, sequence)
        self._doubt_until: dict[int, float] = {}
        self.clashes = Counter[int]()  # per robot, poses dropped while its sources clashed

    def admit(self, robot: int, source: object, sequence: int, arrival: float) -> bool:
        """Whether to take a pose of ``robot`` from ``source`` (``sequence``: its count, -1 if it has none)."""
        heard = {s: h for s, h in self._heard.get(robot, {}).items() if arrival - h[0] < RESTART_AFTER}
        before = heard.get(source)
        if len(heard) > (before is not None) or (before is not None and 0 <= sequence <= before[1]):
            self._doubt_until[robot] = arrival + RESTART_AFTER
        heard[source] = (arrival, sequence)
        self._heard[robot] = heard
        if arrival < self._doubt_until.get(robot, -math.inf):
            self.clashes[robot] += 1
            return False
        return True

    def doubted(self, robot: int, now: float) -> bool:
        """The robot's poses are doubted at ``now`` (the arrivals' clock)."""
        return now < self._doubt_until.get(robot, -math.inf)
