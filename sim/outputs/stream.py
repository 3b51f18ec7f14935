"""The central engine's recording, tick by tick: held in memory, or (a large swarm, to stay within the memory
bound) streamed a chunk of ticks at a time to raw files in :data:`SCRATCH`, read back through :class:`OnDisk`."""

from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

# robots from which streamed per-tick floats are float32 (to 4 um at 60 m); below, float64 as the engines compute them
FLOAT32_FROM = 3000
PER_TICK = ("pose", "velocity", "goal")  # (T, N, ...) float arrays
SCRATCH = ".ticks"  # in a partial run directory: the streamed recording's raw files
CHUNK_BYTES = 1 << 21  # a chunk of ticks held before it is appended to the files (two, reused soon)

# the recorded arrays: each robot's shape and type of a tick (t and step: one per tick, held in memory)
ROWS: dict[str, tuple[tuple[int, ...], Any]] = {
    "pose": ((3,), np.float64),
    "velocity": ((2,), np.float64),
    "color": ((3,), np.uint8),
    "goal": ((2,), np.float64),
    "assignment": ((), np.int64),
}


class OnDisk:
    """A (T, N, ...) array in a raw file, indexed as numpy's: the file is mapped only while a piece is copied out,
    so its pages do not stay in memory."""

    def __init__(self, path: Path, dtype: Any, shape: tuple[int, ...]) -> None:
        self.path, self.dtype, self.shape = Path(path), np.dtype(dtype), shape
        self.ndim = len(shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        if 0 in self.shape:  # nothing recorded: an empty file cannot be mapped
            return np.empty(self.shape, self.dtype)[key]
        return np.array(np.memmap(self.path, self.dtype, "r", shape=self.shape)[key])  # a copy: the map goes at once

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        whole = self[...]
        return whole if dtype is None else whole.astype(dtype, copy=False)


class TickRecorder:
    """The recorded ticks' rows (``layout``: :data:`ROWS`, or more): streamed to raw files in ``directory`` (created),
    a thread writing a chunk while the next fills, or (None) held in arrays for ``ticks`` ticks."""

    def __init__(self, ticks: int, robots: int, directory: Path | None = None, layout: dict = ROWS) -> None:
        self.robots, self.directory, self.layout = robots, directory, layout
        self.t, self.step = np.empty(ticks), np.empty(ticks, np.int64)
        single = directory is not None and robots >= FLOAT32_FROM
        self.types = {name: np.float32 if single and name in PER_TICK else kind for name, (_, kind) in layout.items()}
        tick_bytes = sum(np.dtype(self.types[n]).itemsize * robots * int(np.prod(s)) for n, (s, _) in layout.items())
        held = ticks if directory is None else max(1, min(ticks, CHUNK_BYTES // max(tick_bytes, 1)))
        self.rows = {name: np.empty((held, robots, *shape), self.types[name]) for name, (shape, _) in layout.items()}
        self.filled = 0  # ticks in self.rows not yet appended to the files
        self.written = 0  # ticks in the files, or on their way (``pending``)
        self.spare: dict[str, np.ndarray] | None = None  # the other chunk's rows, once a chunk is on its way
        self.pending: Future | None = None  # the write of the chunk before
        self.writer = ThreadPoolExecutor(1, thread_name_prefix="recording") if directory is not None else None
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)
            for name in layout:
                self._path(name).write_bytes(b"")

    def _path(self, name: str) -> Path:
        assert self.directory is not None
        return self.directory / f"{name}.raw"

    def record(self, tick: int, t: float, step: int, rows: tuple[np.ndarray, ...]) -> dict[str, np.ndarray]:
        """Records a tick (in order from 0), its rows in the order of ``layout``; returns them as recorded."""
        if self.directory is not None and self.filled == len(next(iter(self.rows.values()))):  # the chunk is full
            self._append()
        self.t[tick], self.step[tick] = t, step
        at = self.filled if self.directory is not None else tick
        for held, value in zip(self.rows.values(), rows, strict=True):
            held[at] = value
        self.filled += 1
        return {name: held[at] for name, held in self.rows.items()}

    def _append(self) -> None:
        """The chunk to the writer thread; the next is filled in the other set of rows."""
        assert self.writer is not None
        chunk, filled = self.rows, self.filled
        self._wait()  # the other set's write is done: it can be filled again
        self.pending = self.writer.submit(self._write, chunk, filled) if filled else None
        self.rows = self.spare or {name: np.empty_like(held) for name, held in chunk.items()}
        self.spare, self.written, self.filled = chunk, self.written + filled, 0

    def _write(self, rows: dict[str, np.ndarray], filled: int) -> None:
        """The chunk appended to the files made in ``__init__``, as its rows lie (no copy). Appended, never
        created: a run aborted meanwhile has removed the files, and none comes back."""
        for name, held in rows.items():
            with open(os.open(self._path(name), os.O_WRONLY | os.O_APPEND), "wb") as out:
                out.write(held[:filled].data.cast("B"))

    def _wait(self) -> None:
        if self.pending is not None:
            pending, self.pending = self.pending, None
            pending.result()  # a write that failed fails the run here

    def arrays(self, ticks: int) -> dict[str, Any]:
        """The first ``ticks`` ticks recorded by name: numpy arrays, or :class:`OnDisk` ones when streamed."""
        out: dict[str, Any] = {"t": self.t[:ticks]}
        if self.directory is None:
            out |= {name: held[:ticks] for name, held in self.rows.items()}
        else:
            assert self.writer is not None
            self._append()
            self._wait()
            self.writer.shutdown()
            assert self.written == ticks, f"{self.written} ticks recorded, {ticks} asked for"
            for name, (shape, _) in self.layout.items():
                out[name] = OnDisk(self._path(name), self.types[name], (ticks, self.robots, *shape))
            self.rows, self.spare = {}, None  # the chunks' memory goes; the files hold the run
        return out | {"step": self.step[:ticks]}
