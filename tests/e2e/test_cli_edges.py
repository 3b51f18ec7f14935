"""`pixelswarm run` at its edges (issue 40): bad input is one line, exit 2, nothing written and no
process left; a start-up that cannot finish says which robots in one line and exits 3, also on a
machine whose cores are busy; Ctrl-C exits 130 with what was recorded, marked incomplete."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from coordinator.scene import load_scene
from sim.args import MAX_ROBOTS
from sim.cli import main as cli
from sim.node.world import world_node
from tests.conftest import REPO, descendants, pixelswarm_cmd, reap, run_pixelswarm, start_run, ticks_so_far, wait_for
from transport.bus import Bus
from transport.faults import fault_kinds
from transport.session import free_port, loopback_router

FAST = ("--no-video", "--no-plots", "-q")


def leftovers(tmp_path: Path) -> list[int]:
    """Processes (of any parent) whose command line names a path under ``tmp_path``: a run's children
    carry its run directory in theirs."""
    found = []
    for p in psutil.process_iter(["cmdline"]):
        try:
            if any(str(tmp_path) in arg for arg in p.info["cmdline"] or []) and p.status() != psutil.STATUS_ZOMBIE:
                found.append(p.pid)
        except psutil.Error:
            continue
    return found


def one_error_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


def refused(tmp_path: Path, *args: str, scene: str = "circle") -> str:
    """`pixelswarm run SCENE ARGS --out DIR` refuses: exit 2, one line on stderr and no traceback, no
    run directory (final or partial) and no process left. Returns the line."""
    out = tmp_path / "r"
    result = run_pixelswarm("run", scene, "--out", str(out), *FAST, *args, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert result.stdout == ""
    assert not out.exists() and not out.with_name("r.partial").exists()
    assert wait_for(lambda: not leftovers(tmp_path), timeout=10), leftovers(tmp_path)
    return lines[0]


# --- bad input ----------------------------------------------------------------------------------
@pytest.mark.parametrize("plan", ["banana:drop=0.1", "states:drop=0.2", "state:drop=0.1;sim/truth:drop=0.5"])
def test_a_fault_plan_of_no_message_kind_is_refused_with_the_kinds_there_are(tmp_path, plan):
    line = refused(tmp_path, "--faults", plan)
    assert "--faults" in line and ", ".join(fault_kinds()) in line
    assert "state" in fault_kinds() and "sim/truth" not in fault_kinds()  # what the recorder alone hears
    if plan.startswith("states"):
        assert "did you mean 'state'" in line


def test_a_fault_plan_with_the_central_engine_is_refused(tmp_path):
    assert "central engine" in refused(tmp_path, "--engine", "central", "--faults", "state:drop=0.1")


@pytest.mark.parametrize("module", ["agent", "sim.node.world"])
def test_the_processes_a_run_starts_refuse_a_fault_plan_of_no_message_kind(tmp_path, module):
    """`python -m agent` (as `pixelswarm agents` starts it, with the run's plan) and the world."""
    config = tmp_path / "host.json"
    config.write_text(json.dumps({"robots": [0], "params": {}}))
    where = ["--config", str(config)] if module == "agent" else ["--scene", "circle", "--robots", "2"]
    result = subprocess.run(
        [sys.executable, "-m", module, *where, "--faults", "states:drop=0.2", "-e", f"tcp/127.0.0.1:{free_port()}"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "no message kind 'states'" in lines[0] and "Traceback" not in result.stderr


def test_an_out_where_no_directory_can_be_made_is_refused(tmp_path):
    result = run_pixelswarm("run", "circle", "--out", "/proc/nope", *FAST, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0].startswith("pixelswarm run: error: --out /proc/nope: cannot make a run directory")
    assert not Path("/proc/nope.partial").exists()


def test_a_bad_duration_names_the_flag_not_the_scene_file(tmp_path):
    line = refused(tmp_path, "--duration", "-5")
    assert "--duration must be a positive number of seconds, not -5" in line and ".toml" not in line


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--duration", "0"),
        ("--duration", "nan"),
        ("--robots", "0"),
        ("--robots", "-3"),
        ("--seed", "-1"),
        ("--seed", "1.5"),
        ("--deadline", "0"),
        ("--startup-timeout", "-1"),
        ("--startup-timeout", "inf"),
        ("--agents-per-process", "0"),
    ],
)
def test_every_bad_number_names_its_flag(tmp_path, capsys, flag, value):
    """As the command line reads them (in this process: nothing has started when they are read)."""
    try:
        code = cli.main(["run", "circle", "--out", str(tmp_path / "r"), flag, value])
    except SystemExit as stopped:  # argparse's own refusals
        code = stopped.code
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and flag in line and ".toml" not in line, line
    assert not list(tmp_path.iterdir())


def refused_in_process(capsys, *argv: str) -> str:
    """`pixelswarm ARGV` (in this process) refuses: exit 2 and one line on stderr, nothing on stdout."""
    try:
        code = cli.main(list(argv))
    except SystemExit as stopped:  # argparse's own refusals
        code = stopped.code
    captured = capsys.readouterr()
    assert code == 2 and captured.out == "", captured
    return one_error_line(captured.err)


@pytest.mark.parametrize("engine", ["distributed", "central"])
@pytest.mark.parametrize(
    ("flag", "value", "said"),
    [
        ("--display", "a b", "display name 'a b' may hold only"),
        ("--display", "", "display name '' may hold only"),
        ("--out", "", "'' names no new directory"),
        ("--out", ".", "'.' names no new directory"),
        ("--out", "/", "'/' names no new directory"),
        ("--out", "{tmp}/missing/..", "missing/..' names no new directory"),
        ("--agents-connect", "garbage", "'garbage' is not an endpoint: expected PROTOCOL/ADDRESS"),
        ("--robots", str(MAX_ROBOTS + 1), f"at most {MAX_ROBOTS} robots"),
    ],
)
def test_a_flag_no_run_can_use_is_refused_as_it_is_read(tmp_path, capsys, monkeypatch, engine, flag, value, said):
    """Before anything is made, on either engine (the display once crashed the distributed engine's launcher and
    passed the central engine; --agents-connect garbage ran the scene and exited 3)."""
    monkeypatch.chdir(tmp_path)  # '' and '.' are the working directory
    value = value.format(tmp=tmp_path)
    out = [] if flag == "--out" else ["--out", str(tmp_path / "r")]
    line = refused_in_process(capsys, "run", "circle", "--engine", engine, *out, *FAST, flag, value)
    assert line.startswith(f"pixelswarm run: error: argument {flag}") and said in line, line
    assert not list(tmp_path.iterdir())


def test_agents_sent_to_routers_the_run_does_not_reach_are_refused(tmp_path, capsys):
    """The documented --agents-connect example lacked -e: its agents never heard the run, which waited 300 s."""
    line = refused_in_process(
        capsys, "run", "circle", "--out", str(tmp_path / "r"), *FAST, "--agents-connect", "tcp/127.0.0.1:9"
    )
    assert "--agents-connect: the run's own router must reach those routers: join one with -e" in line, line
    assert not list(tmp_path.iterdir())


def test_an_out_below_a_file_says_so(tmp_path, capsys):
    (tmp_path / "afile").write_text("")
    line = refused_in_process(capsys, "run", "circle", "--out", str(tmp_path / "afile" / "r"), *FAST)
    assert line.endswith(f"{tmp_path / 'afile'} is a file, not a folder"), line  # it said (File exists)


def test_a_killed_run_s_partial_folder_is_named_when_out_is_refused(tmp_path, capsys):
    (tmp_path / "r.partial").mkdir()
    line = refused_in_process(capsys, "run", "circle", "--out", str(tmp_path / "r"), *FAST)
    assert f"{tmp_path / 'r.partial'} exists (a run that was killed); remove it or choose another --out" in line, line


def test_a_run_refused_after_its_out_was_tried_leaves_no_folder_it_made(tmp_path, capsys):
    """--out's missing parent folders are made to try it, and removed again when the run is refused later."""
    out = tmp_path / "new" / "deeper" / "r"
    line = refused_in_process(capsys, "run", "circle", "--out", str(out), *FAST, "--view", "banana")
    assert "--view takes native, web or a FILE.rrd" in line
    assert not list(tmp_path.iterdir())


def test_certs_refuse_more_robots_than_the_maximum(tmp_path, capsys):
    line = refused_in_process(capsys, "certs", str(tmp_path / "c"), "-n", str(MAX_ROBOTS + 1))
    assert f"at most {MAX_ROBOTS} robots" in line and not list(tmp_path.iterdir())


def test_a_scene_file_with_a_negative_seed_is_refused(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text("robots = 2\nseed = -1\n")
    assert "seed must be a whole number >= 0" in refused(tmp_path, scene=str(scene))


def test_zenoh_errors_are_one_readable_line_with_a_hint(tmp_path):
    busy = socket.socket()
    try:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cases = {
            f"tcp/127.0.0.1:{port}": ("address already in use", "choose another with -l"),
            "tcp/127.0.0.1:99999": ("invalid port value", "PROTOCOL/HOST:PORT"),
            "nonsense": ("not an endpoint", "PROTOCOL/HOST:PORT"),
        }
        for k, (endpoint, (reason, hint)) in enumerate(cases.items()):
            line = refused(tmp_path / str(k), "-l", endpoint)
            assert f"on {endpoint}: {reason}; " in line and hint in line, line
            assert ".rs:" not in line and ".cargo" not in line and len(line) < 200, line
    finally:
        busy.close()


def test_a_world_that_waits_in_vain_names_the_robots_and_does_not_run():
    """By hand (`python -m sim.node.world`), a world whose agents do not all come says which; it does
    not show the scene without them."""
    scene = load_scene("circle", robots=3, seed=0, clock="lockstep", duration=1.0)
    with Bus(loopback_router(), name="world") as bus:
        node = world_node(bus, scene, startup_timeout=0.5)
        node.run()
    assert node.tick == 0
    assert node.end_reason == "no agent came alive for robots 0-2 within 0.5 s"


@pytest.mark.slow
def test_a_run_on_a_display_another_swarm_is_live_on_is_refused(tmp_path):
    """Two runs on one router and display would take each other's agents for their own, and their robots
    stand for the rest of the run; the second is refused before it starts anything, naming what is live.
    Another display on the same router is free."""
    router = loopback_router()
    endpoint, run = router.listen[0], ("run", "circle", "--robots", "3", "--duration", "2", *FAST)
    with Bus(router, name="world") as other:
        other.declare_alive("world", 0)
        other.declare_alive("agent", "0-7")
        refused = run_pixelswarm(*run, "-e", endpoint, "--out", str(tmp_path / "r"), timeout=60)
        beside = run_pixelswarm(*run, "-e", endpoint, "--display", "beside", "--out", str(tmp_path / "b"), timeout=120)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert refused.stderr.strip().splitlines() == [
        f"pixelswarm run: error: display 'default' at {endpoint} is in use: another swarm is live on it "
        "(world, agents of 8 robots); end that run or pass --display NAME"
    ]
    assert not (tmp_path / "r").exists()
    assert beside.returncode == 0, beside.stderr
    assert json.loads((tmp_path / "b" / "metrics.json").read_text())["contacts"] == 0
    assert not leftovers(tmp_path)


# --- runs ---------------------------------------------------------------------------------------
def assert_incomplete(out: Path, reason: str) -> dict:
    assert out.is_dir() and not out.with_name(out.name + ".partial").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] is False and metrics["end_reason"] == reason
    assert (out / "INCOMPLETE").read_text().splitlines()[0] == reason
    return metrics


STARTUP_S = 10.0  # s: that run's --startup-timeout; the test checks what it says when it expires


@pytest.mark.slow
def test_a_run_whose_agents_hear_no_pose_names_them_and_exits_3(tmp_path, spawned):
    """Half the agents join a router the run is not on (a mistaken --agents-connect): they never hear
    their poses. Real time: in lock-step their neighbours would wait for their hellos too. The test
    is about the message, not the wait: a start-up timeout of STARTUP_S, long enough for the agents
    that can hear their poses to come alive on a loaded machine (a few seconds)."""
    ours, other = free_port(), free_port()
    router = subprocess.Popen(
        pixelswarm_cmd("router", "-l", f"tcp/127.0.0.1:{other}"), cwd=REPO, stdout=subprocess.DEVNULL
    )
    spawned.append(router)
    out = tmp_path / "r"
    connect = ["--agents-connect", f"tcp/127.0.0.1:{ours}", "--agents-connect", f"tcp/127.0.0.1:{other}"]
    result = run_pixelswarm(
        "run", "circle", "--robots", "4", "--clock", "realtime", "--out", str(out), *FAST,
        "-l", f"tcp/127.0.0.1:{ours}", *connect, "--startup-timeout", f"{STARTUP_S:g}", timeout=240,
    )  # fmt: skip
    assert result.returncode == 3, result.stderr
    line = one_error_line(result.stderr)
    assert line.startswith(
        f"pixelswarm run: error: start-up failed: robots 1, 3: no agent came alive within {STARTUP_S:g} s"
    )
    assert result.stdout.strip() == str(out)
    metrics = assert_incomplete(out, "start-up failed")
    assert metrics["startup_failure"] in line and (out / "logs" / "agent-0001.log").exists()
    assert leftovers(tmp_path) == []


@pytest.mark.slow
def test_a_run_whose_agent_processes_exit_at_start_up_names_the_robots_and_exits_3(tmp_path):
    """The agents' router is not there: each agent process gives up on its session (exit 2)."""
    out = tmp_path / "r"
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    ours = ("-l", f"tcp/127.0.0.1:{free_port()}")  # the run's router, which the agents do not reach
    result = run_pixelswarm(
        "run", "circle", "--robots", "3", "--out", str(out), *FAST, *ours, "--agents-connect", nowhere, timeout=180
    )
    assert result.returncode == 3, result.stderr
    line = one_error_line(result.stderr)
    assert "start-up failed: robots 0-2: no agent came alive (the agent process of robot" in line
    assert "exited with code 2" in line
    assert_incomplete(out, "start-up failed")
    assert leftovers(tmp_path) == []


@pytest.mark.slow
def test_ctrl_c_writes_what_was_recorded_marked_incomplete_and_exits_130(tmp_path, spawned):
    out = tmp_path / "r"
    # real time: the robots take longer to form the circle than the run is given here
    proc = start_run(spawned, "circle", out, "--robots", "4", "--clock", "realtime")
    assert wait_for(lambda: (out.with_name("r.partial") / "logs" / "world.log").exists(), timeout=120)
    time.sleep(3.0)
    everyone = [p.pid for p in descendants(proc.pid)]
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert (
        one_error_line(stderr) == f"pixelswarm run: stopped by SIGINT; what was recorded is in {out}, marked incomplete"
    )
    assert stdout.strip() == str(out)
    assert_incomplete(out, "interrupted")
    assert not reap(everyone) and leftovers(tmp_path) == []


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_twenty_lockstep_agents_start_while_both_cores_are_busy_and_finish(tmp_path, spawned):
    """Issue 40: with both cores saturated, start-up used to time out (`no agent came alive`) and the
    run still exited 0. The cores stay busy until the first tick is recorded, start-up over: a
    lock-step run after it is the same run however loaded the machine is, so it ends 5 s in."""
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    out = tmp_path / "r"
    try:
        proc = start_run(
            spawned, "circle", out, "--robots", "20", "--clock", "lockstep", "--seed", "1", "--duration", "5"
        )
        assert wait_for(lambda: ticks_so_far(out) > 0 or proc.poll() is not None, timeout=600)
    finally:
        for p in busy:
            p.kill()
            p.wait(timeout=10)
    _, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] is True and metrics["contacts"] == 0 and metrics["agents_crashed"] == 0
    assert not (out / "INCOMPLETE").exists()
    assert leftovers(tmp_path) == []
