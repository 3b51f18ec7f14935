"""Agents on other machines: `pixelswarm run --remote-agents` and `pixelswarm agents --connect`.

The run and the agents are separate process trees (two `pixelswarm` commands) joined only through
a router's endpoint on loopback, directly or through a second router joined to the run's.
"""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import psutil
import pytest

from sim.run.remote_agents import format_ids, merge_configs, parse_ids
from tests.conftest import REPO, agent_processes, pixelswarm_cmd, run_pixelswarm, ticks_so_far, wait_for
from transport.session import free_port, listening

TIMEOUT = 90  # s for one end-to-end command on a loaded machine


def start(spawned: list, log: Path, *args: str) -> subprocess.Popen:
    """A `pixelswarm` command of its own (its own process tree), stderr to ``log``."""
    with open(log, "w") as err:
        proc = subprocess.Popen(
            pixelswarm_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=err, text=True, start_new_session=True
        )
    spawned.append(proc)
    return proc


def start_run(spawned: list, tmp_path: Path, port: int, *extra: str, clock: str = "lockstep") -> subprocess.Popen:
    return start(
        spawned,
        tmp_path / "run.err",
        *("run", "circle", "--robots", "6", "--listen", f"tcp/127.0.0.1:{port}", "--remote-agents"),
        *("--clock", clock, "--no-video", "--no-plots", "--out", str(tmp_path / "run"), *extra),
    )


def processes_on(port: int) -> list[psutil.Process]:
    """Every process whose command line names this (free, test-only) port."""
    found = []
    for p in psutil.process_iter(["cmdline"]):
        if any(f":{port}" in part for part in p.info["cmdline"] or []):
            found.append(p)
    return found


def agents_of(command: subprocess.Popen, count: int) -> list[psutil.Process]:
    """The agent processes a `pixelswarm agents` started, once there are ``count`` (or what there is
    after a while, for the assertion to show)."""
    wait_for(lambda: len(agent_processes(command.pid)) >= count, timeout=30)
    return agent_processes(command.pid)


def finish(proc: subprocess.Popen) -> str:
    out, _ = proc.communicate(timeout=TIMEOUT)
    return out


def check_picture(tmp_path: Path, run: subprocess.Popen, agents: subprocess.Popen, started: list) -> None:
    """Both commands succeed, the run forms the picture with no contact, and the agent processes
    ``started`` are gone."""
    assert finish(agents) == "" and agents.returncode == 0, (tmp_path / "agents.err").read_text()
    assert finish(run).strip() == str(tmp_path / "run"), (tmp_path / "run.err").read_text()[-2000:]
    assert run.returncode == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["converged"] and metrics["end_reason"] == "converged"
    assert metrics["contacts"] == 0 and metrics["missed_ticks"] == 0
    assert metrics["agents_crashed"] == 0 and metrics["liveliness_lost"] == []
    assert metrics["agent_processes"] == len(started)  # every host's statistics reached the run
    assert not (tmp_path / "run" / "config").exists()  # no config file written for the agents
    assert not any(p.is_running() and p.status() != psutil.STATUS_ZOMBIE for p in started)


@pytest.mark.slow
def test_agents_from_another_process_tree_form_the_picture(tmp_path, spawned):
    port = free_port()
    run = start_run(spawned, tmp_path, port)
    # the run says what it waits for (agents started at once with it can be there before it looks)
    assert wait_for(lambda: "waiting for agents" in (tmp_path / "run.err").read_text(), timeout=30)
    agents = start(spawned, tmp_path / "agents.err", "agents", "--connect", f"tcp/127.0.0.1:{port}")
    started = agents_of(agents, 6)
    assert len(started) == 6, (tmp_path / "agents.err").read_text()  # one robot per process by default
    check_picture(tmp_path, run, agents, started)
    assert processes_on(port) == []


@pytest.mark.slow
@pytest.mark.wall_clock  # real time: the second commands must come while the run goes on
def test_a_second_agents_command_for_robots_whose_agents_live_is_refused_and_the_run_goes_on(tmp_path, spawned):
    """Two agents for one robot would send two commands a tick, and the world would stop the robot: the run
    answers a robot's configuration query with 'taken' while its agent lives, and `pixelswarm agents` says so."""
    port = free_port()
    run = start_run(spawned, tmp_path, port, clock="realtime")
    assert wait_for(lambda: "waiting for agents" in (tmp_path / "run.err").read_text(), timeout=30)
    agents = start(spawned, tmp_path / "agents.err", "agents", "--connect", f"tcp/127.0.0.1:{port}")
    started = agents_of(agents, 6)
    assert wait_for(lambda: ticks_so_far(tmp_path / "run") >= 10, timeout=60), (tmp_path / "run.err").read_text()
    for robots in ([], ["--robots", "1-2"]):
        second = run_pixelswarm("agents", "--connect", f"tcp/127.0.0.1:{port}", *robots, timeout=TIMEOUT)
        taken = "1-2" if robots else "0-5"
        assert second.returncode == 2, second.stderr
        assert f"robots {taken} of the run on tcp/127.0.0.1:{port} (display default) have agents alive" in second.stderr
    # the picture formed by the first command's agents alone (in real time: a tick the second command's start
    # made late is not asked about)
    assert finish(agents) == "" and agents.returncode == 0, (tmp_path / "agents.err").read_text()
    assert finish(run).strip() == str(tmp_path / "run") and run.returncode == 0, (tmp_path / "run.err").read_text()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["converged"] and metrics["contacts"] == 0 and metrics["commanded_two_ways"] == []
    assert metrics["agent_processes"] == len(started) == 6 and metrics["liveliness_lost"] == []


@pytest.mark.slow
def test_agents_through_a_second_router_form_the_picture(tmp_path, spawned):
    port, second = free_port(), free_port()
    run = start_run(spawned, tmp_path, port)
    assert wait_for(lambda: "waiting for agents" in (tmp_path / "run.err").read_text(), timeout=30)
    router = start(
        spawned, tmp_path / "router.err", "router", "-l", f"tcp/127.0.0.1:{second}", "-e", f"tcp/127.0.0.1:{port}"
    )
    assert "listening" in router.stdout.readline()
    agents = start(spawned, tmp_path / "agents.err", "agents", "--connect", f"tcp/127.0.0.1:{second}", "-k", "2")
    started = agents_of(agents, 3)
    assert len(started) == 3  # -k 2: six robots in three processes
    assert all(f"tcp/127.0.0.1:{second}" in p.cmdline() for p in started)  # they joined the second router only
    check_picture(tmp_path, run, agents, started)
    router.terminate()
    assert router.wait(timeout=10) == 0
    assert processes_on(port) == [] and processes_on(second) == []


# s the run waits for its agents: long enough for robots 0-2's agents, started by hand below, to come
# alive (a few seconds alone on the machine); the test checks what the run says when it expires
AGENTS_WAIT = 10.0


@pytest.mark.slow
@pytest.mark.wall_clock  # a wall-clock timeout: agents starting beside other runs may miss it
def test_a_run_whose_agents_never_all_come_names_the_missing_robots(tmp_path, spawned):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    # on the wall clock: a lock-step agent would wait for its missing neighbours' hellos first
    run = start_run(spawned, tmp_path, port, "--agents-timeout", f"{AGENTS_WAIT:g}", "-q", clock="realtime")
    assert wait_for(lambda: run.poll() is not None or listening(port), 30), "the run's router never listened"
    # robots the run does not have: refused with one line, nothing started
    wrong = run_pixelswarm("agents", "--connect", endpoint, "--robots", "4-9", timeout=TIMEOUT)
    assert wrong.returncode == 2, wrong.stderr
    assert wrong.stderr.strip().splitlines() == [
        f"pixelswarm agents: error: robots 6-9 are not agent robots of the run on {endpoint} (display default)"
    ]
    some = start(spawned, tmp_path / "some.err", "agents", "--connect", endpoint, "--robots", "0-2")
    other = start(spawned, tmp_path / "other.err", "agents", "--connect", endpoint, "--robots", "3", "-q")
    some_agents, other_agent = agents_of(some, 3), agents_of(other, 1)
    assert len(some_agents) == 3 and len(other_agent) == 1
    other.send_signal(signal.SIGINT)  # passed on: its agent stops with it
    assert finish(other) == "" and other.returncode == 130, (tmp_path / "other.err").read_text()
    assert not other_agent[0].is_running() or other_agent[0].status() == psutil.STATUS_ZOMBIE
    # robots 0-2 came alive; 3 left with its agent, 4 and 5 were only asked about
    assert finish(run) == "" and run.returncode == 2
    lines = (tmp_path / "run.err").read_text().strip().splitlines()
    assert len(lines) == 1 and f"no agent came for robots 3-5 within {AGENTS_WAIT:g} s" in lines[0], lines
    assert not (tmp_path / "run").exists() and not (tmp_path / "run.partial").exists()
    # the run went away: the remaining agents stop, and their command exits 0
    assert finish(some) == "" and some.returncode == 0, (tmp_path / "some.err").read_text()
    assert not any(p.is_running() and p.status() != psutil.STATUS_ZOMBIE for p in some_agents)
    assert processes_on(port) == []


@pytest.mark.parametrize(
    "args, message",
    [
        (["agents", "--connect", "localhost"], "is not an endpoint"),
        (["agents", "--connect", "tcp/127.0.0.1:7447", "--robots", "3-1"], "runs backwards"),
        (["agents", "--connect", "tcp/127.0.0.1:7447", "--robots", "a,b"], "expected ids and ranges"),
        (["agents", "--connect", "tcp/127.0.0.1:7447", "--display", "a/b"], "display name"),
        (["agents", "--connect", "tcp/127.0.0.1:7447", "-k", "0"], "at least 1"),
        (["run", "circle", "--remote-agents", "--agents-timeout", "0"], "--agents-timeout must be a positive"),
        (["run", "circle", "--agents-timeout", "5"], "goes with --remote-agents"),
        (["run", "circle", "--remote-agents", "--engine", "central"], "needs the distributed engine"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    extra = ["--out", str(tmp_path / "out")] if args[0] == "run" else []
    result = run_pixelswarm(*args, *extra, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert not (tmp_path / "out").exists()


def test_robot_ids_read_as_written():
    assert parse_ids("0-3,7") == [0, 1, 2, 3, 7]
    assert parse_ids("5, 2,2") == [2, 5]
    assert format_ids([0, 1, 2, 3, 7, 9, 10]) == "0-3, 7, 9-10"
    for bad in ("", "-1", "1-", "x", "3-1"):
        with pytest.raises(ValueError):
            parse_ids(bad)


def test_merged_host_greets_only_other_hosts_robots():
    from agent.core.params import EPUCK
    from agent.runtime import HostConfig

    a = HostConfig(robots=[0], params=EPUCK, greet=[1, 2], pursue={0: 5}, lockstep=True)
    b = HostConfig(robots=[1], params=EPUCK, greet=[0, 3], lockstep=True)
    merged = merge_configs([a, b])
    assert merged.robots == [0, 1] and merged.greet == [2, 3] and merged.pursue == {0: 5}
    assert merged.lockstep


@pytest.mark.slow
def test_remote_agents_that_leave_mid_run_are_said(tmp_path, spawned):
    """Local agents that die are said on stderr; remote ones that left said nothing (only metrics.json's
    liveliness_lost), and the progress line said it waited for a goal set."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    run = start_run(spawned, tmp_path, port, "--duration", "12", clock="realtime")
    assert wait_for(lambda: run.poll() is not None or listening(port), 30), "the run's router never listened"
    agents = start(spawned, tmp_path / "agents.err", "agents", "--connect", endpoint)
    assert len(agents_of(agents, 6)) == 6
    assert wait_for(lambda: ticks_so_far(tmp_path / "run") >= 20, 60), "the run never ticked"
    agents.send_signal(signal.SIGINT)
    finish(agents)
    assert finish(run).strip() == str(tmp_path / "run") and run.returncode == 0
    said = [ln for ln in (tmp_path / "run.err").read_text().splitlines() if "left the run" in ln]
    robots = {r for ln in said for r in parse_ids(ln.split("robots ")[1].split(" left")[0].replace(" ", ""))}
    assert robots == set(range(6)), said
