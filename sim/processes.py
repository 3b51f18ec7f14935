"""Stopping the processes this program started, by their own handles, and this one on a signal."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any


def stop_processes(processes: Iterable[subprocess.Popen], grace: float) -> None:
    """SIGTERM each of these that still runs, and SIGKILL whichever has not ended ``grace`` seconds
    later (one deadline for all of them)."""
    running = [p for p in processes if p.poll() is None]
    for p in running:
        p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for p in running:
        try:
            p.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@contextmanager
def handling_signals(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """SIGINT and SIGTERM go to ``handler`` while inside; the previous handlers come back after."""
    previous = {signum: signal.signal(signum, handler) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def stop_on_sigterm() -> Any:
    """SIGTERM as Ctrl-C (a KeyboardInterrupt), so the ``finally`` blocks that stop what this process
    started run; returns the handler it replaces."""

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, interrupt)


@contextmanager
def stopped_by_signals() -> Iterator[threading.Event]:
    """An event that SIGINT or SIGTERM sets while inside."""
    stop = threading.Event()
    with handling_signals(lambda *_: stop.set()):
        yield stop
