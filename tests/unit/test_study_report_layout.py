"""The study report reads in a 1280-pixel window (sim.study.report): the summary table fits, and a key
metric with one value in every run (contacts 0 throughout) is said in one line, not plotted.

The study is written, not run: metrics.json files of a mission-sized spec (3 axes of 3 values, a
baseline, 2 seeds: 60 runs), seeded, so only the report is under test."""

from __future__ import annotations

import html
import json
import os
import random
import re
import shutil
import signal
import subprocess

import pytest

from sim.study import report as study_report
from sim.study.report import KEY_METRICS, write_report
from sim.study.spec import StudyDir, load_spec

# --dist loadgroup gives the module one xdist worker: its module fixture (the written report) is made
# once, not once on each worker
pytestmark = pytest.mark.xdist_group("study-report")

SPEC = """
name = "wide"
seeds = [1, 2]
[base]
scene = "paper-sequence"
robots = 14
engine = "distributed"
agents_per_process = 7
clock = "lockstep"
[axes]
loss = [0.0, 0.2, 0.5]
delay = [0.0, 0.25, 0.5]
range = [0.15, 1.5, inf]
[baseline]
engine = "central"
loss = 0.0
delay = 0.0
"""
WINDOW_PX = 1280
BODY_PX = 1152  # report.html's body: at most 72em of 16 px
CHAR_PX, CELL_PX = 8, 13  # a character of the table's 0.85em sans-serif (bold headers: wider), a cell's padding


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The written study's report.html, and the metrics each axis's plot was drawn with (once a
    module: the plots take seconds)."""
    tmp_path = tmp_path_factory.mktemp("study-report")
    spec_path = tmp_path / "wide.toml"
    spec_path.write_text(SPEC)
    spec = load_spec(spec_path)
    study = StudyDir(tmp_path / "study")
    rng = random.Random(7)
    for run in spec.runs():
        metrics = {
            "complete": True,
            "contacts": 0,
            "min_clearance_m": rng.uniform(0.01, 0.1),
            "time_to_converge_s": rng.uniform(20, 90),
            "converged": rng.random() < 0.7,
            "path_length_m": [rng.uniform(1, 3) for _ in range(14)],
            "missed_ticks": rng.randint(0, 50),
            "late_commands": rng.randint(0, 9),
            "orca_fallbacks": rng.randint(0, 400),
        }
        (study.run_dir(run)).mkdir(parents=True)
        (study.run_dir(run) / "metrics.json").write_text(json.dumps(metrics))
        study.write_record(run, {"status": "done", "process_wall_s": rng.uniform(50, 200)})
    plotted: dict[str, list[str]] = {}
    plot_axis = study_report.plot_axis

    def spy(spec, axis, rows, metrics):
        plotted[axis] = list(metrics)
        return plot_axis(spec, axis, rows, metrics)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(study_report, "plot_axis", spy)
        return write_report(spec, study, "pixelswarm study wide.toml"), plotted


def _summary(page: str) -> list[list[str]]:
    """The summary table's cells, row by row, each cell as its pieces between line-break opportunities."""
    table = page[page.index("<table class='summary'>") :]
    table = table[: table.index("</table>")]
    return [
        [[html.unescape(p) for p in cell.split("<wbr>")] for cell in re.findall(r"<t[hd]>(.*?)</t[hd]>", row)]
        for row in re.findall(r"<tr>(.*?)</tr>", table)
    ]


def test_a_metric_the_same_in_every_run_is_one_line_not_a_plot(report):
    path, plotted = report
    page = path.read_text()
    assert "<p>The same in every finished run (not plotted): contacts 0.</p>" in page
    assert set(plotted) == {"loss", "delay", "range"}
    for metrics in plotted.values():
        assert "contacts" not in metrics and set(metrics) == set(KEY_METRICS) - {"contacts"}
    head = ["".join(cell) for cell in _summary(page)[0]]
    assert "contacts" not in head and "min_clearance_m" in head
    summary = (path.parent / "summary.csv").read_text()
    assert "contacts.mean" in summary  # the data keep it: only the page says it once


def test_the_summary_table_fits_the_window_at_its_narrowest(report):
    """Its narrowest width, each column as wide as its longest unbreakable piece (a cell does not
    wrap; a header wraps after _ and .), fits the report's body, itself inside 1280 pixels."""
    rows = _summary(report[0].read_text())
    head = ["".join(cell) for cell in rows[0]]
    assert head[:4] == ["baseline", "loss", "delay", "range"] and "failed" not in head  # no run failed
    widest = [max(len(piece) for piece in cell) for cell in rows[0]]
    for row in rows[1:]:
        assert len(row) == len(widest)
        widest = [max(w, len("".join(cell))) for w, cell in zip(widest, row)]
    assert sum(CHAR_PX * w + CELL_PX for w in widest) <= BODY_PX < WINDOW_PX


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium on this machine")
def test_in_chromium_the_report_does_not_scroll_sideways_in_a_1280_pixel_window(report, tmp_path):
    page = report[0].read_text()
    measure = (
        "<script>const t = document.querySelector('.summary'); t.style.width = 'min-content';"
        "const body = document.body.getBoundingClientRect();"
        "document.body.dataset.fit = [document.documentElement.scrollWidth, window.innerWidth,"
        " Math.round(t.getBoundingClientRect().right), Math.round(body.right)].join(' ');</script></body>"
    )
    probe = report[0].with_name("probe.html")
    probe.write_text(page.replace("</body>", measure))
    command = [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}"]
    command += [f"--window-size={WINDOW_PX},900", "--dump-dom", probe.as_uri()]
    browser = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        dom, _ = browser.communicate(timeout=60)
    finally:  # its helper processes are in the session it leads, made here
        try:
            os.killpg(browser.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        browser.wait()
    found = re.search(rb'data-fit="(\d+) (\d+) (\d+) (\d+)"', dom)
    assert found, dom[-2000:]
    scroll, inner, table_right, body_right = map(int, found.groups())
    assert inner == WINDOW_PX and scroll <= inner  # nothing wider than the window
    assert table_right <= body_right  # the table at its narrowest inside the page's column


def test_constant_metrics_are_those_with_one_value_in_every_finished_run():
    rows = [{"status": "done", "contacts": 0, "converged": 1}, {"status": "done", "contacts": 0, "converged": 1}]
    rows.append({"status": "failed"})
    assert study_report.constant_metrics(rows, ["contacts", "converged"]) == {"contacts": 0, "converged": 1}
    rows[1]["converged"] = 0
    assert study_report.constant_metrics(rows, ["contacts", "converged"]) == {"contacts": 0}


def test_figures_have_no_exponent_where_digits_read_better():
    assert study_report._mean_std(121.4, 150.2) == "121 ± 150"
    assert study_report._mean_std(0.04528, 0.00045) == "0.0453 ± 0.00045"
    assert study_report._mean_std(2.0, float("nan")) == "2"
