"""Types of the compiled control core (agent/core/control.pyx)."""

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

class Settings:
    def __init__(
        self,
        params: Any,
        *,
        safety: bool = ...,
        margin: float | None = ...,
        timeout: float | None = ...,
        noise: float | None = ...,
        committed: float | None = ...,
        horizons: tuple[float, float, float] | None = ...,
    ) -> None: ...
    @property
    def omega_cap(self) -> float: ...

class Heard:
    def __init__(self, states: Any) -> None: ...
    @property
    def batch(self) -> int: ...

class Obstacles:
    def __init__(self, segments: ArrayLike | None = ...) -> None: ...

class Batch:
    def __init__(
        self,
        position: ArrayLike,
        velocity: ArrayLike,
        pref: ArrayLike,
        heading: ArrayLike | None = ...,
        radius: ArrayLike | None = ...,
        vmax: ArrayLike | None = ...,
        cap: ArrayLike | None = ...,
    ) -> None: ...

def vertex_angles(dent: float) -> list[float]: ...
def preferred_velocity(position: ArrayLike, goal: ArrayLike, v_pref: float, k_a: float) -> np.ndarray: ...
def blocked(params: Any, to_goal: ArrayLike, pref_velocity: ArrayLike, velocity: ArrayLike) -> np.ndarray: ...
def perturbation(robot_ids: ArrayLike, seed: int, tick: int = ..., magnitude: float = ...) -> np.ndarray: ...
def preferred_velocities(
    settings: Settings,
    robot_ids: ArrayLike,
    position: ArrayLike,
    velocity: ArrayLike,
    goal: ArrayLike,
    given: ArrayLike | None,
    seed: int,
    tick: int,
    cap: ArrayLike | None = ...,
) -> np.ndarray: ...
def step(
    settings: Settings, robots: Batch, heard: Any, segments: ArrayLike | Obstacles | None = ..., threads: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...
def step_known(
    settings: Settings,
    robots: Batch,
    index: ArrayLike,
    segments: ArrayLike | Obstacles | None = ...,
    out: np.ndarray | None = ...,
) -> tuple[np.ndarray, np.ndarray]: ...
def prepare_neighbours(
    settings: Settings, heard: Any, vmax: float | None = ...
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...
def touch_reach(settings: Settings, radius: float, other: ArrayLike, age: ArrayLike) -> np.ndarray: ...
def orca_line(
    robot: tuple[float, ...], neighbour: tuple[float, ...], tau: float, dt: float
) -> tuple[float, float, float, float]: ...
def obstacle_line(
    position: ArrayLike, radius: float, segment: ArrayLike, tau_obst: float
) -> tuple[float, float, float, float]: ...
def linear_program(lines: ArrayLike, vmax: float, target: ArrayLike, n_hard: int = ...) -> tuple[np.ndarray, bool]: ...
def max_trackable_speed(settings: Settings, theta: ArrayLike, error: ArrayLike) -> np.ndarray: ...
def min_error_speed(v_h: float, theta: float) -> float: ...
def tracking_error(settings: Settings, robot: ArrayLike, neighbours: ArrayLike) -> tuple[float, np.ndarray]: ...
def ahv_polygon(settings: Settings, heading: float, error: float, mirrored: bool = ...) -> np.ndarray: ...
def controls(settings: Settings, velocity: ArrayLike, heading: float, reverse: bool = ...) -> tuple[float, float]: ...
