"""Entry point of an agent process: `python -m agent --config host.json [zenoh flags]` (`--config -`: stdin).
With PIXELSWARM_PROFILE=DIR the host's loop runs under cProfile into DIR/agent<first robot>.prof."""

from __future__ import annotations

import getopt
import math
import os
import sys
from collections.abc import Callable

from . import ONE_BLAS_THREAD

os.environ.setdefault(*ONE_BLAS_THREAD)  # before numpy loads: a robot's computer may start this module itself

from transport import session
from transport.bus import Bus
from transport.faults import parse_faults
from transport.session import ZENOH_LONG, ZENOH_SHORT, TransportError, one_malloc_arena, zenoh_usage

from .runtime import AgentHost, HostConfig, install_stop_handlers

START_TIMEOUT = 60.0  # s to wait for the robots' poses by default (`pixelswarm run` says how long)
USAGE = f"""usage: python -m agent --config FILE [--faults PLAN] [--start-timeout S] [--exit-with-parent] [zenoh flags]

Run robot agents: the robots its host config names, one by default.

options:
  -h, --help            show this help message and exit
  --config FILE         host config JSON file (robots, parameters, map); - reads it from stdin
  --faults PLAN         fault injection, e.g. 'state:drop=0.1,delay=0.05'
  --start-timeout SECONDS
                        how long to wait for the robots' poses (default {START_TIMEOUT:g} s)
  --exit-with-parent    stop when the parent process exits

""" + zenoh_usage()
# getopt, not argparse, and os.path, not pathlib: the modules they load would stay in every robot's process
OPTIONS = ["help", "config=", "faults=", "start-timeout=", "exit-with-parent", *ZENOH_LONG]


def main(argv: list[str] | None = None) -> int:
    try:
        options, extra = getopt.getopt(sys.argv[1:] if argv is None else argv, "h" + ZENOH_SHORT, OPTIONS)
        if extra:
            raise getopt.GetoptError(f"unrecognized arguments: {' '.join(extra)}")
        flags = dict(options)  # a repeated flag: its last value
        if "-h" in flags or "--help" in flags:
            print(USAGE)
            return 0
        if "--config" not in flags:
            raise getopt.GetoptError("the following arguments are required: --config")
        start_timeout = _seconds(flags.get("--start-timeout"), START_TIMEOUT)
    except getopt.GetoptError as err:
        print(f"{USAGE.splitlines()[0]}\npython -m agent: error: {err}", file=sys.stderr)
        return 2
    try:
        if flags["--config"] == "-":
            config = HostConfig.from_json(sys.stdin.read())
        else:
            with open(flags["--config"]) as f:
                config = HostConfig.from_json(f.read())
    except (OSError, ValueError, KeyError) as err:
        print(f"agent: error: bad config: {err}", file=sys.stderr)
        return 2
    try:
        faults = parse_faults(flags.get("--faults", ""))
    except ValueError as err:
        print(f"agent: error: --faults: {err}", file=sys.stderr)
        return 2
    if len(config.robots) == 1:
        one_malloc_arena()  # before zenoh's threads start
    try:
        settings, name = session.settings_from_options(options), f"agent{config.robots[0]}"
        bus = Bus(
            settings, config.display, faults=faults, seed=config.seed, name=name, hears_itself=config.hears_itself
        )
    except TransportError as err:
        print(f"agent: error: {err}", file=sys.stderr)
        return 2
    with bus:
        return _run_host(bus, config, start_timeout, "--exit-with-parent" in flags)


def _run_host(bus: Bus, config: HostConfig, start_timeout: float, exit_with_parent: bool) -> int:
    """Start the robots' host (exit code 1 without their poses), run its loop, then report its statistics."""
    host = AgentHost(bus, config)
    install_stop_handlers(host)
    parent = os.getppid() if exit_with_parent else None  # exit when the launcher is gone
    if not host.start(timeout=start_timeout):
        if host.running:  # not stopped meanwhile: the poses never came
            print(
                f"agent: error: no pose arrived for my robots within {start_timeout:g} s; is the tracker running?",
                file=sys.stderr,
            )
        return 1
    if profile_to := os.environ.get("PIXELSWARM_PROFILE"):
        run_profiled(lambda: host.run(parent), os.path.join(profile_to, f"agent{config.robots[0]}.prof"))
    else:
        host.run(parent)
    host.report()
    bus.linger()
    return 0


def _seconds(text: str | None, default: float) -> float:
    """A flag's positive, finite number of seconds (its default when absent)."""
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise getopt.GetoptError(f"--start-timeout must be a positive number of seconds, not {text!r}")
    return value


def run_profiled(run: Callable[[], None], path: str) -> None:
    """Run under cProfile (this thread only) and write the statistics to ``path`` even if ``run`` raises."""
    import cProfile  # here: only a profiled run pays for it

    profile = cProfile.Profile()
    profile.enable()
    try:
        run()
    finally:
        profile.disable()
        os.makedirs(os.path.dirname(path), exist_ok=True)
        profile.dump_stats(path)


if __name__ == "__main__":
    sys.exit(main())
