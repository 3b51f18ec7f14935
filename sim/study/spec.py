"""A study's spec (`[base]`, `[axes]`, seeds, `[baseline]`), checked in full, the grid of runs it
makes, and the study directory they are written to (sim/study/runner.py runs them)."""

from __future__ import annotations

import dataclasses
import fcntl
import itertools
import json
import math
import tomllib
from pathlib import Path
from typing import Any

from coordinator.scene import CLOCKS, ENGINES, SceneError, load_scene
from sim.args import UsageError, refuse_if, usage_errors
from sim.outputs.rundir import atomic_write

FAULT_SETTINGS = ("loss", "delay", "jitter")  # the state messages' fault plan (transport/faults.py)


# --- The spec: settings, their checks, and the grid of runs they make -----------------------------
def _number(key: str, value: Any, *, maximum: float = math.inf, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{key}: {value!r} is not a number")
    if value < 0 or value > maximum or (positive and value <= 0):
        bound = "> 0" if positive else f"in [0, {maximum:g}]"
        raise UsageError(f"{key}: {value!r} must be {bound}")
    return float(value)


def _whole(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise UsageError(f"{key}: {value!r} is not a whole number >= 1")
    return value


def _choice(choices: tuple[str, ...]):
    def check(key: str, value: Any) -> str:
        refuse_if(value not in choices, f"{key}: {value!r} is not one of {', '.join(choices)}")
        return value

    return check


# Every setting a condition may give, with its check: the flags of `pixelswarm run` a study can vary.
SETTINGS = {
    "engine": _choice(ENGINES),
    "clock": _choice(CLOCKS),
    "robots": _whole,
    "agents_per_process": _whole,
    "duration": lambda k, v: _number(k, v, positive=True),
    "deadline": lambda k, v: _number(k, v, positive=True),
    "loss": lambda k, v: _number(k, v, maximum=1.0),
    "delay": _number,
    "jitter": _number,
    "range": lambda k, v: math.inf if v == math.inf else _number(k, v, positive=True),  # inf: everyone hears everyone
}


def _check_setting(where: str, key: str, value: Any) -> Any:
    refuse_if(key in ("seed", "seeds"), f"{where}: seeds are not a setting; list them in seeds = [...]")
    refuse_if(key not in SETTINGS, f"{where}: unknown setting {key!r} (known: {', '.join(SETTINGS)})")
    return SETTINGS[key](f"{where}.{key}", value)


@dataclasses.dataclass(frozen=True)
class Run:
    """One `pixelswarm run`: its condition's settings and a seed."""

    condition: str  # stable name of the settings that vary, e.g. "loss-0.2_agents_per_process-3"
    settings: dict[str, Any]  # base, then the baseline's or the axes' values
    seed: int

    @property
    def id(self) -> str:
        return f"{self.condition}_seed-{self.seed}"


@dataclasses.dataclass
class Spec:
    name: str
    scene: str  # a shipped scene name or a path (made absolute)
    seeds: list[int]
    base: dict[str, Any]
    axes: dict[str, list[Any]]
    baseline: dict[str, Any] | None
    text: str  # the spec file as written

    def runs(self) -> list[Run]:
        """Every combination of the axes for every seed, then the baseline's runs."""
        return [Run(condition, settings, seed) for condition, settings in self.conditions() for seed in self.seeds]

    def conditions(self) -> list[tuple[str, dict[str, Any]]]:
        out = [(_name(values), {**self.base, **values}) for values in _grid(self.axes)]
        if self.baseline is not None:
            # the baseline is crossed with the axes it does not set itself
            free = {k: v for k, v in self.axes.items() if k not in self.baseline}
            for values in _grid(free):
                out.append((_name(values, prefix="baseline"), {**self.base, **values, **self.baseline}))
        return out

    def columns(self) -> list[str]:
        """The settings that tell conditions apart: the axes, then what the baseline changes."""
        extra = [k for k in (self.baseline or {}) if k not in self.axes]
        return list(self.axes) + extra


def _grid(axes: dict[str, list[Any]]) -> list[dict[str, Any]]:
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def _name(values: dict[str, Any], prefix: str = "") -> str:
    parts = [prefix] if prefix else []
    parts += [f"{k}-{_label(v)}" for k, v in values.items()]
    return "_".join(parts) or "base"


def _label(value: Any) -> str:
    """An axis value as a run's id names it: a float by 12 significant digits (0.1 + 0.2 as 0.3, not 0.30000000000000004)."""
    return format(value, ".12g") if isinstance(value, float) else str(value)


def _check_labels(key: str, values: list[Any]) -> None:
    """Two values of an axis that one id would name would share a run directory: the second run would
    overwrite the first, or be skipped as done."""
    seen: dict[str, Any] = {}
    for value in values:
        other = seen.setdefault(_label(value), value)
        if other != value:
            raise UsageError(
                f"axes.{key}: {other!r} and {value!r} both name their runs {key}-{_label(value)}; "
                "give values that differ within 12 significant digits"
            )


def load_spec(path: Path) -> Spec:
    """Read and check a study spec; UsageError (one line) on anything that cannot be run."""
    try:
        text = path.read_text()
        data = tomllib.loads(text)
    except OSError as err:
        raise UsageError(f"cannot read {path}: {err.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise UsageError(f"{path}: not valid TOML: {err}") from None
    unknown = set(data) - {"name", "seeds", "base", "axes", "baseline"}
    if unknown:
        raise UsageError(f"{path}: unknown key {sorted(unknown)[0]!r} (known: name, seeds, base, axes, baseline)")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip() or "/" in name:
        raise UsageError(f"name: {name!r} must be a non-empty string without '/'")
    seeds = data.get("seeds")
    if not isinstance(seeds, list) or not seeds:
        raise UsageError("seeds: give a non-empty list of whole numbers, e.g. seeds = [1, 2, 3]")
    for s in seeds:
        refuse_if(isinstance(s, bool) or not isinstance(s, int) or s < 0, f"seeds: {s!r} is not a whole number >= 0")
    refuse_if(len(set(seeds)) != len(seeds), "seeds: a seed is listed twice")

    base = _table(data, "base")
    scene = base.pop("scene", None)
    refuse_if(not isinstance(scene, str), 'base.scene: give the scene to run, e.g. scene = "circle"')
    # a file or folder beside the spec (else where the command runs), made absolute for the children
    for candidate in (path.parent / scene, Path(scene)):
        if candidate.exists():
            scene = str(candidate.resolve())
            break
    base = {k: _check_setting("base", k, v) for k, v in base.items()}

    axes: dict[str, list[Any]] = {}
    for key, values in _table(data, "axes").items():
        refuse_if(key == "scene", "axes: scene is not an axis; write one spec per scene")
        refuse_if(not isinstance(values, list) or not values, f"axes.{key}: give a non-empty list of values")
        checked = [_check_setting("axes", key, v) for v in values]
        refuse_if(len(set(checked)) != len(checked), f"axes.{key}: a value is listed twice")
        _check_labels(key, checked)
        axes[key] = checked

    baseline = None
    if "baseline" in data:
        baseline = {k: _check_setting("baseline", k, v) for k, v in _table(data, "baseline").items()}
        refuse_if(not baseline, 'baseline: give the settings it changes, e.g. engine = "central"')

    spec = Spec(name.strip(), scene, list(seeds), base, axes, baseline, text)
    _check_conditions(spec)
    return spec


def _table(data: dict[str, Any], key: str) -> dict[str, Any]:
    table = data.get(key, {})
    refuse_if(not isinstance(table, dict), f"{key}: must be a table ([{key}])")
    return dict(table)


def _check_conditions(spec: Spec) -> None:
    """Load the scene as each condition changes it, and refuse what its engine cannot honour."""
    scenes: dict[tuple, Any] = {}
    for condition, settings in spec.conditions():
        key = (settings.get("robots"), settings.get("clock"), settings.get("duration"))
        if key not in scenes:
            with usage_errors(SceneError):
                scenes[key] = load_scene(spec.scene, robots=key[0], clock=key[1], duration=key[2])
        scene = scenes[key]
        if settings.get("engine", scene.engine) == "central":
            faulty = [k for k in FAULT_SETTINGS if settings.get(k, 0.0) != 0.0]
            if faulty:
                raise UsageError(
                    f"condition {condition}: engine central has no messages to lose or delay "
                    f'({faulty[0]} = {settings[faulty[0]]:g}); use a [baseline] with engine = "central" and {faulty[0]} = 0'
                )
            if settings.get("clock", scene.clock) == "realtime":
                raise UsageError(f"condition {condition}: engine central steps without a real-time clock")
        if math.isfinite(settings.get("range", math.inf)) and settings.get("clock", scene.clock) != "lockstep":
            raise UsageError(f'condition {condition}: range = {settings["range"]:g} needs clock = "lockstep"')


def run_args(spec: Spec, run: Run) -> list[str]:
    """The arguments of `pixelswarm run` for one run, but its --out (the worker's to choose)."""
    s = run.settings
    cmd = [spec.scene, "--seed", str(run.seed)]
    for key in ("engine", "robots", "clock", "duration", "deadline"):
        if key in s:
            cmd += [f"--{key}", str(s[key])]  # a float's str is its repr: every digit
    if math.isfinite(s.get("range", math.inf)):
        cmd += ["--range", repr(s["range"])]
    if s.get("engine") != "central":
        if "agents_per_process" in s:
            cmd += ["--agents-per-process", str(s["agents_per_process"])]
        if any(s.get(k, 0.0) for k in FAULT_SETTINGS):
            drop, delay, jitter = (s.get(k, 0.0) for k in FAULT_SETTINGS)
            cmd += ["--faults", f"state:drop={drop!r},delay={delay!r},jitter={jitter!r}"]
    return cmd + ["--no-video", "--no-plots", "-q"]


# --- The study directory: run directories, a record per run, the lock -----------------------------
class StudyDir:
    """DIR/runs/<id> (run directories), DIR/records/<id>.json (status, wall time, error),
    DIR/logs/<id>.log (the run's output), DIR/spec.toml and study.json (hold), and the report."""

    def __init__(self, root: Path):
        self.root = root
        self.runs = root / "runs"
        self.records = root / "records"
        self.logs = root / "logs"

    def run_dir(self, run: Run) -> Path:
        return self.runs / run.id

    def metrics(self, run: Run) -> dict[str, Any] | None:
        """metrics.json of a finished run, or None if the run is missing or incomplete."""
        metrics = _read_json(self.run_dir(run) / "metrics.json")
        return metrics if isinstance(metrics, dict) and metrics.get("complete") is True else None

    def record(self, run: Run) -> dict[str, Any]:
        return _read_json(self.records / f"{run.id}.json") or {}

    def write_record(self, run: Run, record: dict[str, Any]) -> None:
        write_text(self.records / f"{run.id}.json", json.dumps(record, indent=2) + "\n")

    def check_same(self, spec: Spec) -> None:
        """A directory resumes only the study it holds (hold): runs are named by what varies, so the base
        must match."""
        held = _read_json(self.root / "study.json")
        if held is not None and held != json.loads(json.dumps(_held(spec))):
            raise UsageError(
                f"{self.root} holds another study (its scene, [base] or [baseline] differ); choose another --out"
            )

    def hold(self, spec: Spec) -> None:
        """DIR/spec.toml, the spec as written, and DIR/study.json, what check_same compares."""
        write_text(self.root / "spec.toml", spec.text)
        write_text(self.root / "study.json", json.dumps(_held(spec), indent=2) + "\n")


def _read_json(path: Path) -> Any:
    """A JSON file's value, or None if it cannot be read."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _held(spec: Spec) -> dict[str, Any]:
    return {"scene": spec.scene, "base": spec.base, "baseline": spec.baseline}


def write_text(path: Path, text: str | bytes) -> None:
    """Write through a temporary sibling and rename, so that no reader sees half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    data = text.encode() if isinstance(text, str) else text
    atomic_write(path, lambda fh: fh.write(data))


def lock_study(root: Path) -> Any:
    """Hold DIR/.lock for the study's life: two studies on one directory would run the same runs."""
    try:
        root.mkdir(parents=True, exist_ok=True)
        handle = open(root / ".lock", "w")  # noqa: SIM115 - held open until the study ends
    except OSError as err:
        raise UsageError(f"cannot make the study directory {root}: {err.strerror}") from None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise UsageError(f"another study is running in {root}") from None
    return handle
