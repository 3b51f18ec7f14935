"""The key-expression schema: every key the system uses is built here and nowhere else.

Every key of a display is ``px/<display>/<kind>/...``; each method says what its key carries. Who sends
what to whom: docs/protocol.md ("Key expressions").
"""

from __future__ import annotations

import functools
import itertools
import math
import re
from typing import TYPE_CHECKING

import numpy as np

from .codec import MAX_ROBOTS

if TYPE_CHECKING:  # numpy.typing stays out of a robot's process: annotations only
    from numpy.typing import ArrayLike

PREFIX = "px"
_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
_RUN = re.compile(r"^(\d+)(?:-(\d+))?$")  # a run of robot ids in a liveliness ident


def robots_ident(robots: list[int]) -> str:
    """An agent host's liveliness ident: its robots as runs of consecutive ids, "0-999" or "3_5-7". One
    token per host: zenoh's propagation of tokens slows faster than their number grows."""
    ids = sorted(set(robots))
    runs = [[r for _, r in run] for _, run in itertools.groupby(enumerate(ids), lambda at: at[1] - at[0])]
    return "_".join(str(run[0]) if len(run) == 1 else f"{run[0]}-{run[-1]}" for run in runs)


def robots_of_ident(ident: str) -> list[int] | None:
    """The robots a liveliness ident of robots_ident names; None if it names none, or an id no robot has
    (a forged "0-4294967295" would have every process listing four billion robots)."""
    robots: list[int] = []
    for run in ident.split("_"):
        bounds = _RUN.match(run)
        if bounds is None or not int(bounds[1]) <= int(bounds[2] or bounds[1]) < MAX_ROBOTS:
            return None
        robots.extend(range(int(bounds[1]), int(bounds[2] or bounds[1]) + 1))
        if len(robots) > MAX_ROBOTS:  # runs that repeat each other
            return None
    return robots


CELLS = 2**30  # cells either side of 0 at most: a position beyond (a forged pose) is in the outermost


def cell_of(x: float, y: float, cell_size: float) -> tuple[int, int]:
    """The spatial cell of a position: an agent subscribes to the 5x5 (real time) or
    7x7 (lock-step) cells around each of its robots' (agent.runtime.CellSubscriptions)."""
    return _cell(x / cell_size), _cell(y / cell_size)


def _cell(v: float) -> int:
    return math.floor(v) if -CELLS <= v < CELLS else (-CELLS if v < 0 else CELLS - 1)


def cells_of(xy: ArrayLike, cell_size: float) -> np.ndarray:
    """cell_of for rows of positions at once: (N, 2) int64 (a host places all its robots each tick)."""
    cells = np.floor(np.asarray(xy, float).reshape(-1, 2) / cell_size)
    return np.minimum(np.maximum(cells, -CELLS, out=cells), CELLS - 1, out=cells).astype(np.int64)


class Keys:
    """Key expressions of one display (one swarm sharing a router)."""

    def __init__(self, display: str = "default") -> None:
        if not _NAME.match(display):
            raise ValueError(f"display name {display!r} may hold only letters, digits, '_' and '-'")
        self.display = display
        self.root = root = f"{PREFIX}/{display}"
        self.poses = f"{root}/pose"  # the Poses frame of every tracked robot (agent hosts of several robots)
        self.states_all = f"{root}/state/*"  # every host's States frames (not the cells: one chunk after 'state')
        self.states_in_cells = f"{root}/state/*/*/*"  # every robot alone's state, whatever its cell
        # the newest goal set the run recorded, served by the launcher: a restarted coordinator goes on from it
        self.run_goals = f"{root}/run/goals"
        self.clock, self.event, self.everything = f"{root}/clock", f"{root}/event", f"{root}/**"
        self.truth, self.contact = f"{root}/sim/truth", f"{root}/sim/contact"

    def stats(self, robot: int) -> str:
        """An agent host's events (its statistics; a lock-step block given up), keyed by its first robot: the run's
        own events (its end, the world's report) are the services', which a robot may not publish on a secured bus."""
        return f"{self.event}/{robot}"

    @property
    def agents_events(self) -> str:
        """Every agent host's events (stats)."""
        return f"{self.event}/*"

    # tracker -> agent: every key of kind 'pose' carries a Poses frame
    def pose(self, robot: int) -> str:
        """One robot's frame: its pose first, then the bodies near it (a robot alone hears no other pose)."""
        return f"{self.root}/pose/{robot}"

    # agent broadcasts: every key of kind 'state' carries a States frame
    def state(self, cell: tuple[int, int], robot: int) -> str:
        """A robot alone: its frame of one, under its spatial cell (neighbours subscribe to cells)."""
        return f"{self.root}/state/{cell[0]}/{cell[1]}/{robot}"

    def states(self, host: int) -> str:
        """A host's frame of its robots' states (<host>: its first robot), heard by every host."""
        return f"{self.root}/state/{host}"

    def state_of(self, robot: int) -> str:
        """One robot's broadcasts, whatever cell it is in."""
        return f"{self.root}/state/*/*/{robot}"

    def state_cell(self, cell: tuple[int, int]) -> str:
        return f"{self.root}/state/{cell[0]}/{cell[1]}/*"

    def cmd(self, robot: int) -> str:
        """A Commands frame from the sender whose first robot this is (a robot alone: its own)."""
        return f"{self.root}/cmd/{robot}"

    def goals(self, epoch: int) -> str:
        return f"{self.root}/goals/{epoch}"

    def auction(self, epoch: int, robot: int) -> str:
        return f"{self.root}/auction/{epoch}/{robot}"

    def auction_of(self, robot: int) -> str:
        """One robot's bids and prices, whatever the epoch."""
        return f"{self.root}/auction/*/{robot}"

    def boards(self, epoch: int, robot: int) -> str:
        """The range-limited auction's words of the host whose first robot this is."""
        return f"{self.root}/boards/{epoch}/{robot}"

    def boards_of(self, robot: int) -> str:
        return f"{self.root}/boards/*/{robot}"

    def config(self, robot: int | str) -> str:
        """A robot's host configuration, served by a run whose agents join from elsewhere ('*': every robot's)."""
        return f"{self.root}/config/{robot}"

    def alive(self, role: str, ident: int | str, incarnation: str = "*") -> str:
        """A process's liveliness token (incarnation: its life, transport.bus.LivelinessWatch)."""
        return f"{self.root}/alive/{role}/{ident}/{incarnation}"

    # wildcards for subscribers
    def all_of(self, kind: str) -> str:
        """Every key of one kind, e.g. all_of('cmd') -> px/<display>/cmd/**."""
        return f"{self.root}/{kind}/**"

    def alive_all(self, role: str | None = None) -> str:
        return f"{self.root}/alive/{role}/*/*" if role else f"{self.root}/alive/**"

    def kind_of(self, key: str) -> str:
        """The message kind a key carries ('pose', 'state', 'sim/truth', ...), '' if not ours."""
        if not key.startswith(self.root + "/"):
            return ""
        parts = key[len(self.root) + 1 :].split("/")
        return "/".join(parts[:2]) if parts[0] == "sim" else parts[0]

    @staticmethod
    @functools.lru_cache(maxsize=4096)  # a receiver hears the same few keys every tick
    def robot_alone(key: str) -> int | None:
        """The robot a key names as the one robot its frames hold (``pose/<id>``,
        ``state/<cx>/<cy>/<id>``), None for keys of several robots' frames or of other kinds."""
        parts = key.rsplit("/", 4)
        if (len(parts) >= 3 and parts[-2] == "pose") or (len(parts) == 5 and parts[-4] == "state"):
            return Keys.last_id(key)
        return None

    @staticmethod
    def last_id(key: str) -> int | None:
        """The trailing robot id of a key, None if it is not a number."""
        tail = key.rsplit("/", 1)[-1]
        return int(tail) if tail.lstrip("-").isdigit() else None
