"""`pixelswarm study`: a grid of real `pixelswarm run` processes, its tables, plots, page and resuming."""

from __future__ import annotations

import base64
import itertools
import json
import math
import shutil
import signal
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import psutil
import pytest

from sim.cli.main import main
from sim.study.runner import STOP_GRACE_S
from tests.conftest import REPO, descendants, wait_for
from tests.support.study import GRID, read_csv, study

# metrics of the processes and messages of a run, which the central engine has no counterpart for (its
# commands: a distributed world steps on until it hears the end), and of its wall time
PROCESS_ONLY = {
    *("engine", "wall_s", "realtime_factor", "stepping_wall_s", "stepping_realtime_factor", "end_reason"),
    *("messages_per_robot_s", "bytes_per_robot_s", "messages_total", "bytes_total"),
    *("agent_processes", "commands_sent", "commands_applied"),
}


@pytest.mark.slow
@pytest.mark.xdist_group("study-grid")
def test_the_grid_runs_with_one_command_one_row_per_run(grid):
    rows = read_csv(grid / "out" / "runs.csv")
    expected = {(r, d, s) for r, d, s in itertools.product(["2", "4"], ["1.0", "1.5"], ["1", "2"])}
    assert {(row["robots"], row["duration"], row["seed"]) for row in rows} == expected
    assert len(rows) == 8 and len({row["id"] for row in rows}) == 8
    for row in rows:
        assert row["status"] == "done" and row["error"] == ""
        assert float(row["process_wall_s"]) > 0
        # the settings reached the runs: metrics.json says what the axes asked for
        metrics = json.loads((grid / "out" / "runs" / row["id"] / "metrics.json").read_text())
        assert metrics["robots"] == int(row["robots"])
        assert metrics["seed"] == int(row["seed"])
        assert metrics["engine"] == row["engine"] == "central"
        assert float(row["duration_s"]) <= float(row["duration"]) + 1e-9
        assert int(row["contacts"]) == metrics["contacts"]


@pytest.mark.slow
@pytest.mark.xdist_group("study-grid")
def test_summary_agrees_with_runs(grid):
    rows = read_csv(grid / "out" / "runs.csv")
    summary = read_csv(grid / "out" / "summary.csv")
    assert len(summary) == 4
    metrics = [c[: -len(".mean")] for c in summary[0] if c.endswith(".mean")]
    assert {"contacts", "min_clearance_m", "path_length_m.mean", "process_wall_s", "wall_s"} <= set(metrics)
    for condition in summary:
        mine = [r for r in rows if r["condition"] == condition["condition"]]
        assert len(mine) == 2 == int(condition["runs"])
        assert {(r["robots"], r["duration"]) for r in mine} == {(condition["robots"], condition["duration"])}
        for m in metrics:
            values = [float(r[m]) for r in mine if r[m] != ""]
            assert int(condition[f"{m}.n"]) == len(values)
            if values:
                mean = sum(values) / len(values)
                assert math.isclose(float(condition[f"{m}.mean"]), mean, rel_tol=1e-9, abs_tol=1e-12)
            if len(values) == 2:
                std = abs(values[0] - values[1]) / math.sqrt(2)
                assert math.isclose(float(condition[f"{m}.std"]), std, rel_tol=1e-9, abs_tol=1e-12)


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs.get("src", ""))
        for key in ("href", "src"):
            if key in attrs and tag != "img":
                self.links.append(attrs[key])

    def handle_data(self, data):
        self.text.append(data)


@pytest.mark.slow
@pytest.mark.xdist_group("study-grid")
def test_report_is_one_self_contained_page(grid):
    page = _Page()
    page.feed((grid / "out" / "report.html").read_text())
    page.close()
    assert len(page.images) == 2  # one per axis with more than one value
    for src in page.images:
        prefix = "data:image/png;base64,"
        assert src.startswith(prefix)
        assert base64.b64decode(src[len(prefix) :], validate=True).startswith(b"\x89PNG\r\n\x1a\n")
    assert page.links == []  # nothing to fetch
    text = "".join(page.text)
    for fact in ("cores", "python", "numpy", "zenoh", "pixelswarm", "pixelswarm study", 'scene = "swap"'):
        assert fact in text
    assert (grid / "out" / "plot_robots.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.slow
@pytest.mark.xdist_group("study-grid")
def test_resume_runs_only_what_is_missing_or_incomplete(grid, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(grid / "out", out)
    rows = read_csv(out / "runs.csv")
    deleted, incomplete = rows[0]["id"], rows[5]["id"]
    shutil.rmtree(out / "runs" / deleted)
    metrics_path = out / "runs" / incomplete / "metrics.json"
    metrics = json.loads(metrics_path.read_text())
    metrics_path.write_text(json.dumps({**metrics, "complete": False}))
    kept = {
        r["id"]: (out / "runs" / r["id"] / "metrics.json").stat().st_mtime_ns
        for r in rows
        if r["id"] not in (deleted, incomplete)
    }

    result = study(grid / "grid.toml", out, "--jobs", "2")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "8 runs, 6 already done, 2 to run" in result.stderr
    for run_id, mtime in kept.items():  # the finished runs were not run again
        assert (out / "runs" / run_id / "metrics.json").stat().st_mtime_ns == mtime
    for run_id in (deleted, incomplete):
        assert json.loads((out / "runs" / run_id / "metrics.json").read_text())["complete"] is True
    assert [r["status"] for r in read_csv(out / "runs.csv")] == ["done"] * 8
    assert not list((out / "runs").glob("*.partial"))


@pytest.mark.slow
@pytest.mark.xdist_group("study-grid")
def test_ctrl_c_while_the_report_is_written_is_one_line_and_resumes(grid, tmp_path, capsys, monkeypatch):
    """Every run done, the user presses Ctrl-C as the report is written: a one-line stop (it was a
    traceback), and the same command again writes the report."""
    out = tmp_path / "out"
    shutil.copytree(grid / "out", out)
    (out / "report.html").unlink()

    def interrupted(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr("sim.study.report.write_report", interrupted)
    assert main(["study", str(grid / "grid.toml"), "--out", str(out), "--jobs", "1"]) == 130
    said = capsys.readouterr().err
    err = said.strip().splitlines()[-1]
    assert err.startswith("pixelswarm study: stopped by SIGINT; 8 of 8 runs done and kept"), err
    assert "Traceback" not in said
    assert not (out / "report.html").exists()
    monkeypatch.undo()
    assert main(["study", str(grid / "grid.toml"), "--out", str(out), "--jobs", "1"]) == 0
    assert (out / "report.html").exists()


@pytest.mark.slow
def test_a_failed_run_is_recorded_and_the_study_goes_on(tmp_path):
    scene = tmp_path / "dies.toml"  # the central engine refuses fail events: each run exits with an error
    scene.write_text(
        'robots = 2\n[goals]\nkind = "swap"\n[layout]\nkind = "rows"\n[[events]]\nt = 1.0\nkind = "fail"\nrobot = 0\n'
    )
    spec = tmp_path / "spec.toml"
    spec.write_text('seeds = [1, 2]\n[base]\nscene = "dies.toml"\nengine = "central"\nduration = 1.0\n')
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    result = study(spec, tmp_path / "out", "--jobs", "1", tmpdir=scratch)
    assert result.returncode == 1, result.stderr[-3000:]
    assert list(scratch.iterdir()) == []  # the local cluster's scratch space too
    rows = read_csv(tmp_path / "out" / "runs.csv")
    assert [(r["id"], r["status"]) for r in rows] == [("base_seed-1", "failed"), ("base_seed-2", "failed")]
    for row in rows:
        assert "fail and tracker-outage events" in row["error"]
        record = json.loads((tmp_path / "out" / "records" / f"{row['id']}.json").read_text())
        assert (
            record["status"] == "failed"
            and record["returncode"] == 2
            and "need the distributed engine" in record["error"]
        )
    assert "Failed runs" in (tmp_path / "out" / "report.html").read_text()


@pytest.mark.slow
def test_loss_reaches_the_distributed_runs_beside_a_central_baseline(tmp_path):
    spec = tmp_path / "loss.toml"
    spec.write_text(
        'seeds = [3]\n[base]\nscene = "swap"\nrobots = 2\nengine = "distributed"\nagents_per_process = 2\n'
        'duration = 1.0\n[axes]\nloss = [0.5]\ndelay = [0.05]\n[baseline]\nengine = "central"\nloss = 0.0\n'
        "delay = 0.0\n"
    )
    result = study(spec, tmp_path / "out", "--jobs", "2")
    assert result.returncode == 0, result.stderr[-3000:]
    rows = {r["id"]: r for r in read_csv(tmp_path / "out" / "runs.csv")}
    assert set(rows) == {"loss-0.5_delay-0.05_seed-3", "baseline_seed-3"}
    lossy = rows["loss-0.5_delay-0.05_seed-3"]
    assert lossy["faults"] == "state:drop=0.5,delay=0.05,jitter=0.0"  # as the run itself records it
    assert (lossy["engine"], lossy["status"]) == ("distributed", "done")
    baseline = rows["baseline_seed-3"]
    assert (baseline["engine"], baseline["loss"], baseline["status"]) == ("central", "0.0", "done")
    assert baseline["faults"] == ""  # the central engine has none
    summary = read_csv(tmp_path / "out" / "summary.csv")
    assert [s["condition"] for s in summary] == ["loss-0.5_delay-0.05", "baseline"]


def test_a_range_axis_reaches_the_runs_and_inf_is_everyone_hearing_everyone(tmp_path):
    """The central engine honours a range (its robots run the range-limited auction in process):
    each run gets --range, inf gets none, and the report plots both."""
    spec = tmp_path / "range.toml"
    spec.write_text(
        'seeds = [1]\n[base]\nscene = "swap"\nrobots = 4\nengine = "central"\nduration = 1.0\n[axes]\nrange = [0.2, inf]\n'
    )
    result = study(spec, tmp_path / "out", "--jobs", "2")
    assert result.returncode == 0, result.stderr[-3000:]
    rows = {r["id"]: r for r in read_csv(tmp_path / "out" / "runs.csv")}
    assert set(rows) == {"range-0.2_seed-1", "range-inf_seed-1"}
    assert rows["range-0.2_seed-1"]["range_m"] == "0.2" and rows["range-inf_seed-1"]["range_m"] == ""
    assert all(r["status"] == "done" for r in rows.values())
    assert (tmp_path / "out" / "report.html").stat().st_size > 0


BAD_SPECS = {
    "unknown axis": ('seeds = [1]\n[base]\nscene = "swap"\n[axes]\nspeed = [1, 2]\n', "unknown setting 'speed'"),
    "bad value": ('seeds = [1]\n[base]\nscene = "swap"\n[axes]\nloss = [0.0, 1.5]\n', "axes.loss: 1.5"),
    "bad robots": ('seeds = [1]\n[base]\nscene = "swap"\nrobots = 0\n', "base.robots"),
    "unknown scene": ('seeds = [1]\n[base]\nscene = "no-such-scene"\n', "unknown scene 'no-such-scene'"),
    "loss on central": (
        'seeds = [1]\n[base]\nscene = "swap"\n[axes]\nengine = ["central", "distributed"]\nloss = [0.0, 0.1]\n',
        "engine central has no messages to lose",
    ),
    "bad range": ('seeds = [1]\n[base]\nscene = "swap"\n[axes]\nrange = [0.0, inf]\n', "axes.range: 0.0 must be > 0"),
    "range in real time": (
        'seeds = [1]\n[base]\nscene = "swap"\nclock = "realtime"\n[axes]\nrange = [0.5]\n',
        'needs clock = "lockstep"',
    ),
    "no seeds": ('[base]\nscene = "swap"\n', "seeds"),
    "not toml": ("seeds = [1\n", "not valid TOML"),
    "seed axis": ('seeds = [1]\n[base]\nscene = "swap"\n[axes]\nseed = [1, 2]\n', "seeds are not a setting"),
    # one id for both: the second run would overwrite the first, or be skipped as done
    "values one id names": (
        'seeds = [1]\n[base]\nscene = "swap"\n[axes]\nloss = [0.1, 0.1000000000001]\n',
        "axes.loss: 0.1 and 0.1000000000001 both name their runs loss-0.1",
    ),
}


@pytest.mark.parametrize("case", list(BAD_SPECS))
def test_a_bad_spec_is_one_line_exit_2_and_starts_nothing(case, tmp_path, capsys):
    text, message = BAD_SPECS[case]
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    assert main(["study", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pixelswarm study: error: ") and message in err, err
    assert not (tmp_path / "out").exists()


def test_bad_command_lines_exit_2(tmp_path, capsys):
    spec = tmp_path / "ok.toml"
    spec.write_text(GRID)
    for argv in (["study", str(spec), "--out", str(spec)], ["study", str(tmp_path / "missing.toml")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("pixelswarm study: error: "), err
    result = study(spec, tmp_path / "out", "--jobs", "0")  # and from a real process: its exit code
    assert result.returncode == 2 and result.stderr == "pixelswarm study: error: --jobs must be at least 1, not 0\n"
    assert not (tmp_path / "out").exists()


def interrupt_study(spec: Path, out: Path, run: str, stop: signal.Signals, timeout: float) -> tuple[int, str, list]:
    """`pixelswarm study SPEC --out OUT --jobs 1`, sent ``stop`` once ``run`` has begun (its .partial exists):
    its exit code, its stderr and the processes it had started by then."""
    command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), "--jobs", "1"]
    # Ctrl-C's SIGINT as a terminal delivers it, even if whoever started pytest ignores SIGINT
    study_process = subprocess.Popen(
        command,
        cwd=REPO,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        assert wait_for(lambda: (out / "runs" / f"{run}.partial").exists(), timeout=120)
        started = descendants(study_process.pid)
        study_process.send_signal(stop)
        _, err = study_process.communicate(timeout=timeout)
    finally:
        if study_process.poll() is None:
            study_process.kill()
            study_process.wait()
    return study_process.returncode, err, started


@pytest.mark.slow
def test_ctrl_c_stops_the_runs_it_started_and_keeps_the_finished_ones(tmp_path):
    # a short central run, then a long distributed one to interrupt: on the wall clock, as two robots in
    # lock-step converge (and end the run) so soon that a loaded machine's Ctrl-C may come after
    spec = tmp_path / "spec.toml"
    spec.write_text(
        'seeds = [1]\n[base]\nscene = "swap"\nrobots = 2\nengine = "central"\nduration = 1.0\n'
        '[baseline]\nengine = "distributed"\nagents_per_process = 2\nduration = 90.0\nclock = "realtime"\n'
    )
    out = tmp_path / "out"
    returncode, err, started = interrupt_study(spec, out, "baseline_seed-1", signal.SIGINT, timeout=120)
    assert started  # the run and its processes
    assert returncode == 130, err[-3000:]
    assert "stopped by SIGINT; 1 of 2 runs done" in err
    assert not [p.pid for p in started if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    assert json.loads((out / "runs" / "base_seed-1" / "metrics.json").read_text())["complete"] is True
    interrupted = out / "runs" / "baseline_seed-1" / "metrics.json"
    assert not interrupted.exists() or json.loads(interrupted.read_text())["complete"] is False
    assert not (out / "report.html").exists()


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stopped_study_starts_none_of_its_queued_runs(stop, tmp_path):
    """Ctrl-C or SIGTERM with runs queued: the running one stops at once, marked incomplete, and no queued
    one starts (they did, one after another, until a 45 s grace ran out); one line, exit 128 + the signal."""
    spec = tmp_path / "spec.toml"  # runs far longer than the test: each one runs until it is stopped
    spec.write_text(
        'seeds = [1, 2, 3, 4]\n[base]\nscene = "swap"\nrobots = 2\nengine = "distributed"\n'
        'agents_per_process = 2\nduration = 90.0\nclock = "realtime"\n'
    )
    out = tmp_path / "out"
    # a run stops in a second or two
    returncode, err, started = interrupt_study(spec, out, "base_seed-1", stop, timeout=STOP_GRACE_S)
    assert returncode == 128 + stop, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"pixelswarm study: stopped by {stop.name}; 0 of 4 runs done") and "Traceback" not in err
    # the queued ones never started; the running one wrote what it recorded, marked incomplete (nothing if
    # the stop came before its processes were up, as `pixelswarm run` does)
    assert {p.name for p in (out / "runs").iterdir()} <= {"base_seed-1"}
    assert [p.name for p in (out / "records").iterdir()] == ["base_seed-1.json"]
    assert json.loads((out / "records" / "base_seed-1.json").read_text())["status"] == "interrupted"
    stopped = out / "runs" / "base_seed-1" / "metrics.json"
    assert not stopped.exists() or json.loads(stopped.read_text())["complete"] is False
    assert not [p.pid for p in started if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    assert not (out / "report.html").exists()


@pytest.mark.slow
def test_without_impairment_a_distributed_run_has_every_metric_of_the_central_run(tmp_path):
    """One controller in every engine (issue 21), seen through a study: with no impairment, the
    distributed run of a seed reports what the central run of that seed reports, metric for metric;
    only what the central engine has no counterpart for (processes, messages, wall time) differs."""
    spec = tmp_path / "engines.toml"
    spec.write_text(
        'seeds = [2]\n[base]\nscene = "swap"\nrobots = 6\nclock = "lockstep"\n[axes]\n'
        'engine = ["central", "distributed"]\n'
    )
    result = study(spec, tmp_path / "out", "--jobs", "2")
    assert result.returncode == 0, result.stderr[-3000:]
    runs = tmp_path / "out" / "runs"
    central = json.loads((runs / "engine-central_seed-2" / "metrics.json").read_text())
    distributed = json.loads((runs / "engine-distributed_seed-2" / "metrics.json").read_text())
    assert central["converged"] and central["contacts"] == 0
    for key in sorted(set(central) - PROCESS_ONLY):
        assert _same(distributed.get(key), central[key]), (key, distributed.get(key), central[key])


def _same(a: object, b: object) -> bool:
    """Equal, numbers to 1e-9 (lists and tables element by element)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=0, abs_tol=1e-9)
    return a == b
