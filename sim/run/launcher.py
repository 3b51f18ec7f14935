"""The launcher: embeds a router, starts coordinator, world and agent processes, records the run.

Children run in their own process group (a terminal's Ctrl-C reaches only the launcher, which then
stops them in order) and exit by themselves if the launcher disappears."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from agent.core.params import HOLONOMIC, RobotParams
from agent.runtime import HostConfig, interpreter
from coordinator.resolved import save_resolved
from coordinator.scene import Scene, count_due, events_of, take_due
from sim.args import AGENTS_TIMEOUT, STARTUP_TIMEOUT, UsageError, format_ids
from sim.node.body import TWO_WAYS
from sim.node.hardware import ERROR as HARDWARE_ERROR
from sim.outputs.metrics import Traffic, lockstep_waits_given_up, reported
from sim.outputs.recorder import Recorder
from sim.outputs.rundir import RunDir
from sim.outputs.ticklog import TICKS_FILE
from sim.outputs.write import RunOutcome, write_run
from sim.processes import handling_signals, start_session, stop_processes
from sim.run.remote_agents import TAKEN, encode_remote_config
from transport.bus import Bus
from transport.codec import Event
from transport.faults import FaultPlan, format_faults
from transport.keys import robots_of_ident
from transport.security import client_config, robot_role, router_config
from transport.session import ZenohSettings, client_of, free_port, loopback_router

RESTARTS = 5  # times the launcher restarts a central service that died (beyond: the run goes on without it)
# the services it restarts; the simulated world is also the tracker: its death ends the run
RESTARTED = ("coordinator",)


def progress_line(scene: str, t: float, at_goal: int, with_goal: int, min_clearance: float, contacts: int) -> str:
    """The once-a-second progress line; before any robot has a goal it says so, not ``at goal 0/0``."""
    goals = f"at goal {at_goal}/{with_goal}" if with_goal else "waiting for the goal set"
    return f"[{scene}] t={t:6.1f} s  {goals}  min clearance {min_clearance:+.3f} m  contacts {contacts}"


@dataclass
class RunOptions:
    """How `pixelswarm run` runs a scene: one attribute per run flag (--out, --no-video, -k, --connect ...)."""

    out: Path
    video: bool = True
    plots: bool = True  # clearance.png and trajectories.png
    agents_per_process: int = 1
    display: str = "default"
    router: ZenohSettings | None = None  # None: embed one on a free loopback port
    connect: list[str] = field(default_factory=list)  # an external router to join instead of embedding
    faults: FaultPlan = field(default_factory=dict)
    agent_routers: list[str] = field(default_factory=list)  # spread agents over these routers (round robin)
    deadline: float = Scene.deadline
    progress: TextIO | None = sys.stderr
    startup_timeout: float = STARTUP_TIMEOUT
    secure: Path | None = None  # a folder from `pixelswarm certs`: each process joins as its role (docs/security.md)
    hardware: Path | None = None  # a hardware file: real robots (sim/node/hardware.py) in place of the world
    remote_agents: bool = False  # spawn no agents: serve their configs, `pixelswarm agents` starts them elsewhere
    agents_timeout: float = AGENTS_TIMEOUT
    reach: float = math.inf  # communication range (m): robots hear states and the auction only this close
    foxglove: int | None = None  # serve the log live over Foxglove's WebSocket protocol on 127.0.0.1:PORT (0: free)
    # sim.outputs.view.SwarmView: the recorder logs the world's truth to it at every tick (agents never do)
    view: Any = None


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    robots: list[int]
    log: Path
    command: list[str] = field(default_factory=list)  # module and arguments, to start it again
    client: ZenohSettings | None = None
    reported: bool = False  # its exit was seen (a crash said once, or a kill on purpose)


class Interrupted(Exception):
    """A second stop signal, or one before the run started: nothing is written."""


def _robots(ids: list[int]) -> str:
    """'robot 3' or 'robots 0-2, 5', for messages."""
    return f"robot{'s' if len(ids) > 1 else ''} {format_ids(ids)}"


def _agents_reported(agent_stats: list[dict[str, Any]], world: dict[str, Any], lockstep: bool) -> dict[str, Any]:
    """The agents' counts for metrics.json; a lock-step run whose waits ran out says so in a line."""
    given_up = lockstep_waits_given_up(agent_stats, world)
    ran_out = {"missed_ticks": reported(world, "missed_ticks"), **given_up}
    if lockstep and any(ran_out.values()):
        _warn(
            f"pixelswarm: lock-step waits ran out ({', '.join(f'{k} {v}' for k, v in ran_out.items() if v)}): "
            "this run may differ from another run of its seed (a process stalled, or the machine was overloaded)"
        )
    return {
        **{k: sum(reported(s, k) for s in agent_stats) for k in ("poses_held", "subscriptions_renewed")},
        "orca_fallbacks": sum(reported(s, "fallbacks") for s in agent_stats),
        "lockstep_waits_given_up": given_up,
        "deadlock_penalties": sum(reported(s.get("auction"), "deadlock_penalties") for s in agent_stats),
    }


def _warn(text: str) -> None:
    """A line on stderr even with --quiet: what befalls the run's processes is not progress."""
    print(text, file=sys.stderr, flush=True)


def _agent_stats(rec: Recorder) -> list[dict[str, Any]]:
    """The agents' statistics events whose fields have their types (anyone may publish an event on an open bus)."""
    return [
        e
        for e in rec.happened.events
        if e.get("kind") == "stats"
        and e.get("role") == "agent"
        and isinstance(e.get("robots"), list)
        and all(type(r) is int for r in e["robots"])
        and isinstance(e.get("dropped") or {}, dict)
        and all(type(k) is int for k in (e.get("dropped") or {}).values())
    ]


def _last_said(log: Path, prefix: str) -> str | None:
    """The rest of the last line of a child's log that starts with ``prefix`` (None: none, or no log)."""
    lines = log.read_text().splitlines() if log.exists() else []
    return next((ln.removeprefix(prefix) for ln in reversed(lines) if ln.startswith(prefix)), None)


def _agents(liveliness: list[dict], alive: bool) -> list[int]:
    """The robots whose agent's liveliness began (``alive``) or ended, of these liveliness events (the recorder's)."""
    return sorted(
        {int(e["id"]) for e in liveliness if e["role"] == "agent" and e["alive"] == alive and str(e["id"]).isdigit()}
    )


def _in_use(alive: list[tuple[str, str]]) -> str:
    """What another run has alive on a display, and how to go on."""
    roles = [role for role, _ in alive]
    robots = sum(len(robots_of_ident(ident) or []) for role, ident in alive if role == "agent")
    what: list[str] = [role for role in ("run", "world", "coordinator") if role in roles]
    what += [f"agents of {robots} robots"] if robots else []
    return f"another swarm is live on it ({', '.join(what) or 'its processes'}); end that run or pass --display NAME"


def _last_line(log: Path) -> str:
    """A child's last words: the last line of its log (which goes with a run directory a failed start removes)."""
    lines = [ln.strip() for ln in (log.read_text(errors="replace").splitlines() if log.exists() else []) if ln.strip()]
    return lines[-1][-300:] if lines else "its log is empty"


@dataclass
class WorldOutcome:
    """What became of the world process: its exit code, its final report's statistics, whether it died mid-run."""

    exit_code: int | None = None
    stats: dict[str, Any] = field(default_factory=dict)
    died: bool = False


@dataclass
class Incidents:
    """What befell the run's processes, for metrics.json: agent processes that crashed, central services
    restarted, agents the scene killed; and the kills the scene has still to come."""

    failures: list[dict[str, Any]]  # the scene's 'fail' events not yet due (take_due takes them off)
    crashes: list[dict[str, Any]] = field(default_factory=list)
    restarts: list[dict[str, Any]] = field(default_factory=list)
    killed: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class RunEnd:
    """How the run ended, which the CLI reads: by a stop signal, by a start-up that failed, or by itself."""

    stop_signal: int | None = None  # the first stop signal received
    startup_failure: str | None = None  # why the run ended before it started (_await_agents)
    interrupted: bool = False  # a stop signal ended the run (written marked incomplete)
    shutdown_wall: float = math.inf  # when the launcher first stopped its children (wall clock)


class Launcher:
    """Runs a scene's processes (router, coordinator, agents, world) and records the run; the CLI reads
    the run's end from ``end``."""

    def __init__(self, scene: Scene, options: RunOptions) -> None:
        self.scene, self.opt = scene, options
        self.params = RobotParams.from_dict(scene.robot)
        self.children: list[Child] = []
        self.world = WorldOutcome()
        self.incidents = Incidents(events_of(scene, "fail"))
        self.end = RunEnd()
        self.run_dir = RunDir(options.out)
        self._last_say = 0.0  # when progress was last said (monotonic)
        self._liveliness_seen = 0  # remote agents: the liveliness events looked at for departures
        self._events_seen = 0  # the run's events looked at for robots commanded two ways

    # --- processes ----------------------------------------------------------------------------
    def _spawn(
        self, name: str, module: str, args: list[str], robots: list[int], client: ZenohSettings | None = None
    ) -> Child:
        log = self.run_dir / "logs" / f"{name}.log"
        log.parent.mkdir(exist_ok=True)
        zenoh_args = (client or self.client).to_args()
        with open(log, "a") as fh:  # a restarted service goes on in its log
            python = interpreter(len(robots)) if module == "agent" else [sys.executable]
            proc = start_session(
                [*python, "-m", module, *args, "--exit-with-parent", *zenoh_args],
                stdout=fh,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                cwd=os.getcwd(),
            )
        child = Child(name, proc, robots, log, [module, *args], client)
        self.children.append(child)
        return child

    def _restart(self, child: Child, code: int, recorder: Recorder) -> None:
        """A central service died mid-run: start it again (it learns where the show is from the bus)."""
        done = [r for r in self.incidents.restarts if r["process"] == child.name]
        if len(done) >= RESTARTS or self.end.stop_signal is not None:
            return
        module, *args = child.command
        again = self._spawn(child.name, module, args, child.robots, child.client)
        self.incidents.restarts.append(
            {"process": child.name, "returncode": code, "pid": again.proc.pid, "sim_time_s": recorder.sim_time}
        )
        _warn(
            f"pixelswarm: {child.name} (pid {child.proc.pid}) exited with code {code}; restarted (pid {again.proc.pid})"
        )

    def _scene_args(self) -> list[str]:
        """The children read the scene and its goal sets from the run directory (saved once, here)."""
        return ["--run-dir", str(self.run_dir.path), "--display", self.opt.display]

    @property
    def _agent_robots(self) -> list[int]:
        """The robots an agent drives (scripted movers have none)."""
        return [i for i in range(self.scene.robots) if i not in self.scene.scripted]

    def _host_config(self, robots: list[int]) -> HostConfig:
        lockstep = self.scene.clock == "lockstep"
        return HostConfig(
            robots=robots,
            params=self.params,
            display=self.opt.display,
            seed=self.scene.seed,
            arena=self.scene.arena,
            obstacles=self.scene.obstacles,
            lockstep=lockstep,
            greet=self._near_at_start(robots, self._agent_robots) if lockstep else [],
            pursue={r: t for r, t in self.scene.pursuers.items() if r in robots},
            frames=self._frames,
            steps=list(self.scene.step_starts) if lockstep else [],
            reach=self.opt.reach,
            swarm=len(self._agent_robots),
        )

    def _start_agents(self) -> None:
        k = max(1, self.opt.agents_per_process)
        ids = self._agent_robots
        cfg_dir = self.run_dir / "config"
        cfg_dir.mkdir(exist_ok=True)
        # an agent gives up on its poses no sooner than the launcher gives up on it (_await_agents)
        extra = ["--start-timeout", str(self.opt.startup_timeout)]
        extra += ["--faults", format_faults(self.opt.faults)] if self.opt.faults else []
        routers = self.opt.agent_routers
        for h in range(math.ceil(len(ids) / k)):
            robots = ids[h * k : (h + 1) * k]
            path = cfg_dir / f"agents-{h:04d}.json"
            path.write_text(self._host_config(robots).to_json())
            router = [routers[h % len(routers)]] if routers else []
            client = ZenohSettings(mode="client", connect=router) if router else self._as(robot_role(robots[0]))
            self._spawn(f"agent-{h:04d}", "agent", ["--config", str(path), *extra], robots, client)

    # --- remote agents (`pixelswarm agents` on other machines) -----------------------------------
    def _serve_configs(self, bus: Bus, rec: Recorder) -> None:
        """Serve each agent robot's host config (as for a robot alone in its process) for `pixelswarm agents`,
        TAKEN for one whose agent is alive; the 'run' token tells those agents when the run is over."""
        self.fetched: set[int] = set()  # robots whose config was asked for (zenoh's threads add to it)
        faults = format_faults(self.opt.faults)
        for r in self._agent_robots:
            key, payload = bus.keys.config(r), encode_remote_config(self._host_config([r]), faults)

            def answer(r: int = r, key: str = key, payload: bytes = payload) -> list[tuple[str, bytes]]:
                if rec.progress.agent_alive[r]:
                    return [(key, TAKEN)]
                self.fetched.add(r)
                return [(key, payload)]

            bus.serve(key, answer)
        bus.declare_alive("run", 0)

    def _await_remote(self, rec: Recorder, stage: str, since: float) -> None:
        """Wait until every agent robot's config was fetched (stage 'fetched': the world starts only
        then, as its own wait for agents is bounded) or its agent is alive (stage 'alive')."""
        ids = self._agent_robots
        endpoint = ", ".join((self.opt.router.listen if self.opt.router else []) or self.client.connect)
        what = "configurations fetched" if stage == "fetched" else "agents alive"
        for waited in self._polling(rec, since):
            done = set(self.fetched) if stage == "fetched" else {i for i in ids if rec.progress.agent_alive[i]}
            missing = [i for i in ids if i not in done]
            if not missing:
                return
            if self._world_gone:
                world_log = self.run_dir / "logs" / "world.log"
                raise RuntimeError(f"the world process exited while waiting for agents: {_last_line(world_log)}")
            if waited > self.opt.agents_timeout:
                # remote agents that did not come, or came and left: one line naming their robots
                left = [i for i in _agents(rec.happened.liveliness, alive=False) if not rec.progress.agent_alive[i]]
                absent = sorted(set(missing) | set(left))
                raise UsageError(
                    f"no agent came for robots {format_ids(absent)} within {self.opt.agents_timeout:g} s "
                    f"(start them with `pixelswarm agents --connect {endpoint}`)"
                )
            self._say(f"[{self.scene.name}] waiting for agents: {len(ids) - len(missing)}/{len(ids)} robots' {what}")

    def _polling(self, rec: Recorder, since: float | None = None, pause: float = 0.05) -> Iterator[float]:
        """The start-up waits' loop: poll the bus every ``pause`` s, yielding the seconds since ``since``
        (default: now); a stop signal raises Interrupted, unless the wait has returned first."""
        since = time.monotonic() if since is None else since
        while True:
            rec.poll()
            yield time.monotonic() - since
            if self.end.stop_signal is not None:
                raise Interrupted()
            time.sleep(pause)

    @property
    def _world_gone(self) -> bool:
        return any(c.name == "world" and c.proc.poll() is not None for c in self.children)

    def _under_way(self, rec: Recorder) -> bool:
        """Started and not ending: no stop said, no end recorded, no final report from the world."""
        ending = (self.end.startup_failure, self.end.stop_signal, rec.progress.ended_at)
        reported = any(e.get("kind") == "world-done" for e in rec.happened.events)
        return all(said is None for said in ending) and not reported

    def _crashed_world(self) -> Child | None:
        """The world process, if it exited with an error code."""
        return next((c for c in self.children if c.name == "world" and c.proc.poll() not in (None, 0)), None)

    @property
    def _frames(self) -> bool:
        """Agent hosts of several robots trade one pose frame of every robot and one command frame a
        tick with the world; a robot alone in its process keeps its own keys, as on hardware."""
        return self.opt.agents_per_process > 1

    def _near_at_start(self, robots: list[int], agents: list[int]) -> list[int]:
        """The agent robots whose state may reach ``robots`` at the first ticks (within state reach at
        the start): a lock-step host hears their hellos before it says it is alive (AgentHost.start)."""
        xy = np.asarray(self.scene.poses, float)[:, :2]
        own, mine = xy[robots], set(robots)
        return [j for j in agents if j not in mine and np.min(np.hypot(*(own - xy[j]).T)) <= self.params.state_reach]

    def _check_children(self, recorder: Recorder) -> None:
        if self.opt.remote_agents:  # no process of ours: their liveliness says when they leave
            events = recorder.happened.liveliness[self._liveliness_seen :]
            self._liveliness_seen += len(events)
            if (gone := _agents(events, alive=False)) and self._under_way(recorder):
                _warn(
                    f"pixelswarm: the agents of robots {format_ids(gone)} left the run; their robots stay in the world, stopped"
                )
        for child in self.children:
            code = child.proc.poll()
            if code is None or child.reported:
                continue
            child.reported = True
            if child.name.startswith("agent"):
                crash = {"process": child.name, "pid": child.proc.pid, "robots": child.robots, "returncode": code}
                self.incidents.crashes.append(
                    crash | {"sim_time_s": recorder.sim_time, "noticed_wall_time": time.time()}
                )
                if self.end.startup_failure is None:  # at start-up, startup_failure names it
                    _warn(
                        f"pixelswarm: agent process {child.name} (pid {child.proc.pid}, robots {child.robots}) "
                        f"exited with code {code}; its robots stay in the world, stopped"
                    )
            elif child.name == "world":
                self.world.exit_code = code
            elif child.name in RESTARTED:
                self._restart(child, code, recorder)

    def _stop_children(self) -> None:
        self.end.shutdown_wall = min(time.time(), self.end.shutdown_wall)
        stop_processes([child.proc for child in self.children], 5.0)

    # --- progress -----------------------------------------------------------------------------
    def _say(self, text: str, force: bool = False) -> None:
        """A progress line, at most one a second unless ``force``."""
        now = time.monotonic()
        if self.opt.progress is not None and (force or now - self._last_say >= 1.0):
            self._last_say = now
            print(text, file=self.opt.progress, flush=True)

    def _progress(self, rec: Recorder) -> None:
        if not rec.traj.t:
            return
        pose = rec.traj.pose[-1]
        err = np.hypot(*(pose[:, :2] - rec.said.goal).T)
        at_goal = int(np.sum(err <= self.params.goal_tolerance))
        with_goal = int(np.sum(np.isfinite(err)))
        self._say(
            progress_line(
                self.scene.name, rec.sim_time, at_goal, with_goal, rec.world.least_clearance, len(rec.happened.contacts)
            )
        )

    # --- the run ------------------------------------------------------------------------------
    def _on_signal(self, signum: int, frame: object) -> None:
        if self.end.stop_signal is not None:
            raise Interrupted()  # a second Ctrl-C: stop writing too
        self.end.stop_signal = signum

    def run(self) -> Path:
        with handling_signals(self._on_signal):
            try:
                return self._run()
            except BaseException:
                self._stop_children()
                self.run_dir.abort()
                raise

    def _run(self) -> Path:
        wall0 = time.time()
        save_resolved(self.scene, self.run_dir.path, robot=self.params.to_dict())  # the children read it
        if self.opt.connect:
            settings = self.client = ZenohSettings(mode="client", connect=list(self.opt.connect))
        else:
            settings = self.opt.router or self._embedded_router()
            self.client = client_of(settings)
        bus = Bus(settings, self.opt.display, name="launcher")
        endpoint = ", ".join(settings.listen or settings.connect)
        try:
            if others := bus.alive_now():  # its processes would take ours for theirs, and ours theirs
                raise UsageError(f"display {self.opt.display!r} at {endpoint} is in use: {_in_use(others)}")
            recorder = self._recorder(bus)
            if self.opt.hardware is not None:  # refused at once (one line) if a robot or its pose is missing
                self._start_hardware(recorder)
            self._say(
                f"[{self.scene.name}] {self.scene.robots} robots, {self.scene.clock} clock, router {endpoint}",
                force=True,
            )
            coord = self._spawn("coordinator", "coordinator.service", self._scene_args(), [], self._as("coordinator"))
            self._wait_alive(recorder, "coordinator", coord)
            if self.opt.remote_agents:
                self._serve_configs(bus, recorder)
                waiting_since = time.monotonic()
                self._await_remote(recorder, "fetched", waiting_since)
            else:
                self._start_agents()
            if self.opt.hardware is None:
                self._spawn("world", "sim.node.world", self._world_args(), [], self._as("world"))
            if self.opt.remote_agents:
                self._await_remote(recorder, "alive", waiting_since)
            self.end.startup_failure = self._await_agents(recorder)
            end_reason = "start-up failed" if self.end.startup_failure else self._loop(bus, recorder)
            self._check_children(recorder)  # an agent that died as the world finished is still a crash
            self._stop_children()
            self._record_the_last_ticks(recorder)
            end_reason = recorder.progress.end_reason(end_reason)
            recorder.out.close()
            (self.run_dir / TICKS_FILE).unlink(missing_ok=True)  # trajectory.npz holds them, and more
        finally:
            bus.close()
        return self._write(recorder, end_reason, time.time() - wall0)

    def _recorder(self, bus: Bus) -> Recorder:
        """The recorder of the world's truth (log.mcap, the ticks file, the live view and Foxglove),
        which also answers a late joiner's question for the newest goal set."""
        files = str(self.run_dir / "log.mcap"), str(self.run_dir / TICKS_FILE)
        recorder = Recorder(bus, self.scene.robots, self.params.goal_tolerance, *files)
        recorder.progress.ends = self._ends_on_convergence
        recorder.out.heading = self.params.kinematics != HOLONOMIC
        recorder.view = self.opt.view
        if self.opt.foxglove is not None and recorder.out.log is not None:
            port = recorder.out.log.serve(self.opt.foxglove)
            _warn(f"[{self.scene.name}] Foxglove live: ws://127.0.0.1:{port}")  # asked for, not progress

        def newest_goals() -> list[tuple[str, bytes]]:
            newest = recorder.sets.newest
            return [] if newest is None else [(bus.keys.run_goals, newest.encode())]

        bus.serve(bus.keys.run_goals, newest_goals)
        return recorder

    def _world_args(self) -> list[str]:
        """The simulated world's command line: the scene, its clock and how long it waits for agents."""
        # the world waits for the agents no shorter than the launcher does (_await_agents)
        startup = self.opt.agents_timeout if self.opt.remote_agents else self.opt.startup_timeout
        args = [*self._scene_args(), "--clock", self.scene.clock, "--duration", str(self.scene.duration)]
        args += ["--deadline", str(self.opt.deadline), "--startup-timeout", str(startup)]
        args += ["--pose-frames"] if self._frames else []
        # faults act where a message is received: commands (cmd:...) at the world
        return args + (["--faults", format_faults(self.opt.faults)] if self.opt.faults else [])

    def _record_the_last_ticks(self, recorder: Recorder) -> None:
        """Wait (bounded) for the agents' final statistics and the world's last ticks still in flight
        (a run that ended on convergence records nothing after its end, so there is nothing to wait for)."""
        last_t = float(self.world.stats.get("ticks", 0)) * self.params.dt
        patience = time.monotonic() + 10.0
        while time.monotonic() < patience:
            recorder.poll()
            ticks_due = recorder.progress.ended_at is None and recorder.sim_time < last_t - 1e-6
            if not (ticks_due or self._stats_missing(recorder)):
                return
            time.sleep(0.05)

    def _await_agents(self, rec: Recorder) -> str | None:
        """Until every agent robot's agent is alive, or a stop signal; else one line naming the robots whose
        agent process exited, or not alive within the start-up timeout or when the world ended."""
        ids = self._agent_robots
        for waited in self._polling(rec):
            alive = _agents(rec.happened.liveliness, alive=True)
            missing = [i for i in ids if i not in alive]
            if not missing or self.end.stop_signal is not None:
                break
            exited = [c for c in self.children if c.name.startswith("agent") and c.proc.poll() is not None]
            gone = sorted({r for c in exited for r in c.robots} & set(missing))
            why = None
            if gone:
                codes = ", ".join(map(str, sorted({c.proc.returncode for c in exited if set(c.robots) & set(gone)})))
                why = f" (the agent process of {_robots(gone)} exited with code {codes})"
            elif (world := self._crashed_world()) is not None:  # the world's failure, not the agents'
                raise RuntimeError(
                    f"the world process exited with code {world.proc.returncode}: {_last_line(world.log)}"
                )
            elif self._world_gone or self._world_done(rec) is not None:
                why = " before the world process ended"
            elif waited > self.opt.startup_timeout:
                why = f" within {self.opt.startup_timeout:g} s (--startup-timeout)"
            if why is not None:
                return f"{_robots(missing)}: no agent came alive{why}; see {self.opt.out / 'logs'}"
            self._say(f"[{self.scene.name}] waiting for {len(missing)}/{len(ids)} agents to come alive")
        return None

    def _stats_missing(self, rec: Recorder) -> bool:
        """Whether statistics are still due from an agent that stopped cleanly (remote agents report
        once their `pixelswarm agents` has seen the world end)."""
        if self.opt.remote_agents:
            expected = set(_agents(rec.happened.liveliness, alive=True))
        else:
            expected = {
                r for c in self.children if c.name.startswith("agent") and c.proc.returncode == 0 for r in c.robots
            }
        reported = {r for e in _agent_stats(rec) for r in e["robots"]}
        return not expected <= reported

    def _start_hardware(self, rec: Recorder) -> None:
        """The hardware node stands in for the world; it is started first, since the agents learn where
        they are from it, and is alive once every robot is reached and tracked."""
        args = self._scene_args() + ["--hardware", str(self.opt.hardware), "--duration", str(self.scene.duration)]
        args += ["--pose-frames"] if self._frames else []
        child = self._spawn("world", "sim.node.hardware", args, [], self._as("world"))
        # its refusal counts once written: the node may take a while to close its robot links
        self._wait_alive(rec, "world", child, refusal=HARDWARE_ERROR)

    def _embedded_router(self) -> ZenohSettings:
        """A router on a free loopback port; in a secured run, with mutual TLS and the folder's rules."""
        if self.opt.secure is None:
            return loopback_router()
        return router_config(self.opt.secure, f"tls/127.0.0.1:{free_port()}")

    def _as(self, role: str) -> ZenohSettings | None:
        """A secured run: the session of a child of this role (None: the run's plain client). The
        launcher's own session, the router's, is outside the rules: it records and ends the run."""
        return None if self.opt.secure is None else client_config(self.opt.secure, role, self.client.connect)

    def _wait_alive(self, rec: Recorder, role: str, child: Child, refusal: str | None = None) -> None:
        """Until a process of ``role`` is alive; RuntimeError if ``child`` exits first or the start-up timeout
        passes, UsageError with the rest of its log's line starting with ``refusal`` once it says one."""
        for waited in self._polling(rec, pause=0.02):
            exited = child.proc.poll() is not None  # before its log is read: its last words are in
            said = None if refusal is None else _last_said(child.log, refusal)
            if said is not None:
                raise UsageError(said)  # e.g. the hardware node refused to start: its one line
            if exited:  # its log goes with the run directory the failed start removes: its last line here
                raise RuntimeError(f"{child.name} exited with code {child.proc.returncode}: {_last_line(child.log)}")
            if self.end.stop_signal is not None:
                raise Interrupted()  # before the run started, even if it came alive: nothing is written
            if any(e["role"] == role and e["alive"] for e in rec.happened.liveliness):
                return
            if waited > self.opt.startup_timeout:
                raise RuntimeError(f"{role} did not come alive within {self.opt.startup_timeout:g} s")

    def _loop(self, bus: Bus, rec: Recorder) -> str:
        end_sent: str | None = None  # the reason of the end event published, if any
        end_at = 0.0  # when it was last published
        while True:
            rec.poll()
            self._check_children(rec)
            done = self._world_done(rec)
            if done is not None:
                self.world.stats = done
                return end_sent or str(done.get("reason", "duration"))
            if self.world.exit_code is not None:
                # the world is the bodies and the tracker: the run ends, written marked incomplete
                self.world.stats, self.world.died = {}, True
                _warn(
                    f"pixelswarm: the world process exited with code {self.world.exit_code} (see logs/world.log); "
                    "the run ends, incomplete"
                )
                return f"world exited with code {self.world.exit_code}"
            if self.end.stop_signal is not None and not end_sent:
                end_sent = "interrupted"
                self.end.interrupted = True
            if not end_sent and rec.progress.ended_at is not None:
                end_sent = "converged"
            if end_sent and time.monotonic() - end_at >= 0.5:
                # Repeated until the world is done: an end published before the world subscribed is lost.
                bus.publish(bus.keys.event, Event({"kind": "end", "reason": end_sent}))
                end_at = time.monotonic()
            self._fail_agents(rec)
            self._commanded_two_ways(rec)
            self._progress(rec)
            time.sleep(0.01)

    def _commanded_two_ways(self, rec: Recorder) -> None:
        """Say each robot the world stopped for two different commands at one tick, as it happens."""
        events = rec.happened.events[self._events_seen :]
        self._events_seen += len(events)
        for e in events:
            robot, t = e.get("robot"), e.get("t")
            # anyone may publish an event on an open bus: a forged one's fields may be anything
            if e.get("kind") == TWO_WAYS and isinstance(robot, int) and isinstance(t, float) and math.isfinite(t):
                _warn(
                    f"pixelswarm: t={t:.1f} s: robot {robot} got two different commands for one tick "
                    "(a second controller on its key): it stands until they agree"
                )

    def _ends_on_convergence(self, since: float, now: float) -> bool:
        """The run ends at the tick where the display has held converged for the scene's hold; with
        image steps, only convergence that began within the last step counts (as sim.central.engine ends)."""
        last_start = self.scene.step_starts[-1] if self.scene.steps else 0.0
        if count_due(self.incidents.failures, now):
            return False  # a robot the scene kills by now is not killed yet: it is not the display for the rest
        return self.scene.ends_on_convergence and since >= last_start - 1e-9 and now - since >= self.scene.converge_hold

    def _fail_agents(self, rec: Recorder) -> None:
        """Scene 'fail' events: SIGKILL the process hosting the robot (a robot that dies, paper 5.1.2).
        The recorder is told at once, so a dead robot on its goal never counts toward convergence."""
        t = rec.sim_time
        for event in take_due(self.incidents.failures, t):
            for child in self.children:
                if child.name.startswith("agent") and event["robot"] in child.robots and child.proc.poll() is None:
                    child.proc.send_signal(signal.SIGKILL)
                    child.reported = True  # killed on purpose, not a crash
                    rec.robots_died(child.robots)
                    self.incidents.killed.append({"robots": child.robots, "sim_time_s": t, "wall_time": time.time()})
                    self._say(
                        f"[{self.scene.name}] t={t:.1f} s: killed agent process {child.name} "
                        f"(robots {child.robots}) as the scene says",
                        force=True,
                    )

    def _world_done(self, rec: Recorder) -> dict | None:
        """The world's final report, once the world process has exited cleanly: as it printed it in its log,
        else as it published it (anyone may publish a report on an open bus, so it ends no run alone)."""
        if self.world.exit_code != 0:
            return None
        log = next((c.log for c in self.children if c.name == "world"), None)
        report = None if log is None else _last_said(log, "WORLD-DONE ")
        if report is not None:
            return json.loads(report)
        end = time.monotonic() + 5.0  # a busy recorder may not have seen it yet
        while time.monotonic() < end:
            rec.poll()
            done = next((e for e in rec.happened.events if e.get("kind") == "world-done"), None)
            if done is not None:
                return done
            time.sleep(0.02)
        return None

    # --- outputs ------------------------------------------------------------------------------
    def _write(self, rec: Recorder, end_reason: str, wall_s: float) -> Path:
        interrupted = self.end.interrupted
        end_reason = "interrupted" if interrupted else end_reason
        started = self.end.startup_failure is None
        arrays = rec.arrays()
        stats = self.world.stats
        agent_stats = _agent_stats(rec)
        dropped: dict[str, int] = dict(rec.tally.drops)
        for s in agent_stats + [stats]:
            for reason, k in (s.get("dropped") or {}).items():
                dropped[reason] = dropped.get(reason, 0) + int(k)
        walls = rec.traj.wall
        stepping_wall = walls[-1] - walls[0] if len(walls) > 1 else 0.0  # start-up excluded
        # lost before the run's last tick recorded: remote agents leave once the world ended, not lost
        until = min(self.end.shutdown_wall, walls[-1] if walls else math.inf)
        lost = [
            e for e in rec.happened.liveliness if e["role"] == "agent" and not e["alive"] and e["wall_time"] < until
        ]
        traffic = Traffic(
            rec.tally.counts, rec.tally.bytes, int(stats.get("missed_ticks", 0)), len(self.incidents.crashes)
        )
        extra = dict(
            agents_failed_by_scene=self.incidents.killed,
            end_reason=end_reason,
            **({} if started else {"startup_failure": self.end.startup_failure}),
            complete=not interrupted and not self.world.died and started,
            engine="distributed",
            agents_per_process=self.opt.agents_per_process,
            # remote agents: the hosts that reported, one stats event each
            agent_processes=len(agent_stats)
            if self.opt.remote_agents
            else sum(c.name.startswith("agent") for c in self.children),
            min_clearance_substep_m=stats.get("min_clearance"),
            commands_applied=int(sum(stats.get("commands_applied", []))),
            commands_sent=rec.tally.commands,
            **{
                k: int(stats.get(k, 0))
                for k in ("late_commands", "expired_commands", "stopped_ticks", "withheld_ticks")
            },
            **{k: stats.get(k, []) for k in ("commanded_two_ways", "missed_ticks_by_robot")},
            **_agents_reported(agent_stats, stats, self.scene.clock == "lockstep"),
            dropped_messages=dropped,
            crashes=self.incidents.crashes,
            restarts=self.incidents.restarts,
            liveliness_lost=[{"robot": e["id"], "wall_time": e["wall_time"]} for e in lost],
            faults=format_faults(self.opt.faults),
            stepping_wall_s=stepping_wall,
            **({"hardware": stats["hardware"]} if "hardware" in stats else {}),
            stepping_realtime_factor=(
                float(arrays["t"][-1] - arrays["t"][0]) / stepping_wall if stepping_wall else None
            ),
        )
        outcome = RunOutcome(wall_s, stats.get("contacts", []), traffic, self.opt.reach, extra)
        video, plots = self.opt.video and not interrupted and started, self.opt.plots and started
        run = (self.run_dir, self.scene, self.params, arrays, outcome)
        return write_run(*run, video=video, plots=plots, progress=self.opt.progress)
