"""The trajectory as it is recorded, a fixed-size record a tick after a JSON header line: a launcher killed
outright never writes ``trajectory.npz``, and :func:`read_ticks` reads the ticks up to the kill."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from sim.outputs.stream import ROWS

TICKS_FILE = "ticks.bin"  # in the run directory, next to log.mcap
FORMAT = "pixelswarm-ticks/1"


def tick_dtype(robots: int) -> np.dtype:
    """One tick's record: its time, wall time and rows (sim.outputs.stream.ROWS), named as in trajectory.npz."""
    rows = [(name, kind, (robots, *shape)) for name, (shape, kind) in ROWS.items()]
    return np.dtype([("t", "<f8"), ("wall", "<f8"), *rows])


class TickLog:
    """Appends one record a tick to ``path`` (created, with its header)."""

    def __init__(self, path: str | os.PathLike, robots: int) -> None:
        self.path, self.robots = Path(path), robots
        self.dtype = tick_dtype(robots)
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.write(self._fd, (json.dumps({"format": FORMAT, "robots": robots}) + "\n").encode())

    def append(self, t: float, wall: float, rows: tuple[np.ndarray, ...]) -> None:
        """A tick's record: its time, wall time and rows in the order of sim.outputs.stream.ROWS."""
        if self._fd is None:
            return
        rec = np.zeros(1, self.dtype)
        rec["t"], rec["wall"] = t, wall
        for name, value in zip(ROWS, rows, strict=True):
            rec[name][0] = value
        os.write(self._fd, rec.tobytes())  # one write a tick: a kill leaves whole records and at most one torn

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def read_ticks(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every whole tick of a tick file as trajectory.npz's arrays (a torn last one left out); ValueError if not one."""
    data = Path(path).read_bytes()
    line, sep, body = data.partition(b"\n")
    try:
        header = json.loads(line) if sep else None
    except ValueError:
        header = None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{path}: not a pixelswarm tick file")
    dtype = tick_dtype(int(header["robots"]))
    records = np.frombuffer(body, dtype, count=len(body) // dtype.itemsize)  # whole records only
    return {name: np.array(records[name]) for name in dtype.names or ()}
