"""A restarted agent is heard again at once (issue 40).

An agent process killed outright (SIGKILL) and started again with the same command line, as a
robot's computer would start it again, is a sender that went back: its ticks begin anew where the
others' lines still hold its old ones (transport.plausible). The world must apply its robot's
commands again within a second of the new process saying it is alive, the new process must say so
within its start-up, and the show must complete without a contact: once in lock-step (the default
clock), once in real time.

"Heard again" is measured in the run's own log (log.mcap), on one clock: every message there is
stamped with the wall time the recorder received it. From the liveliness event that says the robot's
agent is alive again, to the first tick of the world (/sim/truth) whose count of commands applied
to that robot has grown. The world publishes a tick's truth before it applies that tick's commands,
so this counts up to one tick more than the command took: the measure errs long, never short. The
new process's start-up is from just before the test starts it (test's clock, the same wall clock)
to that liveliness event.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from sim.outputs.ticklog import TICKS_FILE, read_ticks
from tests.conftest import REPO, agent_process, start_run, wait_for, write_disk
from tests.support.outputs import logged as mcap_logged

ROBOTS = 10
VICTIM = 4
TOLERANCE = 0.01  # m: the show completes when every robot is this close to its goal at the end
HEARD_WITHIN = 1.0  # s (issue 40)
STARTED_WITHIN = 10.0  # s from starting the process to its liveliness: imports and a zenoh session (4.7 s seen
# on 2 cores at a load of 12), not the 30 s of a wait that the restarted agent cannot end


def ticks_so_far(out: Path) -> int:
    try:
        return len(read_ticks(Path(str(out) + ".partial") / TICKS_FILE)["t"])
    except (OSError, ValueError):
        return 0


def logged(path: Path, topics: set[str]) -> list[tuple[float, str, dict]]:
    """(wall time the recorder received it, topic, message) of every message of these topics."""
    return [(log_time / 1e9, topic, message) for log_time, topic, message in mcap_logged(path, topics)]


def heard_again(run: Path, robot: int, killed_at: float) -> dict[str, float]:
    """Wall times (the recorder's) of the robot's agent coming alive again after ``killed_at``, of its
    first command heard after that, and of the first tick whose truth shows a command of that robot
    applied after that (and that tick)."""
    events = logged(run / "log.mcap", {"/alive", "/sim/truth"})
    alive = [
        t
        for t, topic, m in events
        if topic == "/alive" and m["role"] == "agent" and m["id"] == str(robot) and m["alive"] and t > killed_at
    ]
    assert alive, "the restarted agent never said it was alive"
    applied = [(t, m["tick"], m["records"]["applied"][robot]) for t, topic, m in events if topic == "/sim/truth"]
    before = [n for t, _, n in applied if t <= alive[0]]
    count = before[-1] if before else 0
    after = [(t, tick) for t, tick, n in applied if t > alive[0] and n > count]
    assert after, "no command of the restarted robot was ever applied"
    commands = logged(run / "log.mcap", {"/cmd"})
    sent = [t for t, _, m in commands if t > alive[0] and robot in m["records"]["robot"]]
    return {"alive": alive[0], "sent": sent[0] if sent else np.nan, "applied": after[0][0], "tick": after[0][1]}


def restart_run(
    tmp_path: Path, spawned: list, clock: str, hold: float, converge_hold: float, kill_after: int, down: float
):
    """A run whose robot VICTIM's agent is killed after ``kill_after`` ticks and started again ``down``
    seconds later. ``converge_hold``: display seconds the display stays converged before the run ends;
    long enough that the nine, re-formed meanwhile, do not end the run before the restarted agent
    is back."""
    scene = write_disk(tmp_path, ROBOTS, clock, hold, converge_hold=converge_hold)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out)
    assert wait_for(lambda: ticks_so_far(out) >= kill_after, timeout=120), proc.stderr.read() if proc.poll() else ""
    victim = agent_process(proc.pid, VICTIM)
    command = victim.cmdline()
    killed_at = time.time()
    victim.send_signal(signal.SIGKILL)
    victim.wait(timeout=10)
    time.sleep(down)
    started_at = time.time()
    again = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    spawned.append(again)  # the robot's computer started its agent again, by hand
    try:
        _, stderr = proc.communicate(timeout=240)
    finally:
        again.send_signal(signal.SIGTERM)
        again.wait(timeout=20)
    assert proc.returncode == 0, stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    traj = dict(np.load(out / "trajectory.npz"))
    times = heard_again(out, VICTIM, killed_at)
    times.update(killed=killed_at, started=started_at)
    return m, traj, times


def assert_show_completed(traj: dict) -> None:
    err = np.hypot(*(traj["pose"][-1, :, :2] - traj["goal"][-1]).T)
    assert (traj["assignment_epoch"][-1] == traj["goal_set_epochs"][-1]).all()
    assert np.all(err <= TOLERANCE), np.round(err * 1000).astype(int).tolist()


def report(clock: str, times: dict[str, float]) -> str:
    alive = times["alive"]
    return (
        f"{clock}: alive {alive - times['started']:.2f} s after the new process started; its first command "
        f"heard {times['sent'] - alive:.3f} s and applied {times['applied'] - alive:.3f} s after that (tick "
        f"{times['tick']})"
    )


def assert_heard_again(clock: str, times: dict[str, float]) -> None:
    print(report(clock, times))
    assert times["alive"] - times["started"] <= STARTED_WITHIN, report(clock, times)
    assert times["applied"] - times["alive"] <= HEARD_WITHIN, report(clock, times)


@pytest.mark.slow
@pytest.mark.serial  # a bound in wall time
def test_a_lockstep_agent_killed_and_started_again_is_heard_within_a_second(tmp_path, spawned):
    m, traj, times = restart_run(tmp_path, spawned, "lockstep", hold=40.0, converge_hold=8.0, kill_after=30, down=0.5)
    assert_heard_again("lockstep", times)
    assert m["contacts"] == 0 and m["agents_crashed"] == 1 and m["crashes"][0]["robots"] == [VICTIM]
    assert traj["goal_set_robots"][-1].all()  # back in the newest goal set
    assert m["end_reason"] == "converged"
    assert_show_completed(traj)


@pytest.mark.slow
@pytest.mark.serial
def test_a_realtime_agent_killed_and_started_again_is_heard_within_a_second(tmp_path, spawned):
    m, traj, times = restart_run(tmp_path, spawned, "realtime", hold=25.0, converge_hold=6.0, kill_after=30, down=2.0)
    assert_heard_again("realtime", times)
    assert m["contacts"] == 0 and m["agents_crashed"] == 1 and m["crashes"][0]["robots"] == [VICTIM]
    members = traj["goal_set_robots"]
    assert members[:, VICTIM].any() and not members[:, VICTIM].all()  # dropped from a goal set while down ...
    assert members[-1].all()  # ... and in the newest again: it rejoined the auction
    assert m["end_reason"] == "converged"
    assert_show_completed(traj)


STALL = 2.5  # s: past a link's lease (2 s; a process is heard dead after about 1.5 s of silence)


@pytest.mark.slow
def test_a_lockstep_host_stalled_past_its_lease_is_heard_dead_and_back_and_the_show_completes(tmp_path, spawned):
    """A host whose process stalls (SIGSTOP, as a machine too busy or a laptop lid) is heard dead, and the
    world and the other host's rounds go on without its robots; back in the same life, it takes the world's
    next tick however far ahead, and every host bids again from a new goal set. Before, the two hosts could
    part for good (the host refused the world's clock as one from the future, or took the new set up at
    another tick than the other host): every tick waited ROUND_CAP (30 s), and CI timed out."""
    # the world goes on without the stalled robots, as fast as the machine lets it: a fast world runs tens of
    # seconds of display time meanwhile, so the show needs room to converge and hold (it ends once it has)
    scene = write_disk(tmp_path, ROBOTS, "lockstep", 80.0, converge_hold=8.0)
    out = tmp_path / "run"
    proc = start_run(spawned, scene, out, "--agents-per-process", str(ROBOTS // 2))
    assert wait_for(lambda: ticks_so_far(out) >= 30, timeout=120), proc.stderr.read() if proc.poll() else ""
    stalled = agent_process(proc.pid, 1)  # the second host
    stalled.send_signal(signal.SIGSTOP)
    time.sleep(STALL)
    stalled.send_signal(signal.SIGCONT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    traj = dict(np.load(out / "trajectory.npz"))
    assert m["contacts"] == 0 and m["end_reason"] == "converged"
    assert traj["goal_set_epochs"][-1] >= 2  # a new goal set for the robots heard dead and back
    assert_show_completed(traj)
    # the world went on without the stalled robots: the run is not its seed's alone, and says so
    assert m["missed_ticks"] + sum(m["lockstep_waits_given_up"].values()) > 0
    assert "this run may differ from another run of its seed" in stderr, stderr[-3000:]


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_an_agent_started_again_gets_a_new_goal_set_and_so_in_lockstep_does_one_heard_dead_and_back(clock):
    """Back within the coordinator's debounce, a restarted agent leaves the live robots as they were,
    yet it bids only in goal sets published after it joined: the coordinator tells the restart (a new
    incarnation of the agent) from a blip of its link (the same one back). In lock-step the blip takes a
    new set too: the other hosts may have closed rounds without the agent while it was heard dead, and
    they never met in a round again (the stalled-host test above)."""
    from coordinator import service
    from coordinator.scene import scene_from_dict
    from tests.support.fake_bus import Bus
    from transport.codec import Tick

    grid = {"kind": "grid", "spacing": 0.2}
    scene = scene_from_dict(
        {"robots": 4, "seed": 5, "clock": clock, "layout": grid, "steps": [{"shape": "disk", "hold": 30}]}
    )
    bus = Bus()
    coordinator = service.Coordinator(bus, scene)
    first, again = "0000000a", "0000000b"  # lives as Bus.incarnation makes them
    bus.alive.items = [("agent", str(r), True, 0.0, first) for r in range(4)]
    bus.clock.items = [("clock", Tick(0, 0.0, 0.1))]
    assert coordinator._follow_show() and bus.published[-1].epoch == 1
    lockstep, epochs = clock == "lockstep", 1
    for k, life in enumerate((first, again), start=1):  # a blip, then a restart
        bus.alive.items = [("agent", "2", False, 0.0, first), ("agent", "2", True, 0.0, life)]
        bus.clock.items = [("clock", Tick(k, k * 0.1, 0.1))]  # the same set at the same tick is a replay
        assert not coordinator._follow_show()  # debounced, as any change in the live robots
        time.sleep(service.SETTLE_S + 0.05)
        assert coordinator._follow_show() == (lockstep or life == again)
        epochs += lockstep or life == again
        assert bus.published[-1].epoch == epochs and bus.published[-1].robots.tolist() == [0, 1, 2, 3]
        # lock-step: no warm start the new incarnation (or the stalled one) might not share, so every host
        # starts the auction from the same board and bound of rounds a tick
        assert bus.published[-1].warm_start is None or not lockstep
        assert not coordinator._follow_show()  # once
