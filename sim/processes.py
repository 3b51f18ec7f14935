"""Starting processes in sessions of their own at this one's priority; stopping the processes this program
started, by their own handles, and this one on a signal."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

# Unprivileged, Linux takes one autogroup change machine-wide per AUTOGROUP_RETRY_S: a busy moment is tried again
AUTOGROUP_TRIES = 10
AUTOGROUP_RETRY_S = 0.1  # the kernel's interval (HZ / 10)


def start_session(command: list[str], **popen: Any) -> subprocess.Popen:
    """``command`` in a session of its own (a terminal's Ctrl-C reaches only us, who pass it on), at this
    process's priority: Linux schedules each session as one group (autogroup) at nice 0 whatever the nice
    its processes inherit, so without this `nice pixelswarm run` would lower the launcher alone."""
    process = subprocess.Popen(command, start_new_session=True, **popen)
    niceness = os.nice(0)
    for _ in range(AUTOGROUP_TRIES if niceness > 0 else 0):
        try:
            with open(f"/proc/{process.pid}/autogroup", "w") as f:
                f.write(str(niceness))
            break
        except BlockingIOError:
            time.sleep(AUTOGROUP_RETRY_S)
        except OSError:
            break  # no autogroup (another system, or switched off): the nice it inherited is its priority
    return process


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
