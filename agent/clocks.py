"""The agent host's two clocks: the world's lock-step ticks (reproducible from the seed), or the wall clock."""

from __future__ import annotations

import bisect
import math
import time
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from transport.bus import Inbox
from transport.codec import BEFORE_START, START_TICK, Goals, Pose, State, Tick, as_sent
from transport.plausible import AHEAD, STALE, Clock

from .core.params import RobotParams

GOAL_SET_WAIT = 10.0  # s a lock-step tick waits for its clock message and the goal sets it names
HELLO_EVERY = 0.1  # s between a lock-step host's hellos before the first tick, up to HELLO_SWARM robots
HELLO_SWARM = 1000  # larger swarms say hello proportionally less often: every host hears every hello
HELLO_TIMEOUT = 30.0  # s a host waits for its neighbours' hellos before it says it is alive anyway
LATENESS_WINDOW = 50  # ticks over which the quickest pose is remembered, so that a loaded spell ages out


class Lateness:
    """Real time: the age of a tick's pose when the agent acts on it, beyond the quickest seen lately."""

    def __init__(self, dt: float, command_margin: float, window: int = LATENESS_WINDOW) -> None:
        self.most = dt + command_margin  # a later command never drives: its body stands
        self._quickest: deque[float] = deque(maxlen=window)  # wall time minus stamp, per tick
        self.worst = 0.0  # the worst lateness acted on (s), for the host's statistics
        self.total, self.count = 0.0, 0  # ... and their sum over the ticks acted on

    def arrived(self, stamp: float, wall: float) -> None:
        """A tick's first pose, stamped ``stamp`` (display time), taken at ``wall`` (monotonic)."""
        self._quickest.append(wall - stamp)

    def at(self, stamp: float, wall: float) -> float:
        """How late acting at ``wall`` on a pose stamped ``stamp`` is, in seconds (0 on time)."""
        if not self._quickest:
            return 0.0
        late = min(max(wall - stamp - min(self._quickest), 0.0), self.most)
        self.worst = max(self.worst, late)
        self.total, self.count = self.total + late, self.count + 1
        return late

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0


def strayed(late: float, v_max: float) -> float:
    """How far a body may be from where its plan starts when a command late by ``late`` takes over (a reversal)."""
    return 2.0 * v_max * late


class HostClock:
    """What the host asks of its clock at each point of a tick; each hook does nothing unless the clock needs it."""

    def __init__(self, host: Any) -> None:  # the agent.runtime.AgentHost whose ticks this clock brings
        self.host = host
        self.pose_period: float | None = None  # a pose's tick may not run ahead of the wall clock by more
        self.collect = 0.0  # s to wait for the rest of a tick's poses
        self.lateness = Lateness(host.params.dt, host.params.command_margin)  # real time: a pose's age acted on
        self.inbox: Inbox[Tick] | None = None  # the world's clock messages
        self.clock = Clock()  # the world's clock as heard
        self.link_returns = 0  # of the host's bus, when the clock last started again (hear)
        self.silent: set[int] = set()  # lock-step: nearby robots that did not answer in time
        self.state_waits = 0
        # lock-step waits that ran out, so the run went on in a way the machine's load chose: by what was waited for
        self.gave_up: dict[str, int] = {"neighbour_states": 0, "goal_sets": 0}
        self.hello_every = math.inf  # s between hellos (lock-step's start-up)

    def greet(self, where: dict[int, Pose], timeout: float) -> None: ...  # before the robots say they are alive

    def say_hello(self) -> None: ...

    def hear_hello(self, hello: State) -> None: ...

    def latest_pose_tick(self) -> int | None:
        """The latest tick an honest pose can carry now (None: the clock does not say). The world sends a
        tick's clock message before its poses, on the same link and in order: a pose beyond the newest tick
        heard was forged (a few ticks' slack only under injected clock faults)."""
        if self.inbox is None:
            return None
        self.hear()
        newest = self.clock.newest
        return newest if newest is None or self.inbox.fault is None else newest + AHEAD

    def hear(self) -> None:
        """The world's clock messages heard since. Once our link to the router came back, the clock starts again
        from the first tick heard: the ticks sent meanwhile are lost, and a lock-step world goes on without robots
        heard dead, so the next may lie any number of ticks ahead (refused, it would wait for us in vain). So do
        the goal sets' epochs (GoalSets.rejoin)."""
        if self.host.bus.link_returns != self.link_returns:
            self.link_returns = self.host.bus.link_returns
            self.clock = Clock(self.clock.line.period)
            self.host.goal_sets.believed.rejoin()
        for _, clock in self.inbox.drain() if self.inbox is not None else ():
            self.on_clock(clock)

    def begins_again_after(self, epoch: int) -> bool:
        """A goal set after ``epoch`` is held that starts cold: every host begins its auction again from it."""
        return False

    def on_clock(self, clock: Tick) -> str | None:
        """A clock message taken (None) or why not."""
        why = self.clock.admit(clock, time.monotonic())
        if why is not None and self.inbox is not None:
            self.inbox.drops[why] += 1
        return why

    def display_time(self) -> float | None:
        return None

    def holds(self, goals: Goals) -> bool:
        """A goal set held back until a tick takes it up."""
        return False

    def poses_arrived(self, poses: list[Pose], wall: float) -> None: ...

    def before_step(self, poses: list[Pose]) -> None: ...

    def params_at(self, stamp: float, began: float) -> RobotParams:
        return self.host.params

    def await_neighbours(self, tick: int, position: np.ndarray) -> None: ...

    def take_up_goal_sets(self, tick: int, stamp: float) -> None: ...

    def stepped(self, began: float) -> None: ...


class WallClock(HostClock):
    """Real time: a tick's poses as they come; robots acting late grow their margins."""

    def __init__(self, host: Any) -> None:
        super().__init__(host)
        self.pose_period, self.collect = host.params.dt, host.config.batch_wait
        self.compute = 0.0  # wall seconds the last tick's step took (its command leaves that much later)
        # the world's clock bounds the poses' ticks, as in lock-step: a forged pose of a tick or two ahead,
        # taken first, would make the robot brake when the world's pose of that tick came
        self.inbox = host.bus.subscribe(host.bus.keys.clock, Tick, pulled=True)
        self.clock = Clock(host.params.dt)  # in real time it keeps the wall clock's pace

    def poses_arrived(self, poses: list[Pose], wall: float) -> None:
        if poses:
            self.lateness.arrived(max(q.stamp for q in poses), wall)

    def params_at(self, stamp: float, began: float) -> RobotParams:
        """Late: the body may have strayed from the pose (Lateness)."""
        p = self.host.params
        late = self.lateness.at(stamp, began + self.compute)
        return p.grown(strayed(late, p.v_max)) if late > 0 else p

    def stepped(self, began: float) -> None:
        self.compute = time.monotonic() - began


class LockStep(HostClock):
    """The world's ticks: a tick waits for its neighbours' states and the goal sets it names."""

    def __init__(self, host: Any) -> None:
        super().__init__(host)
        self.collect = host.config.state_wait
        # read when a pose comes or a tick waits for its goal sets (the pose wakes the loop): pulled
        self.ticks = self.inbox = host.bus.subscribe(host.bus.keys.clock, Tick, pulled=True)
        self.named: dict[int, int] = {}  # tick -> the newest goal set the world named in it
        self.unnamed: dict[int, Goals] = {}  # goal sets heard that no tick has named yet
        self.greeted: dict[int, State] = {}  # hellos heard before the first tick, by robot
        self.hellos: list[State] = []  # our own, sent until the first tick
        self.joined_in = -1  # started again (or late) in a run under way: the newest tick greet heard poses of
        self.last_hello = -math.inf
        self.hello_every = HELLO_EVERY * max(1.0, host.config.swarm / HELLO_SWARM)
        # injected state delays count in ticks (reproducible); see Inbox.sim_time
        host.inbox.state.sim_time = -math.inf
        host.inbox.state.seen = {}  # states waited for arrive, even those the fault plan drops or holds

    def greet(self, where: dict[int, Pose], timeout: float) -> None:
        """Before the robots say they are alive: hear every nearby robot's hello, so their tick-0 states reach us."""
        host = self.host
        self.hellos = [
            State(r, BEFORE_START, 0.0, q.x, q.y, 0.0, 0.0, host.params.radius, 0.0, 0.0, -1, 0, 0, 0)
            for r, q in sorted(where.items())
        ]
        if max(q.stamp for q in where.values()) > 0.0:  # under way: its auction waits for the next goal set
            host.goal_sets.bid_from = host.goal_sets.newest_heard + 1
            self.joined_in = max((q.tick for q in where.values() if q.tick != BEFORE_START), default=-1)
            return
        expected = set(host.config.greet) - set(host.config.robots)
        end = time.monotonic() + min(HELLO_TIMEOUT, timeout)
        while host.running and not expected <= set(self.greeted) and time.monotonic() < end:
            self.say_hello()
            # looked at twice a hello period: a wait on the pulled inbox looks too often when many hosts greet
            time.sleep(self.hello_every / 2)
            for _, state in host.inbox.state.drain():
                host.on_state(state)
        # where each stands at tick 0, as a state of the tick before: one heard no more goes stale and ours
        # stand for it (agent.core.control). Ours and those expected only, whatever else came by when: every
        # run the same, and as the central engine's link starts (InProcessLink.start)
        mine = self.hellos if host.config.hears_itself else []  # a robot alone keeps no state of itself
        for hello in [*mine, *(self.greeted[r] for r in sorted(expected) if r in self.greeted)]:
            x, y, radius = as_sent([hello.x, hello.y, hello.radius]).tolist()  # ours as the others hear them
            start = replace(hello, tick=START_TICK, stamp=START_TICK * host.params.dt, x=x, y=y, radius=radius)
            host.table.update(start)

    def say_hello(self) -> None:
        if self.hellos and time.monotonic() - self.last_hello >= self.hello_every:
            self.host.publish_states(BEFORE_START, 0.0, self.hellos)
            self.last_hello = time.monotonic()

    def hear_hello(self, hello: State) -> None:
        if self.host.counts.ticks < 2:
            self.greeted[hello.robot] = hello

    def display_time(self) -> float | None:
        return None if self.clock.newest is None else self.clock.newest * self.host.params.dt

    def holds(self, goals: Goals) -> bool:
        """A new goal set waits for the tick that takes it up, the same for every host (take_up_goal_sets)."""
        if goals.per_robot or goals.epoch <= max(self.host.goal_sets.by_epoch, default=0):
            return False
        self.unnamed[goals.epoch] = goals
        return True

    def begins_again_after(self, epoch: int) -> bool:
        return any(e > epoch and goals.warm_start is None for e, goals in self.unnamed.items())

    def before_step(self, poses: list[Pose]) -> None:
        self.host.inbox.state.sim_time = max(p.stamp for p in poses)

    def await_neighbours(self, tick: int, position: np.ndarray) -> None:
        """Wait for every nearby robot's state of the last tick; one silent ``state_wait`` is skipped till it speaks."""
        host = self.host
        reach = host.params.state_reach
        deadline = time.monotonic() + host.config.state_wait
        seen = host.inbox.state.seen if host.inbox.state.seen is not None else {}  # arrived, whatever a fault did
        # the newest tick heard of a robot: an arrival claimed from beyond this tick proves nothing (damaged, forged)
        heard = lambda s: max(s.tick, _at_most(seen.get(s.robot, -1), tick))
        near = lambda s: np.min(np.hypot(position[:, 0] - s.x, position[:, 1] - s.y)) <= reach
        while True:
            behind = [s for s in host.table.latest_before(tick) if heard(s) < tick - 1]
            if tick > 0 and host.counts.ticks < 2:  # the first tick after tick 0: robots that greeted us
                behind += [
                    h for r, h in self.greeted.items() if r not in host.table and r not in seen and r not in host.robots
                ]
            missing = [s.robot for s in behind if s.robot not in self.silent and near(s)]
            if not missing:
                for _, state in host.inbox.state.drain():  # what arrived (seen) is taken in before the step
                    host.on_state(state)
                return
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.silent.update(missing)
                self.gave_up["neighbour_states"] += len(missing)
                return
            self.state_waits += 1
            # short: a state the fault plan dropped counts as arrived (seen) but rings nothing
            got = host.inbox.state.get(timeout=min(remaining, 0.005))
            if got is not None:
                host.on_state(got[1])

    def take_up_goal_sets(self, tick: int, stamp: float) -> None:
        """Take up the goal sets due at this tick (its clock message names them), the same for every host."""
        host = self.host
        due = bisect.bisect_right(host.config.steps, stamp + 1e-9) - 1  # numpy's would make an array a tick
        deadline = time.monotonic() + GOAL_SET_WAIT
        if tick <= self.joined_in:
            # a tick we joined in: its clock message may have gone out before we subscribed, and the world
            # waits for our command; a set it names began without us anyway (Lives, bid_from)
            deadline = 0.0
        self.hear()
        host.hear_early_goals()  # once the clock has gone on
        while host.running and time.monotonic() < deadline:
            self.hear()
            has_step = due < 0 or any(
                g.timing.step >= due for g in (*host.goal_sets.by_epoch.values(), *self.unnamed.values())
            )
            known = tick in self.named or self._missed(tick)
            # an epoch past AHEAD of the newest heard is taken only after those between: not worth a wait
            named = self.named.get(tick, 0)
            if known and has_step and not host.goal_sets.newest_heard < named <= host.goal_sets.newest_heard + AHEAD:
                break
            wait = max(min(deadline - time.monotonic(), 0.05), 0.0)
            if not known:
                got_tick = self.ticks.get(timeout=wait)
                if got_tick is not None:
                    self.on_clock(got_tick[1])
                continue
            got = host.inbox.goals.get(timeout=wait)
            if got is not None:
                host.hear_goals(got[1])
        else:  # the wait ran out (a tick we joined in waits for nothing)
            self.gave_up["goal_sets"] += int(host.running and tick > self.joined_in)
        # no clock message in time, or missed (a world that names no goal set): take up all that was heard
        upto = self.named.get(tick, max(self.unnamed, default=0))
        # the coordinator sends a step's set once it hears the step's first tick, so that tick cannot name it: every
        # host takes it up there. A later tick names what the others took up; a host back from a stall that missed
        # the step's set must not take a later one of the step there (named by a tick to come: the hosts would part)
        if due >= 0 and stamp < host.config.steps[due] + host.params.dt - 1e-9:
            of_step = [e for e, g in {**host.goal_sets.by_epoch, **self.unnamed}.items() if g.timing.step >= due]
            upto = max(upto, min(of_step, default=0))
        self.named = {t: e for t, e in self.named.items() if t > tick}
        for epoch in sorted(e for e in self.unnamed if e <= upto):
            host.on_goals(self.unnamed.pop(epoch))

    def _missed(self, tick: int) -> bool:
        """This tick's clock message will not come. The world sends it before the tick's poses, on the same link
        and in order, so with its pose here it came or went out before our subscription took hold (a
        subscription declared after another may take hold a few ticks later). Under injected clock faults,
        once a later tick's came."""
        return self.ticks.fault is None or any(t > tick for t in self.named)

    def on_clock(self, clock: Tick) -> str | None:
        """A clock message names the goal set of its tick; its tick bounds the poses' (it may not skip ahead). Two
        of one tick naming different goal sets (one forged): the older is waited for, which the world has heard."""
        why = super().on_clock(clock)
        if why == STALE and clock.tick in self.named:
            self.named[clock.tick] = min(self.named[clock.tick], clock.goal_epoch)
        if why is None:
            self.named[clock.tick] = clock.goal_epoch
        return why


def _at_most(tick: int, bound: int) -> int:
    """A tick claimed beyond ``bound`` counts as none (-1)."""
    return tick if tick <= bound else -1
