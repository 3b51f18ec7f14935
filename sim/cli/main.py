"""The `pixelswarm` command: run a scene, run a router, make goals from an image, list scenes."""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
import time
import tomllib
import typing
from dataclasses import replace
from pathlib import Path
from typing import Any

from agent.core.params import BUS_ROUNDS_PER_TICK, EPUCK, RobotParams
from coordinator.goals_cli import add_goals_parser
from coordinator.scene import (
    CLOCKS,
    ENGINES,
    Scene,
    make_goal_sets,
    parse_scene,
    resolve_scene_path,
    shipped_scenes,
)
from sim.args import (
    AGENTS_TIMEOUT,
    MAX_ROBOTS,
    STARTUP_TIMEOUT,
    OneLineParser,
    UsageError,
    add_seconds,
    display_name,
    format_ids,
    new_directory,
    positive_int,
    refuse,
    refuse_if,
    robot_count,
    usage_errors,
    zenoh_endpoint,
)
from sim.cli.track import add_track_parser
from sim.outputs.rundir import PARTIAL_SUFFIX, default_run_path
from sim.processes import stopped_by_signals
from sim.run.remote_agents import add_agents_parser
from sim.study.runner import add_study_parser
from transport.codec import BEFORE_START
from transport.faults import parse_faults
from transport.security import SecurityError, check_folder, make_certificates, router_config
from transport.session import (
    TransportError,
    ZenohSettings,
    add_zenoh_args,
    listen_endpoints,
    open_session,
    settings_from_args,
)

STARTUP_FAILED = 3  # exit code of a run whose agents did not all come alive (docs/cli.md)
GOALS_SAID_AFTER = 0.5  # s: goal sets that take longer are said on stderr, so a long start-up is not silent
FOXGLOVE_PORT = 8765  # Foxglove's own default for a WebSocket connection
WATCH_TIMEOUT = 60.0  # s `pixelswarm view --connect` waits for a running swarm's first tick


def port_number(text: str) -> int:
    """A TCP port, 0 (a free one) to 65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0 to 65535, not {value}")
    return value


def _add_run_scene(run: argparse.ArgumentParser) -> None:
    """What to show: a scene, a picture or keyframes, and what overrides the scene's own settings."""
    group = run.add_argument_group("the scene")
    group.add_argument(
        "scene",
        help=f"a shipped scene ({', '.join(shipped_scenes())}), a path to a scene .toml, "
        "an image (PNG, JPEG, BMP, TIFF) to display, or a folder of keyframe images "
        "to play as an animation (file-name order)",
    )
    group.add_argument(
        "--robots", "-n", type=robot_count, help=f"number of robots, at most {MAX_ROBOTS} (overrides the scene)"
    )
    group.add_argument("--seed", type=int, help="random seed, a whole number >= 0 (overrides the scene)")
    group.add_argument("--clock", choices=CLOCKS, help="clock (overrides the scene)")
    group.add_argument("--duration", type=float, help="seconds of display time at most (overrides the scene)")


def _add_run_engine(run: argparse.ArgumentParser) -> None:
    """How the robots decide and hear each other."""
    group = run.add_argument_group("the engine")
    group.add_argument(
        "--engine",
        choices=ENGINES,
        help="distributed: one process per robot over zenoh (default, unless the scene says "
        'engine = "central"); central: every robot stepped in one call with perfect '
        "information (reference, and fast for large swarms)",
    )
    group.add_argument(
        "--agents-per-process",
        "-k",
        type=positive_int,
        metavar="K",
        help="robots per agent process (default 1: one process per robot, unless the scene "
        "says agents_per_process = K)",
    )
    group.add_argument(
        "--faults",
        default="",
        metavar="PLAN",
        help="fault injection, e.g. 'state:drop=0.1,delay=0.05,jitter=0.01' (';' between kinds)",
    )
    group.add_argument(
        "--range",
        dest="reach",
        type=float,
        metavar="R",
        help="communication range in metres: a robot hears the states and auction words only of robots "
        "within R (lock-step only; default: everyone hears everyone)",
    )
    group.add_argument(
        "--rounds-per-tick",
        type=int,
        metavar="N",
        help="lock-step: at most N auction message rounds a tick, a block of phases spanning ticks "
        "(default: the scene's [robot] rounds_per_tick; if it sets none, 1 for a scene made for agent "
        "processes, 0 for one made for the central engine: every block agreed within its tick)",
    )
    group.add_argument(
        "--deadline",
        type=float,
        help="lock-step: seconds to wait for a late agent's command (default: the scene's, 2 s)",
    )


def _add_run_processes(run: argparse.ArgumentParser) -> None:
    """Where the run's processes are and how they reach each other."""
    group = run.add_argument_group("processes and the bus")
    group.add_argument(
        "--agents-connect",
        action="append",
        default=[],
        type=zenoh_endpoint,
        metavar="ENDPOINT",
        help="spread agent processes over these routers, round robin (repeatable; default: ours)",
    )
    group.add_argument(
        "--display", default="default", type=display_name, help="display name (key prefix), for several swarms"
    )
    group.add_argument(
        "--remote-agents",
        action="store_true",
        help="start no agents: serve each robot's configuration on the bus and wait for `pixelswarm agents "
        "--connect ENDPOINT` to start them (on this machine or others); give the endpoint with --listen",
    )
    group.add_argument(
        "--agents-timeout",
        type=float,
        metavar="SECONDS",
        help=f"--remote-agents: how long to wait for every robot's agent (default {AGENTS_TIMEOUT:g} s)",
    )
    group.add_argument(
        "--startup-timeout",
        type=float,
        default=STARTUP_TIMEOUT,
        metavar="SECONDS",
        help="how long the coordinator, then the agents, have to come alive (default "
        f"{STARTUP_TIMEOUT:g} s); past it the run ends naming the robots still missing (exit code "
        f"{STARTUP_FAILED})",
    )
    group.add_argument(
        "--secure",
        type=Path,
        metavar="DIR",
        help="a secured bus from a folder made by `pixelswarm certs`: mutual TLS, and each process "
        "allowed only its role's keys (docs/security.md); one robot per agent process",
    )
    group.add_argument(
        "--hardware",
        type=Path,
        metavar="FILE",
        help="drive real robots (or emulated ones) named in a hardware file with [backend] and [poses], "
        "on the wall clock; the robot count and start poses come from it (docs/hardware.md)",
    )


def _add_run_outputs(run: argparse.ArgumentParser) -> None:
    """What the run leaves behind and shows while it runs."""
    group = run.add_argument_group("outputs")
    group.add_argument("--out", type=new_directory, help="run directory (default runs/<UTC time>-<scene>)")
    group.add_argument("--no-video", dest="video", action="store_false", help="skip display.mp4")
    group.add_argument("--no-plots", dest="plots", action="store_false", help="skip clearance.png and trajectories.png")
    group.add_argument(
        "--foxglove",
        type=port_number,
        nargs="?",
        const=FOXGLOVE_PORT,
        metavar="PORT",
        help=f"also stream log.mcap's channels live over Foxglove's WebSocket protocol on 127.0.0.1:PORT "
        f"(default {FOXGLOVE_PORT}; 0: a free port), for the Foxglove app; distributed engine",
    )
    group.add_argument(
        "--view",
        nargs="?",
        const="native",
        metavar="native|web|FILE.rrd",
        help="watch the swarm live in Rerun's viewer (pip install 'pixelswarm[view]'): native (the default) "
        "opens its window, web serves its web viewer on 127.0.0.1 and prints the address (kept up after the "
        "run until Ctrl-C), FILE.rrd writes the recording to a file",
    )
    group.add_argument("--quiet", "-q", action="store_true", help="no progress output")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="pixelswarm", description="Image and animation display with robot swarms.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a scene: router, world, tracker, coordinator and one process per robot")
    _add_run_scene(run)
    _add_run_engine(run)
    _add_run_processes(run)
    add_zenoh_args(run, default_mode="router")
    _add_run_outputs(run)
    run.set_defaults(func=cmd_run)

    router = sub.add_parser("router", help="run a standalone zenoh router (for several machines or processes)")
    add_zenoh_args(router, default_mode="router")
    router.set_defaults(func=cmd_router)

    stop = sub.add_parser("stop", help="stop every robot of a hardware file at once (after a run died)")
    stop.add_argument("--hardware", type=Path, metavar="FILE", required=True, help="the hardware file")
    stop.add_argument(
        "-e", "--connect", metavar="ENDPOINT", help="the router robots are reached through (ROS 2: rmw_zenohd)"
    )
    stop.set_defaults(func=cmd_stop)

    _add_view_parser(sub)
    sub.add_parser("scenes", help="list the shipped scenes").set_defaults(func=cmd_scenes)

    add_goals_parser(sub)
    add_agents_parser(sub)
    _add_certs_parser(sub)
    add_track_parser(sub)
    add_study_parser(sub)
    return parser


def _add_view_parser(sub: Any) -> None:
    """`pixelswarm view`: a finished run replayed, or a running swarm watched from its bus (sim.outputs.watch)."""
    view = sub.add_parser(
        "view",
        help="replay a finished run in Rerun's viewer (its trajectory.npz), or watch a running one with --connect "
        "(pip install 'pixelswarm[view]')",
    )
    view.add_argument("run_dir", type=Path, nargs="?", metavar="RUN_DIR", help="a run directory (with trajectory.npz)")
    view.add_argument(
        "--connect",
        "-e",
        metavar="ENDPOINT",
        help="watch a running swarm instead: a read-only subscriber of the run's router (or one joined to it), "
        "e.g. tcp/127.0.0.1:7447",
    )
    view.add_argument("--display", help="with --connect: the run's display name (default: default)")
    view.add_argument(
        "--secure",
        type=Path,
        metavar="DIR",
        help="with --connect: join a secured bus as the observer role of a folder made by `pixelswarm certs`",
    )
    add_seconds(view, "--timeout", WATCH_TIMEOUT, "with --connect: how long to wait for the run's first tick")
    view.add_argument("--quiet", "-q", action="store_true", help="with --connect: no progress lines")
    view.add_argument(
        "--web", action="store_true", help="serve Rerun's web viewer on 127.0.0.1 and print its address (until Ctrl-C)"
    )
    view.add_argument(
        "--save",
        type=Path,
        metavar="FILE.rrd",
        help="only write the recording to FILE.rrd (default: RUN_DIR/view.rrd, written once and then reused)",
    )
    view.set_defaults(func=cmd_view)


def _hardware_scene(args: argparse.Namespace) -> Scene:
    """The scene as a hardware run plays it: the hardware file's robots, on the wall clock (load_run
    refuses --robots and --clock lockstep)."""
    from sim.node.hardware import HardwareError, load_run

    refuse_if(args.engine == "central", "--hardware runs the distributed engine: drop --engine central")
    refuse_if(
        args.secure is not None,
        "--hardware cannot be combined with --secure yet: its pose source joins outside the access rules",
    )
    with usage_errors(HardwareError):  # its ValueErrors: _scene_to_run's
        return load_run(args)[1]


def _make_goal_sets(scene: Scene, progress: typing.TextIO | None) -> Scene:
    """The scene's goal sets; past GOALS_SAID_AFTER, progress hears what is being made and when it is done."""
    if scene.goal_plan is None or progress is None:
        return make_goal_sets(scene)
    images = len(scene.steps)
    what = f"{images} image{'s' * (images != 1)}"
    said = threading.Event()

    def say() -> None:
        said.set()
        line = f"[{scene.name}] {scene.robots} robots: making the goals of {what} (segmentation, CVT)"
        print(line, file=progress, flush=True)

    start = time.monotonic()
    timer = threading.Timer(GOALS_SAID_AFTER, say)
    timer.daemon = True
    timer.start()
    try:
        scene = make_goal_sets(scene)
    finally:
        timer.cancel()
    if said.is_set():
        print(f"[{scene.name}] goals of {what} made in {time.monotonic() - start:.1f} s", file=progress, flush=True)
    return scene


def cmd_run(args: argparse.Namespace) -> int:
    scene = _scene_to_run(args)
    faults, reach = _faults_and_reach(args, scene)
    scene = _with_rounds_per_tick(args, scene, reach)
    with usage_errors(ValueError, prefix=f"{args.scene}: "):
        params = RobotParams.from_dict(scene.robot)
    ticks = scene.duration / params.dt  # each numbered on the bus in 32 bits, BEFORE_START the one number kept
    refuse_if(
        ticks > BEFORE_START - 1,
        f"{args.scene}: {scene.duration:g} s at a control period dt of {params.dt:g} s is {ticks:.3g} ticks, more "
        f"than the bus can number ({BEFORE_START - 1}); shorten the duration or lengthen dt",
    )
    # what a run whose agents join from elsewhere cannot do
    refuse_if(args.agents_timeout is not None and not args.remote_agents, "--agents-timeout goes with --remote-agents")
    if args.remote_agents and (args.secure is not None or args.agents_connect):
        raise UsageError("--remote-agents: the agents join by themselves; drop --secure and --agents-connect")
    refuse_if(
        bool(args.agents_connect) and not (args.connect or args.listen),
        "--agents-connect: the run's own router must reach those routers: join one with -e ENDPOINT "
        "(or listen where they connect with -l)",
    )
    if args.remote_agents and any(e["kind"] == "fail" for e in scene.events):
        raise UsageError("--remote-agents: the scene's fail events kill agent processes, which the run has none of")
    out = args.out or default_run_path(scene.name)
    _check_out(out)
    if args.hardware is None and (args.engine or scene.engine) == "central":
        return _run_central(args, scene, out, faults, reach)
    return _run_agents(args, scene, out, faults, reach)


def _with_rounds_per_tick(args: argparse.Namespace, scene: Scene, reach: float) -> Scene:
    """--rounds-per-tick, or the scene's, written into the scene; a lock-step scene made for agent processes
    that sets none gets BUS_ROUNDS_PER_TICK whichever engine runs it, so every engine runs it the same."""
    rounds = args.rounds_per_tick
    if rounds is None and "rounds_per_tick" not in scene.robot and args.hardware is None:
        bus = scene.engine == "distributed" and scene.clock == "lockstep" and not math.isfinite(reach)
        rounds = BUS_ROUNDS_PER_TICK if bus and scene.assignment == "auction" else None
    return scene if rounds is None else replace(scene, robot={**scene.robot, "rounds_per_tick": rounds})


def _scene_to_run(args: argparse.Namespace) -> Scene:
    """The scene `pixelswarm run` names, with its goal sets, or the hardware file's; UsageError if none."""
    from hardware.config import load_hardware

    # numbers before the scene: a bad flag is the flag's fault, not the scene file's
    refuse_if(args.seed is not None and args.seed < 0, f"--seed must be a whole number >= 0, not {args.seed}")
    for flag in ("--duration", "--deadline", "--agents-timeout", "--startup-timeout"):
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UsageError(f"{flag} must be a positive number of seconds, not {value:g}")
    with usage_errors(ValueError):  # SceneError and hardware.config's HardwareConfigError are ValueErrors
        if args.hardware is not None and load_hardware(args.hardware).backend_kind == "sim":
            args.hardware = None  # the simulated world, as without a hardware file
        if args.hardware is not None:
            return _hardware_scene(args)
        scene = parse_scene(args.scene, robots=args.robots, seed=args.seed, clock=args.clock, duration=args.duration)
        return _make_goal_sets(scene, None if args.quiet else sys.stderr)


def _faults_and_reach(args: argparse.Namespace, scene: Scene) -> tuple[Any, float]:
    """--faults and --range, checked against the scene and each other (and --rounds-per-tick)."""
    with usage_errors(ValueError, prefix="--faults: "):
        faults = parse_faults(args.faults)
    reach = math.inf if args.reach is None else args.reach
    lockstep, limited = scene.clock == "lockstep", math.isfinite(reach)
    refuse_if(not reach > 0, f"--range must be a positive distance in metres, not {args.reach}")
    refuse_if(limited and not lockstep, "--range needs the lock-step clock: its auction runs in rounds of ticks")
    refuse_if(limited and args.hardware is not None, "--range simulates a radio's reach; real robots have their own")
    if args.rounds_per_tick is not None:
        rounds = args.rounds_per_tick
        refuse_if(rounds < 0, f"--rounds-per-tick must be a whole number >= 0, not {rounds}")
        refuse_if(not lockstep, "--rounds-per-tick needs the lock-step clock: real time has no rounds of ticks")
        refuse_if(limited, "--rounds-per-tick is not supported with --range: its auction ends blocks by hops")
    return faults, reach


def _run_central(args: argparse.Namespace, scene: Scene, out: Path, faults: Any, reach: float) -> int:
    """The run with every robot in this process (--engine central); a stop signal ends it as it ends the
    distributed engine's (_run_distributed): what was recorded written, marked incomplete."""
    from sim.central.engine import Stop, refuse_process_faults, run_central

    none = "the central engine has none"
    # its ticks are lock-step, as fast as it computes: real time's late commands and missed ticks need agents
    realtime = "--clock realtime" if args.clock == "realtime" else f'{args.scene}: clock = "realtime"'
    refuse_if(
        scene.clock == "realtime", f"{realtime} needs the distributed engine: the central engine has no wall clock"
    )
    refuse_if(args.secure is not None, f"--secure secures the bus between processes; {none}")
    refuse_if(args.remote_agents, "--remote-agents needs the distributed engine: the central engine has no agents")
    refuse_if(args.foxglove is not None, f"--foxglove streams the bus's messages; {none} (use --view)")
    refuse_if(faults, "--faults acts on messages; the central engine sends none (use --engine distributed)")
    with usage_errors(ValueError):
        refuse_process_faults(scene)
    progress = None if args.quiet else sys.stderr
    with _open_view(args.view, scene) as view:
        if progress is not None:  # the engine's own first line comes with its first tick
            print(f"[{scene.name}] {scene.robots} robots: starting the central engine", file=progress, flush=True)
        stop = Stop()
        path = run_central(
            scene, out, video=args.video, plots=args.plots, progress=progress, reach=reach, view=view, stop=stop
        )
        print(path, flush=True)
        if stop.signal is not None:
            return _stopped(stop.signal, stop.interrupted, path)
        _keep_viewing(view)
    return 0


def _run_agents(args: argparse.Namespace, scene: Scene, out: Path, faults: Any, reach: float) -> int:
    """The run with agent processes over an embedded router (the distributed engine, or hardware)."""
    # heavy imports only for the distributed engine (after the goal sets: progress first)
    from sim.run.launcher import Launcher, RunOptions

    if args.zenoh_config:
        raise UsageError("--zenoh-config is not supported here: each process of a run needs its own role's file")
    refuse_if(args.mode != "router", "pixelswarm run embeds a router; to join an existing one use -e tcp/HOST:PORT")
    k = args.agents_per_process or scene.agents_per_process
    router = None
    if args.secure is not None:
        router = _secured_router(args, scene.robots, k)
    elif args.listen:
        router = ZenohSettings(mode="router", listen=list(args.listen), connect=list(args.connect))
    same = ("video", "plots", "display", "secure", "hardware", "remote_agents", "startup_timeout", "foxglove")
    options = RunOptions(
        out=out,
        agents_per_process=k,
        router=router,
        connect=[] if args.listen else list(args.connect),
        faults=faults,
        agent_routers=list(args.agents_connect),
        deadline=scene.deadline if args.deadline is None else args.deadline,
        progress=None if args.quiet else sys.stderr,
        agents_timeout=AGENTS_TIMEOUT if args.agents_timeout is None else args.agents_timeout,
        reach=reach,
        **{name: getattr(args, name) for name in same},
    )
    with _open_view(args.view, scene) as options.view:
        return _run_distributed(Launcher(scene, options))


def _open_view(mode: str | None, scene: Scene) -> Any:
    """The live view ``--view`` asks for (a SwarmView), or None, as a context that closes it."""
    if mode is None:
        return contextlib.nullcontext()
    from sim.outputs.view import SwarmView, ViewUnavailable, no_window

    if mode not in ("native", "web") and not mode.endswith(".rrd"):
        raise UsageError(f"--view takes native, web or a FILE.rrd to write, not {mode!r}")
    if mode.endswith(".rrd"):
        _check_save(Path(mode), "--view")
    if mode == "native" and (why := no_window()):
        raise UsageError(f"--view: {why}: use --view web or --view FILE.rrd")
    params = RobotParams.from_dict(scene.robot)
    with usage_errors(ViewUnavailable, prefix="--view: "):
        display = (scene.name, scene.arena, scene.obstacles, params.radius)
        view = SwarmView(*display, robots=scene.robots, sink=mode, tolerance=params.goal_tolerance)
    if view.url is not None:
        print(f"[{scene.name}] view: {view.url}", file=sys.stderr, flush=True)
    return contextlib.closing(view)


def _keep_viewing(view: Any) -> None:
    """After the run: a web view stays up until Ctrl-C (its page holds the whole run)."""
    if view is None:
        return
    view.flush()
    if view.url is not None:
        print(f"view: {view.url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        view.serve_until_interrupted()


def _run_distributed(launcher: Any) -> int:
    """Run the launcher; its end as an exit code and at most one line on stderr."""
    from sim.run.launcher import Interrupted

    try:
        path = launcher.run()
    except TransportError as err:  # a RuntimeError, but bad input: one line, exit code 2
        raise UsageError(str(err)) from None
    except Interrupted:
        print("pixelswarm: interrupted; no run directory written", file=sys.stderr)
        return 130
    except RuntimeError as err:  # a run that failed (a process died at start-up, ...): one line
        print(f"pixelswarm run: error: {err}", file=sys.stderr)
        return 1
    print(path, flush=True)
    end = launcher.end  # how the run ended (sim.run.launcher.RunEnd)
    if end.startup_failure is not None:  # written, marked incomplete, for its logs
        print(f"pixelswarm run: error: start-up failed: {end.startup_failure}", file=sys.stderr)
        return STARTUP_FAILED
    if end.stop_signal is not None:
        return _stopped(end.stop_signal, end.interrupted, path)
    _keep_viewing(launcher.opt.view)
    return 0


def _stopped(signum: int, interrupted: bool, path: Path) -> int:
    """The user said stop: one line, and 128 + the signal, so `pixelswarm run ... && next` goes no further."""
    name = signal.Signals(signum).name
    if interrupted:
        said = f"stopped by {name}; what was recorded is in {path}, marked incomplete"
    else:
        said = f"{name} came as the run ended; {path} is complete"
    print(f"pixelswarm run: {said}", file=sys.stderr)
    return 128 + signum


def cmd_view(args: argparse.Namespace) -> int:
    from sim.outputs.view import VIEW_FILE, ViewUnavailable, view_recording

    refuse_if(args.save is not None and args.web, "--web serves the view, --save writes it to a file: choose one")
    if args.save is not None:
        _check_save(args.save, "--save")
    if args.connect is not None or args.run_dir is None:
        return _watch(args)
    if args.secure is not None or args.display is not None:
        raise UsageError("--secure and --display go with --connect ENDPOINT (watching a running swarm)")
    run_dir, rrd = args.run_dir, args.save or args.run_dir / VIEW_FILE
    if not (run_dir / "trajectory.npz").is_file() or not (run_dir / "scene.json").is_file():
        raise UsageError(f"{run_dir} is not a run directory (no trajectory.npz and scene.json)")
    _refuse_no_window(args)
    with usage_errors(ViewUnavailable, ValueError):  # ValueError: a run directory that does not read
        if args.save is not None or not rrd.is_file():
            _replay_whole(run_dir, rrd)
        if args.save is not None:
            print(args.save)
            return 0
        view_recording(rrd, web=args.web)
    return 0


def _check_save(path: Path, flag: str) -> None:
    """UsageError unless a recording can be written at ``path`` (its folder there, itself not a folder)."""
    refuse_if(path.is_dir(), f"{flag} {path} is a directory: give a FILE.rrd to write")
    refuse_if(not path.parent.is_dir(), f"{flag}: no directory {path.parent} to write {path.name} in")


def _refuse_no_window(args: argparse.Namespace) -> None:
    """UsageError for `pixelswarm view` into Rerun's window where none can open (it would exit unseen)."""
    from sim.outputs.view import no_window

    why = None if args.save is not None or args.web else no_window()
    refuse_if(why, f"{why}: use --web to serve the view, or --save FILE.rrd to write it")


def _replay_whole(run_dir: Path, rrd: Path) -> None:
    """The recording of a run, written beside ``rrd`` and renamed to it once whole: a replay stopped half-way
    (Ctrl-C) leaves no half recording, in RUN_DIR to be reused or in place of the user's file."""
    from sim.outputs.view import replay

    part = rrd.with_name(rrd.name + PARTIAL_SUFFIX)
    try:
        replay(run_dir, part).close()
        part.replace(rrd)
    finally:
        part.unlink(missing_ok=True)


def _watch(args: argparse.Namespace) -> int:
    """`pixelswarm view --connect ENDPOINT`: a running swarm, from its bus (sim.outputs.watch)."""
    from sim.outputs.view import ViewUnavailable
    from sim.outputs.watch import observer_settings, print_line, watch

    save = args.save
    refuse_if(args.connect is None, "give a RUN_DIR to replay, or --connect ENDPOINT to watch a running swarm")
    refuse_if(args.run_dir is not None, f"either a RUN_DIR to replay or --connect ENDPOINT, not both ({args.run_dir})")
    display = args.display or "default"
    with usage_errors(ViewUnavailable):
        settings = observer_settings(args.connect, args.secure, display)
        _refuse_no_window(args)
        sink = save if save is not None else "web" if args.web else "native"
        code = watch(settings, display, sink, timeout=args.timeout, say=print_line("pixelswarm view", args.quiet))
    if code == 0 and save is not None:
        print(save, flush=True)
    return code


def _check_out(out: Path) -> None:
    """UsageError unless a run directory can be made at ``out`` (made and removed again, as a trial, with the
    folders above it that were missing: the run makes them again, and a run refused later leaves nothing)."""
    trial = out.with_name(out.name + PARTIAL_SUFFIX)
    refuse_if(out.exists(), f"run directory {out} already exists; choose another --out")
    refuse_if(trial.exists(), f"{trial} exists (a run that was killed); remove it or choose another --out")
    missing = [folder for folder in out.parents if not folder.exists() and folder.name != ".."]
    blocking = next((folder for folder in out.parents if folder.is_file()), None)
    refuse_if(blocking is not None, f"--out {out}: {blocking} is a file, not a folder")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        trial.mkdir()
        trial.rmdir()
    except OSError as err:
        raise UsageError(f"--out {out}: cannot make a run directory there ({err.strerror or err})") from None
    finally:
        for folder in missing:  # the deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()


def _secured_router(args: argparse.Namespace, robots: int, k: int) -> ZenohSettings | None:
    """`run --secure DIR`: the embedded router's settings if --listen names its endpoint (None: the
    launcher picks a free loopback port); UsageError for anything a secured run cannot do."""
    refuse_if(
        k > 1,
        f"--secure runs one robot per agent process, not {k} (-k or the scene's agents_per_process): "
        "the access rules let a process speak for its own robot only",
    )
    refuse_if(
        args.connect or args.agents_connect,
        "--secure embeds its router and every process joins it; it cannot be used with -e or --agents-connect",
    )
    plain = [e for e in args.listen if not e.startswith("tls/")]
    if plain:
        raise UsageError(f"--secure listens with TLS only: --listen tls/HOST:PORT, not {plain[0]}")
    with usage_errors(SecurityError, prefix="--secure: "):
        args.secure = check_folder(args.secure, robots, display=args.display)
        return router_config(args.secure, args.listen) if args.listen else None


def cmd_router(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    refuse_if(settings.mode != "router", "pixelswarm router runs in router mode; drop -m")
    if not settings.listen and not settings.config_file:
        settings.listen = ["tcp/127.0.0.1:7447"]
    with usage_errors(TransportError):
        where = ", ".join(listen_endpoints(settings))
    refuse_if(not where, f"--zenoh-config {settings.config_file} names no endpoint to listen on: give -l tls/HOST:PORT")
    session = open_session(settings)
    try:
        with stopped_by_signals() as stop:
            print(f"router listening on {where} (Ctrl-C to stop)", flush=True)
            stop.wait()
    finally:
        session.close()
    return 0


def _add_certs_parser(sub: Any) -> None:
    """`pixelswarm certs DIR --robots N`: certificates, configurations and access rules for a secured bus
    (transport/security.py, docs/security.md)."""
    p = sub.add_parser(
        "certs",
        help="make certificates, client configurations and access rules for a secured bus",
        description="Make a certificate authority, a certificate and a Zenoh configuration for each role "
        "(coordinator, tracker, world, recorder, observer, router, robot-<id>), and the router's access rules.",
    )
    p.add_argument("dir", help="folder to create (must not exist or be empty)")
    p.add_argument("-n", "--robots", type=robot_count, required=True, help="number of robots (ids 0..N-1)")
    p.add_argument(
        "--listen",
        metavar="tls/HOST:PORT",
        help="the router's endpoint, written into every configuration and named by the router "
        "certificate (default: none written; give it when a session opens)",
    )
    p.add_argument("--display", default="default", help="display name (key prefix) the access rules cover")
    p.add_argument("--force", action="store_true", help="replace an existing non-empty folder")
    p.set_defaults(func=cmd_certs)


def cmd_certs(args: argparse.Namespace) -> int:
    try:
        path = make_certificates(args.dir, args.robots, connect=args.listen, display=args.display, overwrite=args.force)
    except (SecurityError, ValueError) as err:
        raise UsageError(str(err)) from None
    except OSError as err:
        raise UsageError(f"cannot write {args.dir}: {err.strerror or err}") from None
    print(path)
    return 0


def cmd_stop(args: argparse.Namespace) -> int:
    from hardware.config import HardwareConfigError, load_hardware
    from hardware.stop import stop_all

    with usage_errors(HardwareConfigError):  # a TransportError main says as one line too
        config = load_hardware(args.hardware)
        settings = None
        if config.backend_kind == "ros2":
            refuse_if(not args.connect, f"{args.hardware}: ROS 2 robots are reached through a router: give -e ENDPOINT")
            settings = ZenohSettings(mode="client", connect=[args.connect])
        unreached = stop_all(config, settings)
    if unreached:
        print(f"pixelswarm stop: error: robots {format_ids(unreached)} were not reached", file=sys.stderr)
        return 1
    if config.backend_kind == "sim":
        print(f"{args.hardware}: simulated robots: nothing to stop")
    else:
        print(f"stopped every robot of {args.hardware}")
    return 0


def cmd_scenes(args: argparse.Namespace) -> int:
    # The files as written, not loaded: loading an animation makes every goal set (`run` validates).
    rows = []
    for name in shipped_scenes():
        with open(resolve_scene_path(name), "rb") as f:
            data = tomllib.load(f)
        kinematics = data.get("robot", {}).get("kinematics", EPUCK.kinematics)
        rows.append((name, int(data.get("robots", 0)), kinematics, data.get("description", "")))
    name_width = max((len(name) for name, *_ in rows), default=0)
    robots_width = max((len(str(robots)) for _, robots, *_ in rows), default=0)
    for name, robots, kinematics, description in rows:
        print(f"{name:<{name_width}}  {robots:>{robots_width}d} robots  {kinematics:10s}  {description}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (UsageError, TransportError) as err:
        return refuse(f"pixelswarm {args.command}", err)
    except KeyboardInterrupt:  # before a run began, or a second stop signal while it was written
        if args.command == "run":
            print("pixelswarm: interrupted; no run directory written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
