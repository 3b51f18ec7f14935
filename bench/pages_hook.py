"""Loaded into one agent process by bench.agent_pages (a sitecustomize on PYTHONPATH imports it):
after every Python and C call returns, how many pages of numpy's core library the process has
mapped (/proc/self/pagemap), and which call mapped more. Kept to sys, os and threading (an agent
loads threading anyway), so that the measuring adds nothing to the pages it counts."""

from __future__ import annotations

import os
import sys
import threading
from typing import Any

LIBRARY = "_multiarray_umath"  # numpy's core: the library whose pages a robot's ticks touch
PAGE = 4096


def _mappings() -> list[tuple[int, int]]:
    ranges = []
    with open("/proc/self/maps") as maps:
        for line in maps:
            if LIBRARY in line:
                lo, hi = line.split()[0].split("-")
                ranges.append((int(lo, 16), int(hi, 16)))
    return ranges


def _mapped(pagemap: int, ranges: list[tuple[int, int]]) -> int:
    """Pages of the ranges present in this process's page table (bit 63 of each 8-byte entry)."""
    present = 0
    for lo, hi in ranges:
        entries = os.pread(pagemap, (hi - lo) // PAGE * 8, lo // PAGE * 8)  # pread: threads share the fd
        present += sum(1 for i in range(7, len(entries), 8) if entries[i] & 0x80)
    return present


def install(out_dir: str) -> None:
    """Trace this process if it is the first agent to claim ``out_dir``; lines go to out_dir/pages.txt:
    'START kB' when numpy is first loaded, then 'kB event name @ frames' for every call that changed
    the count (frames innermost first, 'importlib' among them while a module is being imported)."""
    try:
        os.close(os.open(os.path.join(out_dir, "claimed"), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return  # another agent is the one measured
    out = open(os.path.join(out_dir, "pages.txt"), "w", buffering=1)  # noqa: SIM115 (open while the process runs)
    state: dict[str, Any] = {"ranges": None, "pages": 0, "pagemap": None}

    def profile(frame: Any, event: str, arg: Any) -> None:
        if event not in ("return", "c_return"):
            return
        if state["ranges"] is None:
            if "numpy" not in sys.modules or not (ranges := _mappings()):
                return
            state["ranges"], state["pagemap"] = ranges, os.open("/proc/self/pagemap", os.O_RDONLY)
            state["pages"] = _mapped(state["pagemap"], ranges)
            out.write(f"START {state['pages'] * PAGE // 1024}\n")
            return
        pages = _mapped(state["pagemap"], state["ranges"])
        if pages != state["pages"]:
            where, f = [], frame
            while f is not None and len(where) < 5:
                where.append(f"{f.f_code.co_filename.rsplit('/', 1)[-1]}:{f.f_lineno}")
                f = f.f_back
            name = getattr(arg, "__qualname__", "?") if event == "c_return" else frame.f_code.co_name
            out.write(f"{(pages - state['pages']) * PAGE // 1024} {event} {name} @ {' < '.join(where)}\n")
            state["pages"] = pages

    sys.setprofile(profile)
    threading.setprofile(profile)
