"""`pixelswarm agents --connect ENDPOINT [--robots IDS] [-k K]`: agent processes for a run going elsewhere.

The run (`pixelswarm run ... --remote-agents`) serves each agent robot's host configuration on the bus; this
command fetches them, joins them K robots to a process and passes each on stdin (no shared file system)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

from agent.runtime import HostConfig, interpreter
from sim.args import add_seconds, check_endpoint, format_ids, parse_ids, positive_int, refuse_if, usage_errors
from sim.processes import handling_signals, start_session, stop_processes
from transport.bus import Bus, LivelinessWatch
from transport.keys import Keys
from transport.session import ZenohSettings

# `pixelswarm --help` and `pixelswarm agents --help`
HELP = "start agent processes that join a run going elsewhere (`pixelswarm run --remote-agents`)"
ABOUT = (
    "Start agent processes for robots of a run started with `pixelswarm run SCENE "
    "--listen ENDPOINT --remote-agents`; each robot's configuration comes from the run over the bus."
)

PROG = "pixelswarm agents"
RUN_TIMEOUT = 60.0  # s to wait for a run to be there
QUERY_TIMEOUT = 5.0  # s for the run to answer a configuration query
STOP_GRACE = 5.0  # s an agent has to stop after SIGTERM before it is killed


# --- what the run serves ---------------------------------------------------------------------------
def encode_remote_config(config: HostConfig, faults: str) -> bytes:
    """A robot's host configuration and the run's fault plan, as the run answers a config query."""
    return json.dumps({"host": json.loads(config.to_json()), "faults": faults}).encode()


# the run's answer for a robot whose agent is alive: a second one would make it stand (two commands a tick)
TAKEN = json.dumps({"taken": True}).encode()


def merge_configs(configs: list[HostConfig]) -> HostConfig:
    """One host for several robots' configurations: their robots and pursuits together, and the
    greetings of robots of other hosts only; the rest is the run's, the same in each."""
    robots = sorted(r for c in configs for r in c.robots)
    return dataclasses.replace(
        configs[0],
        robots=robots,
        pursue={r: t for c in configs for r, t in c.pursue.items()},
        greet=sorted({g for c in configs for g in c.greet} - set(robots)),
    )


def fetch_configs(bus: Bus, robots: list[int] | None) -> tuple[dict[int, tuple[HostConfig, str]], list[int]]:
    """The configurations the run serves for ``robots`` (None: every agent robot of the run), and the robots
    whose agents are alive already (TAKEN). One query per named robot, all in flight at once: the run counts
    a robot as claimed when asked."""
    keys = [bus.keys.config("*")] if robots is None else [bus.keys.config(r) for r in robots]
    found: dict[int, tuple[HostConfig, str]] = {}
    taken: list[int] = []
    for key, payload in bus.query_raw(keys, QUERY_TIMEOUT):
        if (robot := Keys.last_id(key)) is not None:
            data = json.loads(payload)  # as encode_remote_config wrote it
            if data.get("taken"):
                taken.append(robot)
            else:
                found[robot] = HostConfig.from_json(json.dumps(data["host"])), str(data.get("faults", ""))
    return found, sorted(taken)


# --- the command -----------------------------------------------------------------------------------
def add_agents_parser(subparsers: Any) -> None:
    """Add the `agents` subcommand to an argparse subparsers object (sets func=run_agents)."""
    p = subparsers.add_parser("agents", help=HELP, description=ABOUT)
    p.add_argument(
        "--connect",
        "-e",
        required=True,
        metavar="ENDPOINT",
        help="the run's router, or a router joined to it, e.g. tcp/192.168.1.10:7447",
    )
    p.add_argument("--robots", metavar="IDS", help="robot ids, e.g. 0-3,7 (default: every agent robot of the run)")
    p.add_argument(
        "--agents-per-process", "-k", type=positive_int, default=1, metavar="K", help="robots per agent process"
    )
    p.add_argument("--display", default="default", help="the run's display name (key prefix)")
    add_seconds(p, "--timeout", RUN_TIMEOUT, "how long to wait for the run to be there")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress output")
    p.set_defaults(func=run_agents)


def run_agents(args: argparse.Namespace) -> int:
    """The command; bad input is a UsageError, which `pixelswarm` says as one line (exit code 2)."""
    with usage_errors(ValueError):
        robots = parse_ids(args.robots) if args.robots is not None else None
        Keys(args.display)
    settings = ZenohSettings(mode="client", connect=[args.connect])
    check_endpoint(settings, args.connect)
    say = (lambda text: None) if args.quiet else (lambda text: print(f"{PROG}: {text}", file=sys.stderr, flush=True))
    with Bus(settings, args.display, name="agents") as bus:  # a TransportError: main says it as one line
        runs, worlds = bus.watch_alive("run"), bus.watch_alive("world")
        if not _wait_for_run(runs, args.timeout):
            print(
                f"{PROG}: error: no run (display {args.display}) came on {args.connect} within {args.timeout:g} s; "
                "start one with `pixelswarm run SCENE --listen ENDPOINT --remote-agents`",
                file=sys.stderr,
            )
            return 1
        configs, taken = fetch_configs(bus, robots)
        unknown = [r for r in robots or [] if r not in configs and r not in taken]
        where = f"the run on {args.connect} (display {args.display})"
        refuse_if(unknown, f"robots {format_ids(unknown)} are not agent robots of {where}")
        # a second agent for a robot would make the world stop it: every tick it hears two commands
        refuse_if(
            taken and (robots is not None or not configs),
            f"robots {format_ids(taken)} of {where} have agents alive already; stop those first",
        )
        if taken:
            say(f"robots {format_ids(taken)} have agents alive already: starting those of the others")
        hosts = _hosts(configs, args.agents_per_process)
        supervisor = Supervisor(settings)
        with supervisor.forwarding_signals():
            for config, faults in hosts:
                supervisor.start(config, faults)
            say(f"{len(hosts)} agent processes started for robots {format_ids(sorted(configs))} of the run")
            code = supervisor.watch(bus, runs, worlds)
        say("the run ended; agents stopped" if code == 0 else f"agents stopped (exit code {code})")
        return code


def _wait_for_run(runs: LivelinessWatch, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(alive for _, _, alive, _, _ in runs.drain()):
            return True
        time.sleep(0.05)
    return False


def _hosts(configs: dict[int, tuple[HostConfig, str]], k: int) -> list[tuple[HostConfig, str]]:
    """The robots in id order, K to a host."""
    ids = sorted(configs)
    groups = [ids[h * k : (h + 1) * k] for h in range(math.ceil(len(ids) / k))]
    return [(merge_configs([configs[r][0] for r in group]), configs[group[0]][1]) for group in groups]


class Supervisor:
    """The agent processes this command started: started with their config on stdin, stopped
    together, and reported when one exits on its own."""

    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self.procs: list[tuple[subprocess.Popen, list[int]]] = []
        self.stop_signal: int | None = None

    def start(self, config: HostConfig, faults: str) -> None:
        cmd = [*interpreter(len(config.robots)), "-m", "agent", "--config", "-", "--exit-with-parent"]
        cmd += ["--faults", faults] if faults else []
        proc = start_session(cmd + self.settings.to_args(), stdin=subprocess.PIPE, cwd=os.getcwd())
        assert proc.stdin is not None
        proc.stdin.write(config.to_json().encode())
        proc.stdin.close()
        self.procs.append((proc, config.robots))

    @contextlib.contextmanager
    def forwarding_signals(self) -> Iterator[None]:
        """SIGINT and SIGTERM stop the agents (see watch); on the way out, none is left running."""
        with handling_signals(self._on_signal):
            try:
                yield
            finally:
                self.stop()

    def _on_signal(self, signum: int, frame: object) -> None:
        self.stop_signal = signum

    def watch(self, bus: Bus, runs: LivelinessWatch, worlds: LivelinessWatch) -> int:
        """Until every agent has exited: stop them all once the run's world has ended (or the run is
        gone, or a signal came). 0 when the run ended them, 128 + signal, or 1 if one failed."""
        world_seen, over = False, False
        reported: set[int] = set()  # agents that exited on their own with an error
        while any(p.poll() is None for p, _ in self.procs):
            bus.renew_if_due()  # its link to the router came back a while ago
            over = over or any(not alive for _, _, alive, _, _ in runs.drain())
            for _, _, alive, _, _ in worlds.drain():
                world_seen |= alive
                over = over or (world_seen and not alive)
            if over or self.stop_signal is not None:
                self.stop()
                break
            for proc, robots in self.procs:
                if proc.poll() not in (None, 0) and proc.pid not in reported:
                    reported.add(proc.pid)
                    print(
                        f"{PROG}: agent process {proc.pid} (robots {format_ids(robots)}) exited with code "
                        f"{proc.returncode}; its robots stay in the world, stopped",
                        file=sys.stderr,
                        flush=True,
                    )
            time.sleep(0.05)
        if self.stop_signal is not None:
            return 128 + self.stop_signal
        return 1 if reported else 0

    def stop(self) -> None:
        """SIGTERM to every agent still running; those not gone within the grace are killed."""
        stop_processes([proc for proc, _ in self.procs], STOP_GRACE)
