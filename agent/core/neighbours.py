"""What a robot assumes about neighbours it knows only from messages.

A neighbour's state was stamped ``age`` seconds ago. ORCA then needs where the neighbour is now and
how sure we are: `prepare_neighbours` extrapolates and inflates; `perturb_preferred_velocity` breaks
the perfect symmetries that deadlock ORCA head-on, deterministically from a robot id and a seed.
"""

from __future__ import annotations

from typing import NamedTuple, TypeVar

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

__all__ = [
    "Neighbours",
    "COOPERATING",
    "NON_COOPERATING",
    "prepare_neighbours",
    "perturb_preferred_velocity",
]

COOPERATING = 0.5  # responsibility c toward a robot running the same ORCA (eq. 12)
NON_COOPERATING = 1.0  # toward a dynamic obstacle, or a robot whose state is stale
PERTURBATION = 1e-4  # largest component of the symmetry-breaking perturbation of a preferred velocity (m/s)


class Neighbours(NamedTuple):
    """Neighbour arrays as `orca_velocity` takes them: (B,M,2), (B,M,2), (B,M), (B,M), (B,M)."""

    position: np.ndarray
    velocity: np.ndarray
    radius: np.ndarray  # grown: the body, the tracking noise and how far it may have strayed
    responsibility: np.ndarray
    valid: np.ndarray
    growth: np.ndarray | None = None  # (B,M) the part of ``radius`` that is how far it may have strayed
    lead: np.ndarray | None = None  # (B,M) s beyond ``position`` at ``velocity`` to where it most likely is


def prepare_neighbours(
    position: ArrayLike,
    velocity: ArrayLike,
    radius: ArrayLike,
    age: ArrayLike,
    valid: ArrayLike,
    *,
    max_speed: float | np.ndarray,
    timeout: float,
    noise: float = 0.0,
    cooperative: ArrayLike | None = None,
    committed: float = 0.0,
) -> Neighbours:
    """Neighbour states as of now, from states stamped ``age`` seconds ago.

    * Fresh (0 <= age <= timeout): where the neighbour can be now. A broadcast velocity is executed
      until the neighbour's next tick (``committed``, one control period); after that it may drive
      at any velocity up to its maximum speed (its command runs out and it stops, or its next one
      turns it). So it is within ``max_speed x h`` of its position extrapolated by the committed
      time, h = max(age - committed, 0) being the time it may have had another velocity: the
      position is extrapolated by min(age, committed) x velocity and the radius grown by
      ``noise + h x max_speed``, the smallest disc holding every place it can have reached (a
      neighbour reported standing still grows by its own reach, not by twice it). ``noise`` covers
      the tracking noise of the stamped positions. Most likely it kept its velocity all along:
      ``lead`` = h is how much further the ORCA lines take it (the safety lines take the disc).
      Responsibility 0.5 (it avoids us too), or 1.0 where ``cooperative`` is False.
    * Stale (age > timeout): last known position and velocity, not extrapolated (the message may be
      from a robot that stopped or died); radius grown by ``noise + (timeout - committed) x 2 max_speed``;
      responsibility 1.0: we avoid it alone.
    * Invalid: not finite, or flagged invalid by the caller (a negative age, from clock skew, is 0).

    Shapes: position, velocity (B,M,2); radius, age, valid (B,M); max_speed scalar or (B,M).
    Elementwise, so deterministic per robot.
    """
    position = np.asarray(position, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    radius = np.asarray(radius, dtype=float)
    elapsed = np.maximum(np.asarray(age, dtype=float), 0.0)
    finite: npt.NDArray[np.bool_] = (
        np.isfinite(position).all(axis=-1)
        & np.isfinite(velocity).all(axis=-1)
        & np.isfinite(radius)
        & np.isfinite(elapsed)
    )
    valid = np.asarray(valid, dtype=bool) & finite
    stale = elapsed > timeout
    # A broadcast velocity is what the neighbour executes until its next tick (``committed``
    # seconds): only time beyond that is time in which it may have changed its mind.
    horizon = np.maximum(np.where(stale, timeout, elapsed) - committed, 0.0)
    shift = np.where(stale, 0.0, elapsed - horizon)[..., None]
    safe_p = np.where(valid[..., None], position, 0.0)
    safe_v = np.where(valid[..., None], velocity, 0.0)
    new_position = safe_p + shift * safe_v
    # Fresh: anywhere within its reach of where its committed velocity took it. Stale: not
    # extrapolated, so its velocity may have turned into its opposite: twice the reach.
    growth = np.where(valid, horizon, 0.0) * np.where(stale, 2.0, 1.0) * max_speed
    new_radius = np.where(valid, radius, 0.0) + noise + growth
    coop = np.ones(valid.shape, dtype=bool) if cooperative is None else np.asarray(cooperative, bool)
    responsibility = np.where(coop & ~stale, COOPERATING, NON_COOPERATING)
    lead = np.where(valid & ~stale, horizon, 0.0)
    return Neighbours(new_position, safe_v, new_radius, responsibility, valid, growth, lead)


_Words = TypeVar("_Words", np.ndarray, np.uint64)


def splitmix64(x: _Words) -> _Words:
    # integer hash (Steele et al.'s SplitMix64 finaliser): elementwise uint64 arithmetic, exact
    with np.errstate(over="ignore"):
        x = x + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))


_WORD = 2**64 - 1  # uint64 arithmetic on Python ints: masked to 64 bits


def _splitmix64_int(x: int) -> int:
    """splitmix64 of one word on Python ints."""
    x = (x + 0x9E3779B97F4A7C15) & _WORD
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _WORD
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _WORD
    return x ^ (x >> 31)


def perturbation_one(robot_id: int, seed: int, tick: int = 0, magnitude: float = PERTURBATION) -> tuple[float, float]:
    """The vector `perturb_preferred_velocity` adds for one robot, on Python ints and floats (the
    same bits; an agent process steps one robot, where numpy's per-call overhead dominates)."""
    ids = robot_id & _WORD  # as numpy's astype(uint64)
    key = _splitmix64_int((_splitmix64_int(ids ^ _splitmix64_int(seed % 2**64)) + tick % 2**64) & _WORD)
    a = float(key >> 11) * 2.0**-53
    b = float(_splitmix64_int(key) >> 11) * 2.0**-53
    return (2.0 * a - 1.0) * magnitude, (2.0 * b - 1.0) * magnitude


def perturb_preferred_velocity(
    pref_velocity: ArrayLike, robot_id: ArrayLike, seed: int, tick: int = 0, magnitude: float = PERTURBATION
) -> np.ndarray:
    """Add a tiny pseudo-random vector (each component in [-magnitude, magnitude]) to each preferred
    velocity, a function of (robot id, seed, tick) only: symmetric configurations (head-on pairs,
    rings) stop being symmetric, and every process computes the same perturbation."""
    ids = np.asarray(robot_id).astype(np.uint64).reshape(-1)
    key = splitmix64(splitmix64(ids ^ splitmix64(np.uint64(seed % 2**64))) + np.uint64(tick % 2**64))
    a = (key >> np.uint64(11)).astype(float) * 2.0**-53  # [0, 1)
    b = (splitmix64(key) >> np.uint64(11)).astype(float) * 2.0**-53
    delta = np.stack([2.0 * a - 1.0, 2.0 * b - 1.0], axis=-1) * magnitude
    return np.asarray(pref_velocity, dtype=float) + delta
