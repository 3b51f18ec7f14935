"""Robots per region, N_i proportional to the area A_i (paper 4.2), with an exact total of N.

Rules, in order:
1. An artist's override {region id: N_i} is taken as given (0 leaves a region empty); the remaining
   robots go to the other regions by rules 2-4. Overrides that exceed N, or that cover every region
   without summing to N, are errors.
2. Largest-remainder rounding of the quotas N A_i / sum A (ties: larger area, then lower id).
3. When there are at least as many robots as regions, every region is shown: a region whose share
   rounds to zero gets one robot, taken from the region whose count most exceeds its quota.
4. When N is smaller than the number of regions, the N largest regions get one robot each and the
   others are left empty (with a note).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .model import GoalError


def _proportional(areas: np.ndarray, total: int) -> np.ndarray:
    m = len(areas)
    counts = np.zeros(m, np.int64)
    if total <= 0 or m == 0:
        return counts
    by_area = np.lexsort((np.arange(m), -areas))  # larger area first, then lower id
    if total < m:
        counts[by_area[:total]] = 1
        return counts
    quota = total * areas / areas.sum()
    counts = np.floor(quota).astype(np.int64)
    frac = quota - counts
    rest = total - int(counts.sum())
    order = np.lexsort((np.arange(m), -areas, -frac))
    counts[order[:rest]] += 1
    for i in by_area:
        if counts[i] == 0:
            surplus = np.where(counts >= 2, counts - quota, -np.inf)
            donor = int(np.argmax(surplus))
            counts[donor] -= 1
            counts[i] = 1
    return counts


def allocate_robots(
    areas: Sequence[float], n: int, overrides: Mapping[int, int] | None = None
) -> tuple[np.ndarray, list[str]]:
    """N_i per region R_i (see the module docstring); returns (counts, notes). Raises GoalError."""
    a = np.asarray(areas, dtype=float)
    m = len(a)
    if n < 1:
        raise GoalError(f"N must be at least 1, not {n}")
    notes: list[str] = []
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
    empty = [int(i) for i in free if counts[i] == 0]
    if empty:
        notes.append(
            f"N={n} is smaller than the number of regions: region(s) {', '.join(map(str, empty))} get no robot"
        )
    return counts, notes
