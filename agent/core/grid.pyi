"""Typed signatures of the compiled agent/core/grid.pyx (see its docstring)."""

import numpy as np
import numpy.typing as npt

def nearest(
    query: npt.NDArray[np.float64],
    query_key: npt.NDArray[np.int64],
    points: npt.NDArray[np.float64],
    key: npt.NDArray[np.int64],
    reach: float,
    m: int,
    inclusive: bool = True,
    threads: int = 1,
) -> npt.NDArray[np.int64]: ...
def unheard(
    robots: npt.NDArray[np.int64],
    position: npt.NDArray[np.float64],
    stamps: npt.NDArray[np.float64],
    bodies: np.ndarray,
    stamp: float,
    stale_after: float,
    v_max: float,
    radius: float,
) -> npt.NDArray[np.bool_]: ...
