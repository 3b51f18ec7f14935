"""Typed signatures of the compiled sim/bodies/kinematics.pyx (see its docstring)."""

import numpy as np

class Bodies:
    n: int
    def __init__(
        self,
        v_max: np.ndarray,
        diffdrive: np.ndarray,
        wheel_base: np.ndarray,
        omega_max: np.ndarray,
        noise_rel: float,
        noise_abs: float,
    ) -> None: ...

def limit(bodies: Bodies, commands: np.ndarray) -> tuple[np.ndarray, int]: ...
def actuate(bodies: Bodies, command: np.ndarray, noise: np.ndarray, theta: np.ndarray) -> np.ndarray: ...
def drive(motion: np.ndarray, since: float, t: np.ndarray, start: np.ndarray, out: np.ndarray) -> None: ...
