"""Shared helpers: run the real `pixelswarm` command, find and reap the processes it starts."""

from __future__ import annotations

import fcntl
import hashlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psutil
import pytest
from hypothesis import HealthCheck, settings

try:
    from _pytest.nodeid import NodeId  # pytest 9.2's structured node ids
except ImportError:  # an older pytest reads item._nodeid itself
    NodeId = None

# Property tests are seeded (same examples every run) and never fail for being slow on a loaded
# 2-core machine: a health check on generation time is not something a user relies on.
settings.register_profile(
    "pixelswarm", derandomize=True, database=None, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("pixelswarm")

REPO = Path(__file__).resolve().parent.parent

# pytest keeps each test module's assertion-rewritten bytecode in tests/__pycache__, unless writing
# bytecode is off (PYTHONDONTWRITEBYTECODE=1, as on the development machine): then every pytest
# process and every xdist worker rewrites and compiles every test module again, 5 of the 8 s it takes
# to collect the suite, three times in `make test`. The sources' own bytecode is written before a test
# run anyway (the Makefile); this turns writing on in pytest's processes only, not in the runs they start.
sys.dont_write_bytecode = False


def pixelswarm_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "sim.cli", *args]


def run_pixelswarm(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run(pixelswarm_cmd(*args), capture_output=True, text=True, timeout=timeout, cwd=REPO)


def run_scene(tmp_path: Path, scene: str, *extra: str, name: str = "run", timeout: float = 600) -> tuple[dict, dict]:
    """`pixelswarm run` of a shipped scene, a scene file or inline scene TOML, without video or plots; returns
    metrics.json and trajectory.npz."""
    return run_scenes(tmp_path, {name: (scene, *extra)}, timeout=timeout)[name]


def run_scenes(tmp_path: Path, runs: dict[str, tuple[str, ...]], timeout: float = 600) -> dict[str, tuple[dict, dict]]:
    """`pixelswarm run` of each ``name: (scene, *extra)`` (a shipped scene, a scene file or inline
    scene TOML, without video or plots), all started at once and each waited for:
    ``{name: (metrics.json, trajectory.npz)}``. A lock-step run waits on its messages more than it
    computes, so runs a test compares side by side share the CPU their waits leave, and a lock-step
    run is the same run beside another (what the tests that compare them check)."""
    procs = {}
    try:
        for name, (scene, *extra) in runs.items():
            if scene.lstrip().startswith(("robots", "name", "[", "seed")):
                path = tmp_path / f"{name}.toml"
                path.write_text(scene)
                scene = str(path)
            command = pixelswarm_cmd("run", scene, "--out", str(tmp_path / name), "--no-video", "--no-plots", "-q")
            procs[name] = subprocess.Popen(
                [*command, *extra], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
            )
        end = time.monotonic() + timeout
        for name, proc in procs.items():
            _, stderr = proc.communicate(timeout=max(end - time.monotonic(), 1.0))
            assert proc.returncode == 0, f"{name}: {stderr[-3000:]}"
    finally:
        for proc in procs.values():  # a failed or timed-out run leaves none of the others behind
            if proc.poll() is None:
                for child in descendants(proc.pid):
                    try:
                        child.kill()
                    except psutil.Error:
                        pass
                proc.kill()
                proc.wait(timeout=10)
    return {
        name: (
            json.loads((tmp_path / name / "metrics.json").read_text()),
            dict(np.load(tmp_path / name / "trajectory.npz")),
        )
        for name in runs
    }


class SharedRuns:
    """End-to-end runs (or any costly outputs) shared between tests that check different things about
    the same run.

    ``run(scene, *extra)`` is `run_scene` of that scene and those flags, made once per pytest
    session: the first test to ask runs it, under a file lock in the temporary directory every xdist
    worker of the session shares, and every later ask (in any worker) reads the same run directory.
    The key is the command line, with a scene or image file's content in place of its path, so two
    tests that write the same scene or draw the same picture into their own tmp_path share the run.
    ``once(key, make)`` does the same for whatever ``make(folder)`` writes (a study, say). Something
    that failed fails every test that asks for it, with its error, without being made again.

    Tests that share a run also carry one ``xdist_group`` mark, so that `--dist loadgroup` gives them
    one worker in turn rather than one worker waiting on the other's lock (with pytest 9.2 and
    pytest-xdist 3.8 only through pytest_collection_modifyitems below: pytest-dev/pytest-xdist#1386).
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def once(self, key: str, make: Callable[[Path], object]) -> Path:
        """The folder ``make`` filled, made by the first test of the session to ask for ``key``."""
        where = self.root / key
        with open(self.root / f"{key}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            failed, done = self.root / f"{key}.failed", self.root / f"{key}.done"
            if failed.exists():
                raise AssertionError(f"{key}, shared, failed for an earlier test:\n{failed.read_text()}")
            if not done.exists():
                where.mkdir(exist_ok=True)
                try:
                    make(where)
                except BaseException as error:  # a failed check, or the test's timeout
                    failed.write_text(f"{type(error).__name__}: {error}"[-4000:])
                    raise
                done.touch()
        return where

    def run(self, scene: str | Path, *extra: str, timeout: float = 600) -> tuple[dict, dict]:
        out = self.run_dir(scene, *extra, timeout=timeout)
        return json.loads((out / "metrics.json").read_text()), dict(np.load(out / "trajectory.npz"))

    def run_dir(self, scene: str | Path, *extra: str, timeout: float = 600) -> Path:
        """The shared run's directory (metrics.json, trajectory.npz, log.mcap, ...)."""
        text = str(scene)
        inline = text.lstrip().startswith(("robots", "name", "[", "seed"))
        source = None if inline else Path(text)
        digest = hashlib.sha256()
        if source is None:
            digest.update(b"toml\0" + text.encode())
        elif source.is_file():
            digest.update(b"file\0" + source.name.encode() + b"\0" + source.read_bytes())
        else:
            digest.update(b"name\0" + text.encode())  # a shipped scene or a folder, by name
        for arg in extra:
            digest.update(b"\0" + arg.encode())

        def make(where: Path) -> None:
            arg = text
            if source is None:
                arg = str(where / "scene.toml")
                Path(arg).write_text(text)
            elif source.is_file():
                arg = str(where / source.name)
                Path(arg).write_bytes(source.read_bytes())
            out = where / "run"
            result = run_pixelswarm(
                "run", arg, "--out", str(out), "--no-video", "--no-plots", "-q", *extra, timeout=timeout
            )
            assert result.returncode == 0, result.stderr[-3000:]

        return self.once(f"run-{digest.hexdigest()[:16]}", make) / "run"


@pytest.fixture(scope="session")
def shared_runs(tmp_path_factory, worker_id) -> SharedRuns:
    """One `SharedRuns` for the session, in a folder every xdist worker of the session sees."""
    base = tmp_path_factory.getbasetemp()
    return SharedRuns((base.parent if worker_id != "master" else base) / "shared-runs")


def ticks_so_far(out: Path) -> int:
    """How many ticks the run writing to ``out`` has recorded so far (its run.partial's tick file)."""
    from sim.outputs.ticklog import TICKS_FILE, read_ticks

    try:
        return len(read_ticks(Path(str(out) + ".partial") / TICKS_FILE)["t"])
    except (OSError, ValueError):
        return 0


def start_run(spawned: list, scene: Path | str, out: Path, *extra: str) -> subprocess.Popen:
    """`pixelswarm run` of a scene in the background, without video or plots; ``spawned`` reaps it."""
    proc = subprocess.Popen(
        pixelswarm_cmd("run", str(scene), "--out", str(out), "--no-video", "--no-plots", "-q", *extra),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(proc)
    return proc


def descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def agent_processes(pid: int) -> list[psutil.Process]:
    out = []
    for p in descendants(pid):
        try:
            cmd = p.cmdline()
        except psutil.Error:
            continue
        if "-m" in cmd and "agent" in cmd:
            out.append(p)
    return out


def agent_process(pid: int, index: int) -> psutil.Process:
    """The agent process of a run (``pid``: its launcher) whose config file is the ``index``-th: the robot's
    index where each robot has a process of its own, the host's with agents per process."""
    for p in descendants(pid):
        try:
            if any(arg.endswith(f"agents-{index:04d}.json") for arg in p.cmdline()):
                return p
        except psutil.Error:
            continue
    raise AssertionError(f"no agent process with config {index}")


def deafen(bus) -> None:
    """Make every subscription of a transport.bus.Bus deaf, as a link drop left some on a starved
    machine: still declared, hearing nothing (Bus.renew_if_due declares them again)."""
    import zenoh  # here: most tests that import this module never open a session

    for i, feed in enumerate(bus._subscriptions):
        feed.declared.undeclare()
        feed.declared = bus.session.declare_subscriber(f"nowhere/{i}", zenoh.handlers.FifoChannel(1))


def wait_for(predicate, timeout: float, interval: float = 0.1):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    return predicate()


def bus_when_listening(settings, stop):
    """A Bus on ``settings`` once the run's router listens; None if ``stop`` (an Event) is set first."""
    from transport.bus import Bus
    from transport.session import TransportError

    while True:
        try:
            return Bus(settings)
        except TransportError:  # the run's router is not listening yet
            if stop.wait(0.2):
                return None


def reap(pids: list[int]) -> list[int]:
    """Kill whatever of these (our own children) is still alive; return the ones that were."""
    alive = []
    for pid in pids:
        try:
            p = psutil.Process(pid)
            if p.status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
                p.kill()
        except psutil.NoSuchProcess:
            pass
    return alive


@pytest.fixture
def spawned():
    """Processes a test starts; any left at the end are killed (and the test fails on its own checks)."""
    procs: list[subprocess.Popen] = []
    yield procs
    for p in procs:
        for child in descendants(p.pid):
            try:
                child.kill()
            except psutil.Error:
                pass
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)


# The longest tests of the parallel passes (half a minute or more each on 2 cores, by wall time, waits
# included), started first: xdist hands tests to its workers in collection order, and a long test
# picked up at the end of the pass leaves the other workers idle meanwhile. (Tests sharing a run carry
# an xdist_group mark; `--dist loadgroup` starts those groups first, the largest first, then the rest
# in this order.) Node ids without parameters, longest first.
LONGEST_FIRST = (
    "tests/e2e/test_lockstep_faults.py::test_two_lockstep_runs_with_lost_and_delayed_states_are_the_same_run",
    "tests/e2e/test_one_controller.py::test_the_auction_is_the_same_in_every_engine",
    "tests/e2e/test_image_display_distributed.py::test_the_paper_sequence_forms_every_image_in_agent_hosts_as_in_the_central_engine",
    "tests/e2e/test_make_run.py::test_make_run_writes_a_complete_run_directory",
    "tests/e2e/test_image_display_distributed.py::test_two_of_fourteen_agents_die_and_twelve_reform_the_image",
    "tests/e2e/test_collision_avoidance.py::test_loss_and_delay_on_states_cause_no_contact",
    "tests/e2e/test_range_auction.py::test_a_hundred_robot_picture_in_hosts_forms_with_a_quarter_of_its_diameter_in_reach",
    "tests/e2e/test_one_controller.py::test_central_and_distributed_runs_of_one_seed_are_the_same_run",
    "tests/e2e/test_one_controller.py::test_with_rounds_per_tick_bounded_blocks_span_ticks_and_every_engine_runs_the_same",
    "tests/e2e/test_image_display_distributed.py::test_auction_survives_loss_and_delay",
    "tests/unit/test_bidder.py::test_lossy_network_agrees_on_one_owner_per_goal",
    "tests/unit/test_codec_fuzz.py::test_every_kind_decodes_what_was_encoded_or_drops_it_with_one_reason",
    "tests/e2e/test_study.py::test_the_grid_runs_with_one_command_one_row_per_run",
    "tests/integration/test_paper_figures.py::test_quick_reproduction_writes_sane_figures",
    "tests/e2e/test_runtime.py::test_lockstep_is_reproducible_and_hosts_match_processes",
    "tests/e2e/test_image_display_distributed.py::test_hundred_holonomic_robots_in_agent_hosts",
    "tests/e2e/test_faults_recovery.py::test_a_tenth_of_the_agents_killed_at_once_and_the_rest_form_the_image_for_the_survivors",
    "tests/unit/test_animation.py::test_fourteen_agents_play_four_keyframes_of_the_story_over_zenoh",
    "tests/e2e/test_restarts.py::test_a_lockstep_host_stalled_past_its_lease_is_heard_dead_and_back_and_the_show_completes",
)


@pytest.hookimpl(trylast=True)  # after pytest-xdist's own hook, which names each test's group
def pytest_collection_modifyitems(config, items):
    for item in items:
        # --dist loadgroup: pytest-xdist 3.8 puts a test's xdist_group in its node id (test@group) by
        # setting item._nodeid, which pytest 9.2 no longer reads (its node ids are structured), so no
        # test was grouped and tests sharing a run waited for each other on two workers
        # (pytest-dev/pytest-xdist#1386). Set the structured id to the same string.
        grouped = item.__dict__.get("_nodeid")
        if NodeId is not None and isinstance(grouped, str) and grouped != item.nodeid:
            item._id = NodeId.parse(grouped)
        _in_one_pass(item)
    rank = {nodeid: k for k, nodeid in enumerate(LONGEST_FIRST)}
    # stable: the rest keep their order (a node id without parameters, or loadgroup's @group)
    items.sort(key=lambda item: rank.get(item.nodeid.split("[")[0].split("@")[0], len(rank)))


def _in_one_pass(item: pytest.Item) -> None:
    """A wall-clock test is slow and either wall_clock or serial: else make test would run it in the fast
    tier or the lock-step pass, beside other work, or in two passes (docs/testing.md)."""
    wall = [name for name in ("wall_clock", "serial") if item.get_closest_marker(name)]
    if wall and (len(wall) > 1 or not item.get_closest_marker("slow")):
        raise pytest.UsageError(f"{item.nodeid}: mark a wall-clock test slow and one of wall_clock, serial")


def assert_usage_error(tmp_path: Path, message: str, *args: str) -> None:
    """`pixelswarm run ARGS --out DIR` refuses in one line, exit 2, no traceback, and writes nothing."""
    result = run_pixelswarm("run", *args, "--out", str(tmp_path / "r"), timeout=60)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "r").exists() and not (tmp_path / "r.partial").exists()


# What every metrics.json holds (docs/outputs.md), whatever the engine
METRIC_KEYS = (
    "robots",
    "duration_s",
    "wall_s",
    "realtime_factor",
    "min_clearance_m",
    "contacts",
    "max_overlap_m",
    "converged",
    "time_to_converge_s",
    "path_length_m",
    "messages_per_robot_s",
    "bytes_per_robot_s",
    "missed_ticks",
    "agents_crashed",
)

# The paper's 14 e-pucks on their starting grid (scenes/paper-sequence.toml), in lock-step: a scene
# of them is a name before this and its steps after it.
PAPER_E_PUCKS = """
robots = 14
seed = 1
clock = "lockstep"
[robot]
kinematics = "diffdrive"
[layout]
kind = "grid"
spacing = 0.2
"""

# A small show for the fault and restart tests: robots on a grid form a disk.
DISK = """
name = "faults"
robots = {robots}
seed = 5
clock = "{clock}"
[layout]
kind = "grid"
spacing = {spacing}
[[steps]]
shape = "disk"
hold = {hold}
[end]
converge_hold = {converge_hold}
{events}
"""


def write_disk(tmp_path: Path, robots: int = 10, clock: str = "lockstep", hold: float = 30.0, **kw: object) -> Path:
    path = tmp_path / "faults.toml"
    text = DISK.format(
        robots=robots,
        clock=clock,
        hold=hold,
        spacing=kw.get("spacing", 0.2),
        converge_hold=kw.get("converge_hold", 100.0),
        events=kw.get("events", ""),
    )
    path.write_text(text)
    return path
