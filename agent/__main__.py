"""Entry point of an agent process: `python -m agent --config host.json [zenoh flags]`.

`--config -` reads the config from stdin: `pixelswarm agents` hands over what it fetched from the
run that way, so a robot's computer needs no file shared with the run.

One process runs the robots its config names (one by default; K with --agents-per-process). With
PIXELSWARM_PROFILE=DIR in its environment (`pixelswarm run` passes its own on), the host's loop runs
under cProfile and its statistics go to DIR/agent<first robot>.prof when it stops (`python -m pstats`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path

from transport.bus import Bus
from transport.faults import parse_faults
from transport.session import TransportError, add_zenoh_args, settings_from_args

from .runtime import AgentHost, HostConfig, install_stop_handlers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m agent", description="Run robot agents (one per robot id).")
    parser.add_argument(
        "--config", required=True, help="host config JSON file (robots, parameters, map); - reads it from stdin"
    )
    parser.add_argument("--exit-with-parent", action="store_true", help="stop when the parent process exits")
    parser.add_argument("--faults", default="", help="fault injection, e.g. 'state:drop=0.1,delay=0.05'")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        if args.config == "-":
            config = HostConfig.from_json(sys.stdin.read())
        else:
            with open(args.config) as f:
                config = HostConfig.from_json(f.read())
        faults = parse_faults(args.faults)
    except (OSError, ValueError, KeyError) as err:
        print(f"agent: error: bad config: {err}", file=sys.stderr)
        return 2
    try:
        bus = Bus(
            settings_from_args(args), config.display, faults=faults, seed=config.seed, name=f"agent{config.robots[0]}"
        )
    except TransportError as err:
        print(f"agent: error: {err}", file=sys.stderr)
        return 2
    with bus:
        host = AgentHost(bus, config)
        install_stop_handlers(host)
        if args.exit_with_parent:
            host.parent_pid = os.getppid()
        if not host.start():
            print("agent: error: no pose arrived for my robots; is the tracker running?", file=sys.stderr)
            return 1
        profile_to = os.environ.get("PIXELSWARM_PROFILE")
        if profile_to:
            run_profiled(host.run, Path(profile_to) / f"agent{config.robots[0]}.prof")
        else:
            host.run()
        host.report()
        bus.linger()
    return 0


def run_profiled(run: Callable[[], None], path: Path) -> None:
    """Run under cProfile (this thread only: zenoh's callbacks are not counted) and write the
    statistics to ``path`` even if ``run`` raises."""
    import cProfile  # here: only a profiled run pays for it

    profile = cProfile.Profile()
    profile.enable()
    try:
        run()
    finally:
        profile.disable()
        path.parent.mkdir(parents=True, exist_ok=True)
        profile.dump_stats(path)


if __name__ == "__main__":
    sys.exit(main())
