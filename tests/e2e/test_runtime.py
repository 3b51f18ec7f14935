"""The runtime end to end: real agent processes over a real zenoh router on loopback."""

from __future__ import annotations

import argparse
import getopt
import importlib.util
import json
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from agent.runtime import interpreter
from tests.conftest import (
    REPO,
    agent_processes,
    descendants,
    pixelswarm_cmd,
    reap,
    run_pixelswarm,
    run_scenes,
    start_run,
    wait_for,
)
from transport.bus import Bus
from transport.codec import VERSION, Pose, Poses
from transport.session import (
    ZENOH_LONG,
    ZENOH_SHORT,
    ZenohSettings,
    add_zenoh_args,
    free_port,
    settings_from_args,
    settings_from_options,
    zenoh_usage,
)

SCENE = """
name = "small"
robots = 8
seed = 7
clock = "lockstep"
duration = {duration}
[robot]
kinematics = "{kinematics}"
[layout]
kind = "circle"
spacing = 0.25
[goals]
kind = "antipodal"
"""


def write_scene(tmp_path: Path, duration: float = 6.0, kinematics: str = "holonomic") -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SCENE.format(duration=duration, kinematics=kinematics))
    return path


def metrics(run: Path) -> dict:
    return json.loads((run / "metrics.json").read_text())


def start_run_with_agents(
    spawned: list, scene: Path, out: Path, *extra: str
) -> tuple[subprocess.Popen, list[psutil.Process]]:
    """`pixelswarm run` in the background; returns it once its 8 agent processes are up."""
    proc = start_run(spawned, scene, out, *extra)
    agents = wait_for(lambda: len(agent_processes(proc.pid)) == 8 and agent_processes(proc.pid), timeout=60)
    return proc, agents or []


def wait_until_alive(agent: psutil.Process, robot: int, timeout: float = 60.0) -> None:
    """Join the run's router (the endpoint the agent was given) and wait for the robot's token."""
    from transport.bus import Bus
    from transport.session import ZenohSettings

    cmd = agent.cmdline()
    endpoint = cmd[cmd.index("-e") + 1]
    with Bus(ZenohSettings(mode="client", connect=[endpoint]), "default", name="test") as bus:
        watch = bus.watch_alive("agent")
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(ident == str(robot) and up for _, ident, up, _, _ in watch.drain()):
                return
            time.sleep(0.05)
    raise AssertionError(f"robot {robot}'s agent never came alive")


def robots_of(agent: psutil.Process) -> list[int]:
    cmd = agent.cmdline()
    return json.loads(Path(cmd[cmd.index("--config") + 1]).read_text())["robots"]


@pytest.mark.slow
def test_each_robot_is_its_own_process_and_commands_cross_the_router(tmp_path, spawned):
    scene = write_scene(tmp_path, duration=8.0)
    out = tmp_path / "run"
    proc, agents = start_run_with_agents(spawned, scene, out)
    assert len(agents) == 8
    robots = {p.pid: robots_of(p) for p in agents}
    assert sorted(r for rs in robots.values() for r in rs) == list(range(8))
    assert all(len(rs) == 1 for rs in robots.values())  # one robot per OS process
    stdout, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0
    assert Path(stdout.strip().splitlines()[-1]) == out
    m = metrics(out)
    assert m["agent_processes"] == 8
    # every command the world applied was a message that crossed the router (the recorder saw it there)
    assert m["commands_applied"] > 8 * 10
    assert m["commands_applied"] <= m["commands_sent"]
    assert m["messages_per_robot_s"]["pose"] == pytest.approx(10, rel=0.15)
    assert not reap([p.pid for p in agents])


@pytest.mark.slow
def test_lockstep_is_reproducible_and_hosts_match_processes(tmp_path):
    scene = write_scene(tmp_path, duration=4.0, kinematics="diffdrive")
    # the three at once, each beside the others: a lock-step run is the same run however busy the machine
    done = run_scenes(
        tmp_path, {"a": (str(scene),), "b": (str(scene),), "k4": (str(scene), "--agents-per-process", "4")}
    )
    runs = [done[name][1] for name in ("a", "b", "k4")]
    assert len(runs[0]["t"]) == 41
    np.testing.assert_array_equal(runs[0]["pose"], runs[1]["pose"])
    np.testing.assert_array_equal(runs[0]["pose"], runs[2]["pose"])
    hosted = metrics(tmp_path / "k4")
    assert hosted["agent_processes"] == 2
    # the hosts traded frames of many robots, a pose frame from the world and a state and a command
    # frame per host per tick, not a frame of one per robot (10 per robot and second), and still every
    # command the world applied crossed the router
    per_robot_s = hosted["messages_per_robot_s"]
    assert per_robot_s["cmd"] == pytest.approx(2 * 10 / 8, rel=0.15)
    assert 10 / 8 * 0.85 <= per_robot_s["pose"] < 10 / 8 * 1.15 + 1  # (and each robot's before it is live)
    assert 2 * 10 / 8 * 0.85 <= per_robot_s["state"] < 10 / 2  # (and hellos before the first tick)
    assert 8 * 30 < hosted["commands_applied"] <= hosted["commands_sent"]
    moved = np.hypot(*(runs[0]["pose"][-1, :, :2] - runs[0]["pose"][0, :, :2]).T)
    assert moved.min() > 0.2  # the robots really drove


@pytest.mark.slow
@pytest.mark.wall_clock
def test_sigkill_of_an_agent(tmp_path, spawned):
    # 6 s of display: the kill lands a second or two in (a second after the victim is alive), and the
    # run goes on to its end for seconds after it
    scene = write_scene(tmp_path, duration=6.0)
    out = tmp_path / "run"
    # Real time: in lock-step 8 robots can finish their display before the kill lands
    proc, agents = start_run_with_agents(spawned, scene, out, "--clock", "realtime")
    everyone = [p.pid for p in descendants(proc.pid)]
    victim = agents[3]
    robot = robots_of(victim)[0]
    wait_until_alive(victim, robot)  # mid-run: its liveliness token is on the router
    time.sleep(1.0)
    killed_at = time.time()
    victim.send_signal(signal.SIGKILL)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert "exited with code -9" in stderr
    m = metrics(out)
    assert m["agents_crashed"] == 1 and m["crashes"][0]["robots"] == [robot]
    lost = [e for e in m["liveliness_lost"] if int(e["robot"]) == robot]
    assert lost and 0 <= lost[0]["wall_time"] - killed_at < 1.0
    # its robot stays in the world, stopped: the pose is frozen from shortly after the kill, which lands
    # about a second into the display, to the end (a command drives a period and a margin, then stops)
    traj = np.load(out / "trajectory.npz")
    pose, t = traj["pose"][:, robot], traj["t"]
    moved = np.flatnonzero(np.any(pose[1:] != pose[:-1], axis=1))
    assert len(moved) and t[-1] - t[moved[-1] + 1] >= 3.0, t[moved[-1] + 1] if len(moved) else "never moved"
    assert m["duration_s"] >= 6.0 - 1.0  # the run went on (to within a second of its end)
    assert not reap(everyone)


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_stopping_the_launcher_leaves_no_process(tmp_path, spawned, sig):
    scene = write_scene(tmp_path, duration=60.0)
    out = tmp_path / "run"
    proc, agents = start_run_with_agents(spawned, scene, out)
    assert len(agents) == 8
    time.sleep(1.0)
    everyone = [p.pid for p in descendants(proc.pid)]
    assert len(everyone) >= 10  # coordinator, world, 8 agents
    proc.send_signal(sig)
    proc.communicate(timeout=60)
    still = [pid for pid in everyone if psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE]
    assert still == []
    # an interrupted run is kept, and says so
    m = metrics(out)
    assert m["complete"] is False and m["end_reason"] == "interrupted"
    assert m["duration_s"] < 30.0  # stopped there, not at the scene's 60 s (even when stopped during start-up)
    assert not Path(str(out) + ".partial").exists()


@pytest.mark.slow
def test_malformed_messages_on_every_key_are_dropped(tmp_path, spawned):
    scene = write_scene(tmp_path, duration=6.0)
    out = tmp_path / "run"
    port = free_port()
    proc, agents = start_run_with_agents(spawned, scene, out, "-l", f"tcp/127.0.0.1:{port}")
    assert len(agents) == 8
    rng = np.random.default_rng(0)
    good = Poses.one(Pose(0, 1, 0.1, 0.0, 0.0, 0.0)).encode()
    bad = [
        rng.bytes(20),
        good[:-3],
        bytes([good[0], VERSION + 9]) + good[2:],
        good[:18] + np.float32(np.nan).tobytes() + good[22:],
        b"",
        b"\x08\x01{not json",
    ]
    keys = [
        "pose/0",
        "pose/5",
        "pose",
        "state/0/0/3",
        "state/-1/0/2",
        "cmd/1",
        "state/1",
        "goals/1",
        "clock",
        "sim/truth",
        "sim/contact",
        "event",
        "auction/1/2",
    ]
    rounds = 0
    with Bus(ZenohSettings(mode="client", connect=[f"tcp/127.0.0.1:{port}"]), "default") as attacker:
        # until the run ends: a lock-step run of 6 s may take a second or two of wall time
        while proc.poll() is None and rounds < 200:
            for key in keys:
                for payload in bad:
                    attacker.put(f"px/default/{key}", payload)
            rounds += 1
            time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=120)
    assert rounds >= 5, "the run ended before the damaged messages were sent"
    assert proc.returncode == 0, stderr
    m = metrics(out)
    assert m["complete"] and m["duration_s"] >= 5.9
    assert sum(m["dropped_messages"].values()) > 100
    assert {"truncated", "version", "non-finite"} <= set(m["dropped_messages"])


@pytest.mark.slow
def test_swarm_spans_two_routers(tmp_path, spawned):
    scene = write_scene(tmp_path, duration=5.0)
    port_a, port_b = free_port(), free_port()
    router_a = subprocess.Popen(
        pixelswarm_cmd("router", "-l", f"tcp/127.0.0.1:{port_a}"),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(router_a)
    assert "listening" in router_a.stdout.readline()
    out = tmp_path / "run"
    result = run_pixelswarm(
        "run",
        str(scene),
        "--out",
        str(out),
        "--no-video",
        "--no-plots",
        "-q",
        "-l",
        f"tcp/127.0.0.1:{port_b}",
        "-e",
        f"tcp/127.0.0.1:{port_a}",
        "--agents-connect",
        f"tcp/127.0.0.1:{port_a}",
        "--agents-connect",
        f"tcp/127.0.0.1:{port_b}",
    )
    assert result.returncode == 0, result.stderr
    configs = sorted((out / "logs").glob("agent-*.log"))
    assert len(configs) == 8
    m = metrics(out)
    assert m["missed_ticks"] == 0
    assert m["commands_applied"] >= 8 * 45  # every robot, both routers, every tick
    router_a.send_signal(signal.SIGTERM)
    assert router_a.wait(timeout=10) == 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["no-such-scene"], "unknown scene"),
        (["{tmp}/missing.toml"], "not found"),
        (["{tmp}/bad.toml"], "not valid TOML"),
        (["circle", "--robots", "0"], "at least 1"),
        (["{tmp}/negative.toml"], "radius must be a positive"),
        (["{tmp}/crowded.toml"], "do not fit"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    (tmp_path / "bad.toml").write_text("robots = [")
    (tmp_path / "negative.toml").write_text("robots = 3\n[robot]\nradius = -0.1\n")
    (tmp_path / "crowded.toml").write_text("robots = 50\n[arena]\nsize = [0.5, 0.5]\n")
    out = tmp_path / "out"
    result = run_pixelswarm("run", *[a.format(tmp=tmp_path) for a in args], "--out", str(out), timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists() and not Path(str(out) + ".partial").exists()


def test_occupied_port_is_one_line_and_exit_2(tmp_path, spawned):
    port = free_port()
    router = subprocess.Popen(
        pixelswarm_cmd("router", "-l", f"tcp/127.0.0.1:{port}"),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(router)
    assert "listening" in router.stdout.readline()
    out = tmp_path / "out"
    result = run_pixelswarm("run", "circle", "--out", str(out), "-l", f"tcp/127.0.0.1:{port}", timeout=60)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "in use" in result.stderr
    assert not out.exists() and not Path(str(out) + ".partial").exists()
    router.send_signal(signal.SIGTERM)
    router.wait(timeout=10)


@pytest.mark.slow
def test_agent_hosts_write_their_profiles_when_asked(tmp_path):
    """PIXELSWARM_PROFILE=DIR: each agent host's loop runs under cProfile and leaves DIR/agent<first
    robot>.prof, readable by pstats, with one control step per tick it stepped."""
    import os
    import pstats

    scene = write_scene(tmp_path, duration=2.0)
    out, profiles = tmp_path / "run", tmp_path / "profiles"
    result = subprocess.run(
        pixelswarm_cmd("run", str(scene), "--out", str(out), "--no-video", "--no-plots", "-q", "-k", "4"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=240,
        env={**os.environ, "PIXELSWARM_PROFILE": str(profiles)},
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert sorted(p.name for p in profiles.iterdir()) == ["agent0.prof", "agent4.prof"]
    ticks = len(np.load(out / "trajectory.npz")["t"])
    for path in profiles.iterdir():
        calls = {f[2]: s[1] for f, s in pstats.Stats(str(path)).stats.items()}  # function name -> calls
        assert ticks - 2 <= calls["_step_tick"] <= ticks + 1, (ticks, calls["_step_tick"])


def test_a_robot_alone_in_its_process_runs_without_docstrings_where_their_optimised_bytecode_is_compiled(
    tmp_path, monkeypatch
):
    """-OO spares a robot's process the docstrings it never reads, but only where compiled bytecode
    for it exists: else every start would compile numpy from source. Hosts of many robots run plain."""
    compiled = tmp_path / "module.opt-2.pyc"
    compiled.write_bytes(b"")
    asked: list[int | str | None] = []

    def cache_from_source(path: str, optimization: int | str | None = None) -> str:
        asked.append(optimization)
        return str(compiled)

    monkeypatch.setattr(importlib.util, "cache_from_source", cache_from_source)  # interpreter() imports it itself
    assert interpreter(1) == [sys.executable, "-OO", "-X", "no_debug_ranges"]
    assert set(asked) == {2}
    assert interpreter(2) == [sys.executable]
    compiled.unlink()
    assert interpreter(1) == [sys.executable]
    monkeypatch.undo()
    # however the bytecode stands, the process so started runs an agent's imports
    code = (
        "import sys, agent.__main__, numpy\n"
        "print(sys.flags.optimize, next(agent.__main__.main.__code__.co_positions())[2] is None)"  # no column
    )
    out = subprocess.run([*interpreter(1), "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0, out.stderr[-500:]
    robot = "-OO" in interpreter(1)
    assert out.stdout.split() == ["2" if robot else "0", str(robot)]


ARENAS = """
import ctypes, sys, threading
from transport.session import ZenohSettings, one_malloc_arena, open_session
if sys.argv[1] == "one" and not one_malloc_arena():  # not an assert: -OO would strip it
    sys.exit("mallopt failed")
session = open_session(ZenohSettings(mode="peer"))  # listens nowhere: its messages stay in the process
heard = []
sub = session.declare_subscriber("px/test/**", lambda sample: heard.append(sample.payload.to_bytes()))
def work():  # a thread that allocates, as zenoh's and the subscriptions' threads do
    kept = [bytes(2000) for _ in range(200)]
    for i in range(20):
        session.put(f"px/test/{i}", bytes(1000))
threads = [threading.Thread(target=work) for _ in range(4)]
for t in threads:
    t.start()
for t in threads:
    t.join()
libc = ctypes.CDLL(None)
libc.fdopen.restype = ctypes.c_void_p
out = ctypes.c_void_p(libc.fdopen(sys.stdout.fileno(), b"w"))
sys.stdout.flush()
libc.malloc_info(0, out)  # an XML element per arena
libc.fflush(out)
sub.undeclare()
session.close()
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc arenas are glibc's")
def test_a_robot_process_allocates_from_one_malloc_arena():
    """glibc gives each thread that allocates an arena of its own, whose part-used pages count in a
    robot's RSS; with one_malloc_arena, zenoh's threads and the process's own share one."""
    heaps = {}
    # glibc's own settings, if the environment holds any, would make "default" something else
    env = {k: v for k, v in os.environ.items() if k not in ("MALLOC_ARENA_MAX", "GLIBC_TUNABLES")}
    for arenas in ("one", "default"):
        out = subprocess.run(
            [*interpreter(1), "-c", ARENAS, arenas], capture_output=True, text=True, cwd=REPO, timeout=60, env=env
        )
        assert out.returncode == 0, out.stderr[-500:]
        heaps[arenas] = out.stdout.count("<heap nr=")
    assert heaps["one"] == 1 and heaps["default"] > 1, heaps


@pytest.mark.parametrize("robots", [[0], [0, 1]])
def test_the_agent_shares_one_malloc_arena_when_it_runs_one_robot(tmp_path, monkeypatch, robots):
    """A robot's own process asks for one arena before its session opens; a host of several robots,
    whose threads allocate more, keeps glibc's default. (The bad zenoh mode stops it right after.)"""
    import agent.__main__

    asked: list[bool] = []
    monkeypatch.setattr(agent.__main__, "one_malloc_arena", lambda: asked.append(True))
    config = tmp_path / "host.json"
    config.write_text(json.dumps({"robots": robots, "params": {}}))
    assert agent.__main__.main(["--config", str(config), "-m", "satellite"]) == 2
    assert asked == ([True] if len(robots) == 1 else [])


def test_a_robot_process_loads_no_module_a_robot_never_uses():
    """Each module is memory in every one of N robot processes: random serves injected faults,
    cProfile a profiled run, socket finding a router's port, importlib.util the launcher's choice of
    interpreter, pathlib (with urllib.parse and ipaddress) nothing a robot needs, numpy.ma nothing
    of a robot's (np.unique loads it), and numpy.typing annotations only. A robot without them never
    loads them, however its cells move or whichever robots its inbox keeps. (zlib it loads: it checks
    goal sets' and bids' checksums.)"""
    not_loaded = ("random", "cProfile", "socket", "importlib.util", "pathlib", "ipaddress", "numpy.ma", "numpy.typing")
    code = (
        f"NOT_LOADED = {not_loaded!r}\n"
        "import sys, numpy as np, zenoh, agent.__main__\n"
        "from agent.runtime import CellSubscriptions\n"
        "from transport.bus import KeepRobots\n"
        "own = KeepRobots(np.array([3, 1, 3]))\n"
        "class Bus:\n"
        "    from transport.keys import Keys\n"
        "    keys = Keys()\n"
        "    def subscribe_into(self, key, inbox): return key\n"
        "    def unsubscribe(self, sub): pass\n"
        "cells = CellSubscriptions(Bus(), None, 0.5)\n"
        "cells.update(np.array([[0.1, 0.2], [0.3, 0.2]]))\n"
        "cells.update(np.array([[2.1, 0.2], [0.3, 0.2]]))\n"
        "print(len(cells.cells), own.ids.tolist(), sorted(m for m in NOT_LOADED if m in sys.modules))"
    )
    out = subprocess.run([*interpreter(1), "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0, out.stderr[-500:]
    # 7 x 7 cells around each robot, in cells 4 apart: 7 columns of 7 and 4 more
    assert out.stdout.strip() == f"{7 * 7 + 4 * 7} [1, 3] []"


@pytest.mark.parametrize("kinematics", ["holonomic", "diffdrive"])
def test_a_robot_steps_on_the_compiled_core_without_a_jit(kinematics):
    """Both kinds of robot drive toward their goal on the core compiled at install: nothing in a
    robot's process compiles at run time (no numba, no llvmlite)."""
    code = (
        "import sys, numpy as np\n"
        "from agent.core.params import RobotParams\n"
        "from agent.core.step import NeighbourStates, OwnStates, control_step\n"
        f"p = RobotParams(kinematics={kinematics!r})\n"
        "own = OwnStates(np.arange(1), np.zeros((1, 2)), np.zeros(1), np.zeros((1, 2)), np.ones((1, 2)))\n"
        "r = control_step(p, own, NeighbourStates.empty(1))\n"
        "print(bool(r.command.any()), sorted(m for m in ('numba', 'llvmlite') if m in sys.modules))"
    )
    out = subprocess.run([*interpreter(1), "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0, out.stderr[-500:]
    assert out.stdout.strip() == "True []"


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["-m", "peer", "-e", "tcp/127.0.0.1:7447", "--connect", "tcp/127.0.0.1:7448", "-l", "tcp/127.0.0.1:7449"],
        ["--mode=router", "--listen=tcp/127.0.0.1:7447", "--multicast-scouting", "--zenoh-config", "robot.json5"],
        ["--multicast-scouting", "--no-multicast-scouting", "-mclient"],
    ],
)
def test_a_robot_process_reads_the_zenoh_flags_as_every_other_command_does(argv):
    """The agent parses its flags with getopt (no argparse in a robot's memory); the zenoh flags
    mean what add_zenoh_args makes them mean in every other command, and its help lists them."""
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    by_argparse = settings_from_args(parser.parse_args(argv))
    by_getopt = settings_from_options(getopt.getopt(argv, ZENOH_SHORT, ZENOH_LONG)[0])
    assert by_getopt == by_argparse
    for action in parser._actions:
        assert all(flag in zenoh_usage() for flag in action.option_strings if flag not in ("-h", "--help"))


def test_the_agent_command_line_says_what_is_wrong_in_one_line_and_exits_2(tmp_path):
    """Bad flags, a missing config and a bad zenoh mode: exit 2, the error in one line after the
    usage line, no traceback; --help shows every flag and exits 0."""
    config = tmp_path / "host.json"
    config.write_text(json.dumps({"robots": [0], "params": {}}))
    cases = [
        ([], "required: --config"),
        (["--config", str(config), "--bogus"], "--bogus not recognized"),
        (["--config", str(config), "stray"], "unrecognized arguments: stray"),
        (["--config", str(tmp_path / "missing.json")], "bad config"),
        (["--config", str(config), "-m", "satellite"], "zenoh mode must be one of"),
    ]
    for argv, message in cases:
        out = subprocess.run(
            [*interpreter(1), "-m", "agent", *argv], capture_output=True, text=True, cwd=REPO, timeout=60
        )
        assert out.returncode == 2, (argv, out.stderr)
        errors = [line for line in out.stderr.splitlines() if not line.startswith("usage:")]
        assert len(errors) == 1 and message in errors[0], (argv, out.stderr)
        assert "Traceback" not in out.stderr
    shown = subprocess.run([*interpreter(1), "-m", "agent", "--help"], capture_output=True, text=True, cwd=REPO)
    assert shown.returncode == 0
    assert all(flag in shown.stdout for flag in ("--config", "--faults", "--exit-with-parent", "--connect"))
