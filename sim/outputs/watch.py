"""`pixelswarm view --connect ENDPOINT`: watch a running swarm from another process, a read-only subscriber (the
``observer`` role on a secured bus) to what the run broadcasts anyway, so no process of the run does anything for it."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sim.args import check_endpoint, usage_errors
from sim.outputs.view import SwarmView
from sim.processes import stop_on_sigterm
from transport.bus import Bus, Inbox, LivelinessWatch, RawInbox
from transport.codec import BEFORE_START, State, States, Truth, decode
from transport.epuck import RADIUS
from transport.keys import Keys
from transport.security import OBSERVER, SecurityError, check_role, client_config
from transport.session import ZenohSettings

RUN_TIMEOUT = 60.0  # s to wait for the run's first tick by default
AFTER_WORLD = 0.5  # s to wait for truth still in flight once the world's liveliness has gone
POLL = 0.2  # s between looks at liveliness while no tick comes
NO_RUN = 1  # exit code: no tick came within the timeout


def observer_settings(endpoint: str, secure: Path | None, display: str) -> ZenohSettings:
    """A client session of the run's router at ``endpoint``, plain or as the observer of a `pixelswarm certs`
    folder; UsageError for bad input."""
    with usage_errors(SecurityError, ValueError):
        Keys(display)
        if secure is not None:
            check_role(secure, OBSERVER, display=display)
            settings = client_config(secure, OBSERVER, endpoint)
        else:
            settings = ZenohSettings(mode="client", connect=[endpoint])
    check_endpoint(settings, endpoint)
    return settings


class Watcher:
    """The subscriptions of one viewer, and the robots' goals and sizes as their states last said."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        keys = bus.keys
        self.truth: Inbox[Truth] = bus.subscribe(keys.truth, Truth)
        self.states: RawInbox = bus.subscribe_raw(keys.all_of("state"))
        self.worlds: LivelinessWatch = bus.watch_alive("world")
        self.world_seen = False
        self.world_alive = False
        self.size(0)

    def size(self, robots: int) -> None:
        self.n = robots
        self.goal = np.full((robots, 2), np.nan)
        self.radius = np.full(robots, np.nan)
        self.state_tick = np.full(robots, -1, np.int64)

    def look_at_worlds(self) -> None:
        self.bus.renew_if_due()  # its link to the router came back a while ago
        for _, _, alive, _, _ in self.worlds.drain():
            self.world_seen |= alive
            self.world_alive = alive

    def take_states(self) -> None:
        """Each robot's newest goal and size (a frame's records at once: a host sends hundreds)."""
        for _, payload, _ in self.states.drain():
            msg = decode(payload, States)
            if msg is None or not self.n:
                continue
            rec = msg.records
            robot = rec["robot"].astype(np.int64)
            ok = robot < self.n
            if msg.tick == BEFORE_START:  # before the first tick: its size, no goal yet
                known = self.radius[robot[ok]]
                self.radius[robot[ok]] = np.where(np.isnan(known), rec["radius"][ok], known)
                continue
            newer = ok.copy()
            newer[ok] = msg.tick >= self.state_tick[robot[ok]]
            r = robot[newer]
            has_goal = (rec["flags"][newer] & State.HAS_GOAL) != 0
            self.goal[r, 0] = np.where(has_goal, rec["goal_x"][newer], np.nan)
            self.goal[r, 1] = np.where(has_goal, rec["goal_y"][newer], np.nan)
            self.radius[r] = rec["radius"][newer]
            self.state_tick[r] = msg.tick

    def first_tick(self, timeout: float) -> Truth | None:
        """The first truth heard within ``timeout`` s, or None."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            got = self.truth.get(timeout=min(POLL, left))
            self.look_at_worlds()
            if got is not None and got[1].count > 0:
                self.size(got[1].count)
                return got[1]
        return None

    def follow(self, view: SwarmView, first: Truth) -> tuple[int, int]:
        """Log every tick heard until AFTER_WORLD after the world's liveliness went; returns (ticks, last tick)."""
        logged, last, quiet_since = 0, first.tick, None
        msg: Truth | None = first
        while True:
            if msg is not None and msg.count == self.n and msg.tick >= last:
                self.take_states()
                view.truth(msg, self.goal, self.radius)
                logged, last = logged + 1, msg.tick
            self.look_at_worlds()
            if self.world_seen and not self.world_alive:
                quiet_since = quiet_since or time.monotonic()
                if time.monotonic() - quiet_since >= AFTER_WORLD:
                    return logged, last
            got = self.truth.get(timeout=POLL)
            msg = None if got is None else got[1]


def watch(
    settings: ZenohSettings,
    display: str,
    sink: str | os.PathLike,
    *,
    timeout: float = RUN_TIMEOUT,
    say: Callable[[str], None] = lambda text: None,
) -> int:
    """Watch the run on ``display`` into ``sink`` (as SwarmView takes it). Exit code: 0 the run ended, NO_RUN no
    tick within ``timeout``, 130 interrupted (the recording whole either way)."""
    stop_on_sigterm()
    with Bus(settings, display, name=OBSERVER) as bus:
        watcher = Watcher(bus)
        say(f"waiting for a run on display {display} to tick")  # subscribed: from here no tick is missed
        try:
            first = watcher.first_tick(timeout)
            if first is None:
                say(f"no run on display {display} ticked within {timeout:g} s")
                return NO_RUN
            # an e-puck's size until the robots' states say theirs
            with contextlib.closing(SwarmView(display, None, [], RADIUS, robots=watcher.n, sink=sink)) as view:
                say(f"watching {watcher.n} robots of display {display} from tick {first.tick}")
                if view.url is not None:
                    say(f"view: {view.url}")
                logged, last = watcher.follow(view, first)
                say(f"the run ended at tick {last}; {logged} ticks viewed")
                view.flush()
                if view.url is not None:
                    say(f"view: {view.url} (Ctrl-C to stop)")
                    view.serve_until_interrupted()
                return 0
        except KeyboardInterrupt:
            return 130


def print_line(prog: str, quiet: bool) -> Callable[[str], None]:
    """Progress lines on stderr (nothing with --quiet)."""
    if quiet:
        return lambda text: None
    return lambda text: print(f"{prog}: {text}", file=sys.stderr, flush=True)
