"""Initial samples inside a region R_i (paper 4.2): uniform darts accepted only if they keep a
distance of at least K_s = 1.2 sqrt(A_i / (pi N_i)) from every accepted sample (Poisson-disk-like).

Coordinates are in pixel units: pixel (row r, column c) is the square [c, c+1) x [r, r+1).
"""

from __future__ import annotations

import math

import numpy as np

KS_FACTOR = 1.2
_TRIES_PER_SAMPLE = 40  # darts per wanted sample before K_s is relaxed
_RELAX = 0.9  # K_s shrink factor when the region is too crowded (thin regions) to place N_i samples


def ks_distance(area: float, n: int, factor: float = KS_FACTOR) -> float:
    """K_s = factor * sqrt(A_i / (pi N_i)), the radius of a circle of area A_i / N_i times 1.2."""
    return factor * math.sqrt(area / (math.pi * n))


def poisson_samples(
    rows: np.ndarray, cols: np.ndarray, n: int, rng: np.random.Generator, ks: float | None = None
) -> tuple[np.ndarray, float]:
    """n samples (x, y) in pixel units inside the pixels (rows, cols) of R_i, pairwise >= K_s apart.

    If n samples at K_s cannot be placed within 40 n darts (a thin or fragmented region), K_s is
    relaxed by 10 % and the darts continue; returns (samples, K_s actually used)."""
    if n <= 0:
        return np.zeros((0, 2)), 0.0
    npx = len(rows)
    if n > npx:
        raise ValueError(f"cannot place {n} samples in {npx} pixels")
    ks = ks_distance(npx, n) if ks is None else float(ks)
    xs_c = cols.astype(float)
    ys_c = rows.astype(float)
    accepted: list[tuple[float, float]] = []
    while True:
        cell = ks / math.sqrt(2.0)
        grid: dict[tuple[int, int], tuple[float, float]] = {}
        for x, y in accepted:
            grid[(int(x // cell), int(y // cell))] = (x, y)
        ks2 = ks * ks
        budget = _TRIES_PER_SAMPLE * n
        while budget > 0 and len(accepted) < n:
            batch = min(budget, max(256, 4 * (n - len(accepted))))
            budget -= batch
            pick = rng.integers(npx, size=batch)
            jit = rng.random((batch, 2))
            for x, y in zip((xs_c[pick] + jit[:, 0]).tolist(), (ys_c[pick] + jit[:, 1]).tolist()):
                gx, gy = int(x // cell), int(y // cell)
                ok = True
                for i in range(gx - 2, gx + 3):
                    for j in range(gy - 2, gy + 3):
                        p = grid.get((i, j))
                        if p is not None and (p[0] - x) ** 2 + (p[1] - y) ** 2 < ks2:
                            ok = False
                            break
                    if not ok:
                        break
                if ok:
                    grid[(gx, gy)] = (x, y)
                    accepted.append((x, y))
                    if len(accepted) == n:
                        break
        if len(accepted) == n:
            return np.asarray(accepted), ks
        ks *= _RELAX
