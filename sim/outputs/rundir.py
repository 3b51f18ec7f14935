"""Atomic run directories (written as ``<name>.partial/``, renamed when complete) and the writers that fill them."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import enum
import io
import json
import math
import os
import re
import shutil
import threading
import zipfile
from collections.abc import Iterable
from pathlib import Path, PurePath
from typing import Any

import numpy as np

PARTIAL_SUFFIX = ".partial"


def json_safe(obj: Any) -> Any:
    """A structure ``json.dumps(..., allow_nan=False)`` accepts: numpy values as Python's (NaN, inf: None), sets
    as lists, keys and paths as strings, enums as their value, bytes decoded as UTF-8."""
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, (float, np.floating)):  # float(), not item(): a long double's item() is one again
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {(k if isinstance(k, str) else str(json_safe(k))): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [json_safe(v) for v in sorted(obj, key=repr)]
    if isinstance(obj, enum.Enum):
        return json_safe(obj.value)
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return bytes(obj).decode("utf-8", errors="replace")
    if hasattr(obj, "tolist"):  # numpy's arrays, bools and integers (and other array-likes) as Python's
        return json_safe(obj.tolist())
    if hasattr(obj, "__dataclass_fields__"):
        return json_safe(dataclasses.asdict(obj))
    raise TypeError(f"cannot convert {type(obj).__name__} to JSON")


def dumps_json(obj: Any, *, indent: int | None = None, sort_keys: bool = False) -> str:
    """``json.dumps`` of :func:`json_safe` (NaN/inf -> null, numpy types converted)."""
    sep = (",", ":") if indent is None else (",", ": ")
    return json.dumps(json_safe(obj), allow_nan=False, indent=indent, separators=sep, sort_keys=sort_keys)


def atomic_write(path: Path, writer) -> None:
    """Write through a temporary sibling file and rename it over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{threading.get_ident()}")
    try:
        with open(tmp, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: str | os.PathLike, obj: Any, *, indent: int = 2) -> Path:
    """Write ``obj`` as JSON (NaN/inf -> null, numpy types converted), atomically. Returns the path."""
    path = Path(path)
    text = dumps_json(obj, indent=indent) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))
    return path


# zlib's level for a run's .npz files: the fastest, and a run's trajectories come out nearly as small as at
# numpy's level 6 (BENCHMARKS.md, "Outputs")
NPZ_LEVEL = 1


def write_npz_streamed(path: str | os.PathLike, arrays: Iterable[tuple[str, Any]]) -> Path:
    """Write arrays to a compressed ``.npz`` exactly at ``path``, atomically (object arrays refused), taken one
    at a time (a generator makes each only while it is written); a value with ``write(file)`` writes its own."""

    def _w(fh: io.BufferedWriter) -> None:
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED, allowZip64=True, compresslevel=NPZ_LEVEL) as z:
            for name, value in arrays:
                with z.open(f"{name}.npy", "w", force_zip64=True) as member:
                    if hasattr(value, "write"):
                        value.write(member)
                    else:
                        np.lib.format.write_array(member, np.asarray(value), allow_pickle=False)

    atomic_write(Path(path), _w)
    return Path(path)


_issued_lock = threading.Lock()
_issued: set[Path] = set()


def default_run_path(scene_name: str, *, root: str | os.PathLike = "runs", now: _dt.datetime | None = None) -> Path:
    """``<root>/<UTC timestamp>-<scene>``, not created; made unique (``-2``, ``-3``, ...) against the final and
    ``.partial`` directories on disk and those handed out earlier in this process."""
    now = now or _dt.datetime.now(_dt.UTC)
    if now.tzinfo is not None:
        now = now.astimezone(_dt.UTC)
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", str(scene_name)).strip("-.") or "run"
    base = f"{now.strftime('%Y%m%dT%H%M%SZ')}-{slug}"
    root = Path(root)
    with _issued_lock:
        k = 1
        while True:
            name = base if k == 1 else f"{base}-{k}"
            cand = root / name
            key = cand.resolve()
            if key not in _issued and not cand.exists() and not cand.with_name(name + PARTIAL_SUFFIX).exists():
                _issued.add(key)
                return cand
            k += 1


class RunDir(contextlib.AbstractContextManager["RunDir"]):
    """An output directory that appears under its final name only when complete: leaving a ``with`` block
    commits it, an exception aborts it. FileExistsError if its final or partial directory exists."""

    def __init__(self, final_path: str | os.PathLike):
        self.final_path = Path(final_path)
        self.partial_path = self.final_path.with_name(self.final_path.name + PARTIAL_SUFFIX)
        if self.final_path.exists():
            raise FileExistsError(f"run directory already exists: {self.final_path}")
        self.final_path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.partial_path.mkdir()
        except FileExistsError:
            raise FileExistsError(
                f"partial run directory already exists (another run, or a killed one: remove it): {self.partial_path}"
            ) from None
        self.state = "open"  # open | committed | aborted

    @property
    def path(self) -> Path:
        """Where to write: the partial directory while open, the final one after commit."""
        return self.final_path if self.state == "committed" else self.partial_path

    def __truediv__(self, name: str | os.PathLike) -> Path:
        return self.path / name

    def __fspath__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.final_path)!r}, state={self.state})"

    def commit(self) -> Path:
        """Rename ``<name>.partial`` to ``<name>``. Returns the final path."""
        if self.state == "committed":
            return self.final_path
        if self.state != "open":
            raise RuntimeError(f"cannot commit a run directory that was {self.state}")
        if self.final_path.exists():
            raise FileExistsError(f"run directory appeared meanwhile: {self.final_path}")
        _fsync_dir(self.partial_path)
        os.rename(self.partial_path, self.final_path)
        _fsync_dir(self.final_path.parent)
        self.state = "committed"
        return self.final_path

    def abort(self) -> None:
        """Remove the partial directory (no-op if already committed or aborted)."""
        if self.state != "open":
            return
        self.state = "aborted"
        shutil.rmtree(self.partial_path, ignore_errors=True)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
        elif self.state == "open":
            try:
                self.commit()
            except BaseException:
                self.abort()
                raise


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):  # a directory some systems cannot open or sync
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
