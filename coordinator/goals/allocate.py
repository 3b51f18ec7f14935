"""Robots per region, N_i proportional to the area A_i (paper 4.2), summing to exactly N.

An artist's override {region id: N_i} is taken as given; the rest go by largest remainder (ties: larger
area, then lower id). With N >= the region count every region gets a robot (taken from the region most
over its quota); with fewer, the N largest regions get one each.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from .model import GoalError


def largest_remainder(quota: np.ndarray, total: int, shown: Iterable[int], *ties: np.ndarray) -> np.ndarray:
    """Whole counts summing to ``total`` from the fractional ``quota``: each rounded down, then the largest
    remainders up (ties: by ``ties``, then lower index); then each of ``shown``, in order, left with none takes
    one from the count most over its quota."""
    counts = np.floor(quota).astype(np.int64)
    order = np.lexsort((np.arange(len(quota)), *ties, -(quota - counts)))
    counts[order[: total - int(counts.sum())]] += 1
    for i in shown:
        if counts[i] == 0:
            donor = int(np.argmax(np.where(counts >= 2, counts - quota, -np.inf)))
            counts[donor] -= 1
            counts[i] = 1
    return counts


def _proportional(areas: np.ndarray, total: int) -> np.ndarray:
    m = len(areas)
    counts = np.zeros(m, np.int64)
    if total <= 0 or m == 0:
        return counts
    by_area = np.lexsort((np.arange(m), -areas))  # larger area first, then lower id
    if total < m:
        counts[by_area[:total]] = 1
        return counts
    return largest_remainder(total * areas / areas.sum(), total, by_area, -areas)


def allocate_robots(
    areas: Sequence[float], n: int, overrides: Mapping[int, int] | None = None
) -> tuple[np.ndarray, list[str]]:
    """N_i per region R_i (see the module docstring) and notes. Raises GoalError."""
    a = np.asarray(areas, dtype=float)
    m = len(a)
    if n < 1:
        raise GoalError(f"N must be at least 1, not {n}")
    fixed = np.zeros(m, bool)
    counts = np.zeros(m, np.int64)
    for rid, c in (overrides or {}).items():
        if not 0 <= int(rid) < m:
            raise GoalError(f"region count override names region {rid}, but the image has regions 0..{m - 1}")
        if int(c) < 0:
            raise GoalError(f"region count override for region {rid} is negative ({c})")
        fixed[int(rid)] = True
        counts[int(rid)] = int(c)
    rest = n - int(counts.sum())
    if rest < 0:
        raise GoalError(f"region count overrides sum to {int(counts.sum())}, more than N={n}")
    free = np.nonzero(~fixed)[0]
    if len(free) == 0 and rest != 0:
        raise GoalError(f"region count overrides cover every region but sum to {int(counts.sum())}, not N={n}")
    counts[free] = _proportional(a[free], rest)
    empty = ", ".join(str(i) for i in free if counts[i] == 0)
    return counts, [f"N={n} is smaller than the number of regions: region(s) {empty} get no robot"] if empty else []
