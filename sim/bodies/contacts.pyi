"""Typed signatures of the compiled sim/bodies/contacts.pyx (see its docstring)."""

import numpy as np
import numpy.typing as npt

def close_pairs(
    traj: npt.NDArray[np.float64],
    radius: npt.NDArray[np.float64],
    reach: float,
    motion: float,
    bound: float,
    first_row: int,
    budget: int,
) -> tuple[bool, float, int, int, npt.NDArray[np.int64], npt.NDArray[np.float64]]: ...
