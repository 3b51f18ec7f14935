"""The hardware file (docs/hardware.md): which robots a run drives (`[backend]`) and where their poses come
from (`[poses]`), each table validated by its kind's config class, found through an import string."""

from __future__ import annotations

import importlib
import math
import threading
import time
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any, Self

BACKEND_KINDS = {
    "epuck2": "hardware.epuck2:Epuck2Config",
    "ros2": "hardware.ros2:Ros2BackendConfig",
    "sim": "hardware.config:SimBackendConfig",
}
POSE_KINDS = {"ros2": "hardware.ros2:Ros2PosesConfig", "camera": "hardware.camera:CameraConfig"}
TABLES = ("backend", "poses")


class HardwareConfigError(ValueError):
    """A hardware file that cannot be used: one line naming the file, the table and what is wrong."""


def need(ok: object, message: str) -> None:
    """HardwareConfigError(message) unless ``ok``."""
    if not ok:
        raise HardwareConfigError(message)


def is_number(value: Any) -> bool:
    """A finite int or float (TOML's true and false are not numbers)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


class FromTable:
    """A config dataclass read from its table (``kind = KIND``): unknown keys (a typo would silently fall back
    to a default) and missing ones are refused here, the values by its ``__post_init__``."""

    KIND = ""

    @classmethod
    def from_table(cls, table: Any, where: str) -> Self:
        need(isinstance(table, Mapping), f"{where}: must be a table")
        fields_ = fields(cls)  # type: ignore[arg-type]  # the subclasses are dataclasses
        known = {"kind", *(f.name for f in fields_)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise HardwareConfigError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
        if table.get("kind", cls.KIND) != cls.KIND:
            raise HardwareConfigError(f"{where}: kind must be {cls.KIND!r}, not {table['kind']!r}")
        missing = [f.name for f in fields_ if f.default is f.default_factory is MISSING and f.name not in table]
        if missing:
            raise HardwareConfigError(f"{where}: missing key {missing[0]!r}")
        try:
            return cls(**{k: v for k, v in table.items() if k != "kind"})
        except HardwareConfigError as err:
            raise HardwareConfigError(f"{where}: {err}") from None


class Started:
    """A backend, pose source or stand-in that runs from start() to close(), as `with` does."""

    def start(self) -> object:
        raise NotImplementedError

    def close(self) -> object:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def every(period: float, start: float, halt: threading.Event, work: Callable[[float], object]) -> Exception | None:
    """Call ``work(s since start)`` every ``period`` s from ``start`` (time.monotonic()) until ``halt`` is set,
    not rushing to catch up after a stall; returns what ended it early (e.g. a bad pose function's error)."""
    deadline = start
    try:
        while not halt.wait(max(0.0, deadline - time.monotonic())):
            work(time.monotonic() - start)
            deadline = max(deadline + period, time.monotonic() - period)
    except Exception as err:  # for the owner to tell: the thread that ran it has ended
        return err
    return None


@dataclass(frozen=True)
class SimBackendConfig(FromTable):
    """The simulated world stands in for the robots: nothing to configure besides the kind."""

    KIND = "sim"

    def stop_robots(self, settings: object = None) -> list[int]:
        """Nothing real to stop: no robot unreached."""
        return []


@dataclass(frozen=True)
class HardwareConfig:
    """A loaded hardware file: the backend's config and the pose source's config (None when absent)."""

    path: Path
    backend: Any
    poses: Any | None
    backend_kind: str = ""  # the [backend] table's kind
    poses_kind: str | None = None  # the [poses] table's kind (None: no such table)


def load_object(target: str, kind: str, where: str) -> Any:
    """ "module:name" -> the object; a kind whose module is not installed is a HardwareConfigError."""
    module_name, _, name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name is not None and module_name.startswith(err.name):
            raise HardwareConfigError(f"{where}: kind {kind!r} is not available in this installation") from None
        raise
    need(hasattr(module, name), f"{where}: kind {kind!r} is not available in this installation ({target} missing)")
    return getattr(module, name)


def parse_table(table: Any, kinds: Mapping[str, str], where: str) -> Any:
    """One `[backend]` or `[poses]` table -> its kind's config object."""
    need(isinstance(table, dict), f"{where}: must be a table")
    need("kind" in table, f"{where}: missing key 'kind' (one of: {', '.join(sorted(kinds))})")
    kind = table["kind"]
    need(isinstance(kind, str) and kind in kinds, f"{where}: unknown kind {kind!r} (known: {', '.join(sorted(kinds))})")
    return load_object(kinds[kind], kind, where).from_table(table, where)


def load_hardware(path: str | Path) -> HardwareConfig:
    """Read and validate a hardware TOML file; every problem is a one-line HardwareConfigError."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise HardwareConfigError(f"{path}: no such hardware file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise HardwareConfigError(f"{path}: cannot read: {err}") from None
    except tomllib.TOMLDecodeError as err:
        raise HardwareConfigError(f"{path}: not valid TOML: {err}") from None
    unknown = sorted(set(data) - set(TABLES))
    if unknown:
        raise HardwareConfigError(f"{path}: unknown table [{unknown[0]}] (known: {', '.join(TABLES)})")
    need("backend" in data, f"{path}: missing table [backend]")
    backend = parse_table(data["backend"], BACKEND_KINDS, f"{path} [backend]")
    poses = parse_table(data["poses"], POSE_KINDS, f"{path} [poses]") if "poses" in data else None
    if poses is not None and hasattr(poses, "check_robots"):  # e.g. a camera: no robot's marker a reference one
        poses.check_robots(getattr(backend, "robot_ids", []), f"{path} [poses]")
    poses_kind = data["poses"]["kind"] if poses is not None else None
    return HardwareConfig(path, backend, poses, data["backend"]["kind"], poses_kind)
