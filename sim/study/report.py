"""The report of a study: runs.csv (a row per run: settings, seed, status and metrics.json's scalars),
summary.csv (a row per condition: mean, std and n over its finished runs), one PNG per axis, report.html."""

from __future__ import annotations

import base64
import contextlib
import csv
import html
import importlib.metadata
import io
import math
import os
import platform
import re
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from sim.study.spec import Spec, StudyDir, write_text

# What a decentralisation study looks at first (paper 7: safety, convergence, path length, timeliness).
KEY_METRICS = tuple(
    "contacts min_clearance_m time_to_converge_s converged path_length_m.mean missed_ticks late_commands orca_fallbacks".split()
)
NOT_SUMMARISED = {"seed"}  # numbers that name a run rather than measure it


# --- Rows -----------------------------------------------------------------------------------------
def flatten(metrics: dict[str, Any]) -> dict[str, Any]:
    """The scalars of metrics.json: nested tables one level down as `table.key`, number lists as `key.mean`."""
    out: dict[str, Any] = {}
    for key, value in metrics.items():
        if isinstance(value, dict):
            out.update({f"{key}.{sub}": v for sub, v in value.items() if isinstance(v, bool | int | float | str)})
        elif isinstance(value, list) and value and all(_is_number(v) for v in value):
            out[f"{key}.mean"] = float(np.mean(value))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for k, entry in enumerate(value):  # a table per image step: steps.<k>.converged_at, ...
                out.update({f"{key}.{k}.{sub}": v for sub, v in entry.items() if _is_scalar(v)})
        elif _is_scalar(value):
            out[key] = value
    return {k: int(v) if isinstance(v, bool) else v for k, v in out.items()}


def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(value, bool | int | float | str)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def collect(spec: Spec, study: StudyDir) -> tuple[list[str], list[dict[str, Any]]]:
    """One row per run of the spec, in the spec's order, and the column names."""
    settings = spec.columns()
    head = ["id", "condition", *settings, "seed", "status", "process_wall_s", "error"]
    metric_names: dict[str, None] = {}
    rows = []
    for run in spec.runs():
        metrics = study.metrics(run)
        record = study.record(run)
        status = "done" if metrics is not None else record.get("status", "not run")
        row: dict[str, Any] = {"id": run.id, "condition": run.condition, "seed": run.seed, "status": status}
        row.update({k: run.settings.get(k) for k in settings})
        row["process_wall_s"] = record.get("process_wall_s") if status == record.get("status") else None
        said = [line.strip() for line in record.get("error", "").splitlines() if line.strip()]
        row["error"] = said[-1] if said and status == "failed" else ""  # its last line
        if metrics is not None:
            flat = flatten(metrics)
            metric_names.update(dict.fromkeys(k for k in flat if k not in head))
            row.update({k: v for k, v in flat.items() if k not in head})
        rows.append(row)
    return head + list(metric_names), rows


def summarise(spec: Spec, columns: list[str], rows: list[dict[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    """Per condition: runs, failed, then mean, std (ddof 1) and n of each numeric column over finished runs."""
    settings = spec.columns()
    numeric = [
        c for c in columns if c not in settings and c not in NOT_SUMMARISED and any(_is_number(r.get(c)) for r in rows)
    ]
    head = ["condition", *settings, "runs", "failed", *(f"{c}.{s}" for c in numeric for s in ("mean", "std", "n"))]
    out = []
    for condition, _ in spec.conditions():
        mine = [r for r in rows if r["condition"] == condition]
        done = [r for r in mine if r["status"] == "done"]
        row = {"condition": condition, "runs": len(done), "failed": sum(r["status"] == "failed" for r in mine)}
        row.update({k: mine[0][k] for k in settings})
        for c in numeric:
            row.update(zip((f"{c}.mean", f"{c}.std", f"{c}.n"), stats([r.get(c) for r in done])))
        out.append(row)
    return head, out


def stats(values: list[Any]) -> tuple[float, float, int]:
    """Mean, sample standard deviation (NaN below two values) and n of the finite numbers given."""
    x = np.array([float(v) for v in values if _is_number(v) and math.isfinite(v)])
    if not x.size:
        return math.nan, math.nan, 0
    return float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else math.nan, int(x.size)


def to_csv(head: list[str], rows: list[dict[str, Any]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=head, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: _cell(row.get(k)) for k in head} for row in rows)
    return buffer.getvalue()


def _cell(value: Any) -> Any:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""  # missing, or NaN: an empty cell reads as missing in every spreadsheet
    return repr(value) if isinstance(value, float) else value


# --- Plots: each key metric against each axis, seeds' spread, the baseline beside -----------------
def plot_axis(spec: Spec, axis: str, rows: list[dict[str, Any]], metrics: list[str]) -> bytes:
    """A PNG: one panel per metric against `axis`; a series per value of the other axes (mean, std
    bars, each seed a dot); a baseline that fixes `axis` is a band (mean +- std) across the panel."""
    from matplotlib.figure import Figure  # its own Agg canvas at savefig: no pyplot state

    values = spec.axes[axis]
    numeric = all(_is_number(v) and math.isfinite(v) for v in values)  # inf (a range): evenly spaced
    position = {v: (v if numeric else i) for i, v in enumerate(values)}
    others = [a for a in spec.axes if a != axis]
    grid = [r for r in rows if r["status"] == "done" and not r["condition"].startswith("baseline")]
    base = [r for r in rows if r["status"] == "done" and r["condition"].startswith("baseline")]
    series: dict[tuple, list[dict[str, Any]]] = {}
    for r in grid:
        series.setdefault(tuple(r[a] for a in others), []).append(r)

    ncols = min(3, len(metrics))
    nrows = math.ceil(len(metrics) / ncols)
    fig = Figure(figsize=(4.2 * ncols, 3.2 * nrows), dpi=90)
    for k, metric in enumerate(metrics):
        ax = fig.add_subplot(nrows, ncols, k + 1)
        _plot_grid(ax, spec, axis, series, metric, position)
        _plot_baselines(ax, spec, axis, base, metric, position)
        ax.set_title(metric, fontsize=10)
        ax.set_xlabel(axis)
        ax.set_xticks(list(position.values()), [_short(v) for v in values])
        ax.grid(alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return buffer.getvalue()


def _plot_grid(
    ax: Any, spec: Spec, axis: str, series: dict[tuple, list[dict[str, Any]]], metric: str, position: dict[Any, Any]
) -> None:
    """The grid's series in one panel: mean and std bars over the seeds at each value of `axis`,
    each seed a dot."""
    others = [a for a in spec.axes if a != axis]
    span = (max(position.values()) - min(position.values())) or 1.0
    for j, (key, members) in enumerate(sorted(series.items(), key=lambda kv: str(kv[0]))):
        label = ", ".join(f"{a}={_short(v)}" for a, v in zip(others, key)) or spec.name
        offset = (j - (len(series) - 1) / 2) * 0.02 * span  # side by side, not on top of each other
        xs, means, stds = [], [], []
        for v in spec.axes[axis]:
            m, s, n = stats([r.get(metric) for r in members if r[axis] == v])
            if n:
                xs.append(position[v] + offset)
                means.append(m)
                stds.append(0.0 if math.isnan(s) else s)
        line = ax.errorbar(xs, means, yerr=stds, marker="o", capsize=3, label=label)
        dots = [(position[r[axis]] + offset, r.get(metric)) for r in members if _is_number(r.get(metric))]
        if dots:
            dot_x, dot_y = zip(*dots)
            ax.scatter(dot_x, dot_y, s=10, alpha=0.45, color=line[0].get_color())


def _plot_baselines(
    ax: Any, spec: Spec, axis: str, base: list[dict[str, Any]], metric: str, position: dict[Any, Any]
) -> None:
    """Each baseline condition in one panel: a band (mean +- std) if it fixes `axis`, else a series."""
    values = spec.axes[axis]
    for condition in dict.fromkeys(r["condition"] for r in base):
        mine = [r for r in base if r["condition"] == condition]
        m, s, n = stats([r.get(metric) for r in mine])
        if not n:
            continue
        words = ", ".join(f"{k}={_short(v)}" for k, v in (spec.baseline or {}).items())
        label = f"{condition} ({words}, n={n})"
        if axis in (spec.baseline or {}):
            ax.axhline(m, color="0.3", linestyle="--", label=label)
            if not math.isnan(s):
                ax.axhspan(m - s, m + s, color="0.5", alpha=0.2)
        else:  # the baseline varies along this axis too: its own series
            by = {v: stats([r.get(metric) for r in mine if r[axis] == v]) for v in values}
            xs = [position[v] for v in values if by[v][2]]
            ax.errorbar(xs, [by[v][0] for v in values if by[v][2]], marker="s", color="0.3", label=label)


def _short(value: Any) -> str:
    return format(value, ".6g") if isinstance(value, float) else str(value)


# --- report.html and the files --------------------------------------------------------------------
def machine_and_software() -> dict[str, str]:
    out = {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cores": str(os.cpu_count()),
        "python": platform.python_version(),
    }
    for name, dist in (("numpy", "numpy"), ("zenoh", "eclipse-zenoh"), ("pixelswarm", "pixelswarm")):
        try:
            out[name] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    root = Path(__file__).resolve().parents[1]
    git = ["git", "-C", str(root), "describe", "--always", "--dirty"]
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        result = subprocess.run(git, capture_output=True, text=True, timeout=10)
        if result.returncode == 0 and result.stdout.strip():
            out["pixelswarm source"] = result.stdout.strip()
    return out


def _table(head: list[str], rows: list[list[Any]], css_class: str = "") -> str:
    cells = "".join(f"<th>{_breakable(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{_breakable(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table{f' class={css_class!r}' if css_class else ''}><tr>{cells}</tr>{body}</table>"


def _breakable(text: Any) -> str:
    """Escaped, with a line-break opportunity after each ``_`` and ``.`` of a word: a browser does not
    break ``time_to_converge_s`` on its own, and such headers would widen the table past the window."""
    return "<wbr>".join(html.escape(part) for part in _BREAK_AFTER.split(str(text)))


_BREAK_AFTER = re.compile(r"(?<=[_.])(?=[A-Za-z])")  # after _ or . before a letter (not in 0.25)


def constant_metrics(rows: list[dict[str, Any]], metrics: list[str]) -> dict[str, Any]:
    """The metrics that have one value in every finished run (e.g. contacts 0 throughout), by name:
    a plot of them shows nothing, so the report says them in one line instead."""
    done = [r for r in rows if r["status"] == "done"]
    values = {m: {r.get(m) for r in done} for m in metrics}
    return {m: next(iter(v)) for m, v in values.items() if len(v) == 1 and _is_number(next(iter(v)))}


def render_html(
    spec: Spec,
    command: str,
    rows: list[dict[str, Any]],
    summary: list[dict[str, Any]],
    plots: dict[str, bytes],
    metrics: list[str],
    constant: dict[str, Any],
) -> str:
    """``metrics``: the key metrics plotted and in the summary table; ``constant``: those with one
    value in every finished run, said in one line."""
    done = sum(r["status"] == "done" for r in rows)
    failed = [r for r in rows if r["status"] == "failed"]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>pixelswarm study {html.escape(spec.name)}</title>",
        "<style>body{font-family:sans-serif;max-width:72em;margin:1em auto;padding:0 1em}"
        "table{border-collapse:collapse;font-size:0.85em}td,th{border:1px solid #ccc;padding:2px 6px}"
        ".summary td{white-space:nowrap}"
        "pre{background:#f4f4f4;padding:0.5em;overflow-x:auto}img{max-width:100%}</style></head><body>",
        f"<h1>pixelswarm study: {html.escape(spec.name)}</h1>",
        f"<p>{done} of {len(rows)} runs done, {len(failed)} failed; scene {html.escape(spec.scene)}, "
        f"seeds {html.escape(', '.join(map(str, spec.seeds)))}.</p>",
        "<h2>Reproduce</h2>",
        f"<p>Save the spec below as spec.toml (the study directory holds a copy) and run:</p>"
        f"<pre>{html.escape(command)}</pre>",
        "<h2>Spec</h2>",
        f"<pre>{html.escape(spec.text)}</pre>",
        "<h2>Machine and software</h2>",
        _table(["what", "value"], [[k, v] for k, v in machine_and_software().items()]),
        "<h2>Plots</h2>",
        "<p>Each point: the mean over the seeds, bars one standard deviation, dots the seeds; "
        "a dashed line and grey band: the baseline's mean and standard deviation.</p>",
    ]
    if constant:
        same = ", ".join(f"{html.escape(m)} {_short(v)}" for m, v in constant.items())
        parts.append(f"<p>The same in every finished run (not plotted): {same}.</p>")
    for axis, png in plots.items():
        data = base64.b64encode(png).decode("ascii")
        parts.append(f"<h3>against {html.escape(axis)}</h3>")
        parts.append(f'<img alt="key metrics against {html.escape(axis)}" src="data:image/png;base64,{data}">')
    if not plots:
        parts.append("<p>No plot: no axis with two or more values, no finished run, or no key metric that varies.</p>")
    parts += ["<h2>Summary (mean &plusmn; std over seeds)</h2>", summary_table(spec, summary, metrics)]
    if failed:
        parts += ["<h2>Failed runs</h2>", _table(["run", "error"], [[r["id"], r["error"]] for r in failed])]
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def summary_table(spec: Spec, summary: list[dict[str, Any]], metrics: list[str]) -> str:
    """A row per condition: its settings (not its id: too wide), then each metric's mean and std; first
    a column marking the baseline's rows if there is one, and one of failed runs only if some failed."""
    settings = spec.columns()
    marked = spec.baseline is not None
    failed = any(s["failed"] for s in summary)  # else no column: the page says none failed
    head = [*(["baseline"] if marked else []), *settings, "runs", *(["failed"] if failed else []), *metrics]
    body = []
    for s in summary:
        mark = ["yes" if s["condition"].startswith("baseline") else ""] if marked else []
        row = [*mark, *(_short(s[k]) if s[k] is not None else "" for k in settings), s["runs"]]
        row += [s["failed"]] if failed else []
        body.append(row + [_mean_std(s.get(f"{m}.mean"), s.get(f"{m}.std")) for m in metrics])
    return _table(head, body, "summary")


def _mean_std(mean: Any, std: Any) -> str:
    if mean is None or not math.isfinite(mean):
        return ""
    if std is None or not math.isfinite(std):
        return _figure(mean, 3)
    return f"{_figure(mean, 3)} ± {_figure(std, 2)}"


def _figure(value: float, digits: int) -> str:
    """``digits`` significant figures without an exponent (1.5e+02 reads worse than 150)."""
    if value == 0 or not 1e-4 <= abs(value) < 1e7:
        return format(value, f".{digits}g")
    return str(np.format_float_positional(value, precision=digits, unique=False, fractional=False, trim="-"))


def write_report(spec: Spec, study: StudyDir, command: str) -> Path:
    """Write runs.csv, summary.csv, plot_<axis>.png and report.html into the study directory."""
    columns, rows = collect(spec, study)
    summary_head, summary = summarise(spec, columns, rows)
    measured = [m for m in KEY_METRICS if any(_is_number(r.get(m)) for r in rows)]
    constant = constant_metrics(rows, measured)
    metrics = [m for m in measured if m not in constant]
    plots = {
        axis: plot_axis(spec, axis, rows, metrics) for axis, values in spec.axes.items() if metrics and len(values) > 1
    }
    write_text(study.root / "runs.csv", to_csv(columns, rows))
    write_text(study.root / "summary.csv", to_csv(summary_head, summary))
    for axis, png in plots.items():
        write_text(study.root / f"plot_{axis}.png", png)
    report = study.root / "report.html"
    write_text(report, render_html(spec, command, rows, summary, plots, metrics, constant))
    return report
