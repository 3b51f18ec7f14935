"""Robot and controller parameters, with the paper's defaults (Table 1, e-puck; section 7.1) but epsilon_A.

SI units throughout: metres, seconds, radians.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields
from typing import Any

from transport import epuck

HOLONOMIC = "holonomic"
DIFFDRIVE = "diffdrive"
KINEMATICS = (HOLONOMIC, DIFFDRIVE)
# 0 turns the feature (or bound) off
_MAY_BE_ZERO = {"assign_hysteresis", "deadlock_cost", "rounds_per_tick", "block_max_age"}
# rounds_per_tick of a lock-step scene made for agent processes that sets none: its one round a tick is
# heard at the next tick, so no tick waits on a round (docs/lockstep_auction.md, "Rounds per tick")
BUS_ROUNDS_PER_TICK = 1


SETTINGS = "_settings"  # where agent.core.step.settings_of keeps a RobotParams' compiled settings


@dataclass(frozen=True)
class RobotParams:
    """What one robot knows about itself: its body and controller settings, an attribute each (the paper's
    symbols in comments)."""

    kinematics: str = DIFFDRIVE
    radius: float = epuck.RADIUS  # r_A
    v_max: float = epuck.V_MAX  # maximum linear speed
    omega_max: float = epuck.OMEGA_MAX  # maximum angular speed (differential drive)
    wheel_base: float = epuck.WHEEL_BASE  # l_w, distance between wheels
    v_pref: float = 0.12  # V_p, preferred speed (eq. 9)
    k_a: float = 0.1  # K_a, distance below which the preferred speed falls linearly (eq. 9)
    tau: float = 2.0  # time-to-collision horizon for robots (eq. 10)
    tau_obst: float = 2.0  # horizon for static obstacles
    t_orient: float = 0.35  # T_o, time to achieve the desired orientation (NH-ORCA)
    error_max: float = 0.01  # epsilon_max, maximum extension of the radius (tracking error, NH-ORCA)
    error_min: float = 0.001  # smallest tracking error used when robots are very close
    neighbour_dist: float = 0.6  # robots farther than this are ignored by ORCA
    max_neighbours: int = 10
    dt: float = 0.1  # control period (10 Hz)
    command_margin: float = 0.05  # a command of tick k drives the body until (k + 1) dt + this; then it stops
    goal_tolerance: float = 0.01  # a robot within this distance of its goal has arrived
    noise_bound: float = 0.01  # bound on the relative tracking error of two robots (3.5 sigma of 2 x 2 mm)
    stale_after: float = 0.5  # a neighbour not heard from this long is an obstacle; near, we stop (control._unsure)
    forget_after: float = 2.0  # ... this long, and out of touch of our robots: forgotten (agent.neighbour_table)
    # Goal assignment (paper 5.1) and deadlocks (5.5.5); costs in m^2 (squared distance, eq. 7)
    # epsilon_A: the agreed assignment costs at most N epsilon_A over the optimum. Table 1 gives 0.01; 0.001 is
    # what the paper shows as the optimal assignment (7.2.2, Fig. 15)
    assign_eps: float = 1e-3
    # Delta C: keep the goal unless another is better by this much for the robot. The paper's test is on the
    # total cost (5.1), which no robot of a distributed auction knows; the optimal assignment applies that one
    assign_hysteresis: float = 5e-3
    assign_period: float = 0.1  # s between auction instances (paper 5.1: every control iteration)
    rounds_per_tick: int = 0  # lock-step: most message rounds a tick gives the auction (0: until agreed)
    # lock-step, rounds per tick bounded: a block not agreed this long after it began is dropped (stale); 0: never
    block_max_age: float = 10.0
    deadlock_cost: float = 0.1  # C_d, added for good to the cost of the goal a robot is stuck before
    deadlock_iterations: int = 50  # N_d, iterations blocked before a deadlock is declared (5 s: outlasts a crowd)
    deadlock_speed: float = 0.03  # |v_pref - v_cf| above this, and headway below it, count as blocked (m/s)
    deadlock_near: float = 0.3  # only robots this close to their goal are checked (m)

    def __post_init__(self) -> None:
        if self.kinematics not in KINEMATICS:
            raise ValueError(f"kinematics must be one of {KINEMATICS}, not {self.kinematics!r}")
        for f in fields(self):
            if f.name != "kinematics":
                _check_parameter(f.name, getattr(self, f.name), whole=f.type == "int")
        if self.forget_after <= self.stale_after:
            raise ValueError(f"forget_after ({self.forget_after}) must be longer than stale_after ({self.stale_after})")
        if self.k_a < self.v_pref * self.dt:
            # eq. 9 converges without oscillation only if K_a >= V_p * dt (paper 5.2)
            raise ValueError(f"k_a ({self.k_a}) must be at least v_pref * dt ({self.v_pref * self.dt})")

    @property
    def state_reach(self) -> float:
        """How far a robot whose state we miss may be and still become a neighbour by the next tick:
        the neighbour distance plus three ticks of travel at v_max plus the tracking noise."""
        return self.neighbour_dist + 3 * self.v_max * self.dt + self.noise_bound

    @property
    def stale_ticks(self) -> int:
        """stale_after in whole control periods, at least one: how long a robot that cannot tell which of two
        poses (agent.runtime) or commands (sim.node.body) of a tick to believe stands."""
        return max(1, math.ceil(self.stale_after / self.dt - 1e-9))

    @property
    def cell_size(self) -> float:
        """Spatial cell of state broadcasts (agent.runtime.CellSubscriptions): half the reach of three ticks."""
        return (self.neighbour_dist + 3 * self.v_max * self.dt + 0.02) / 2

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotParams:
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown robot parameter(s): {', '.join(sorted(unknown))}")
        return cls(**data)

    def stale_block(self, age: float) -> bool:
        """Whether a block begun ``age`` s of display time ago and not agreed is dropped (block_max_age)."""
        return self.block_max_age > 0 and age > self.block_max_age - 1e-9

    def __getstate__(self) -> dict[str, Any]:
        """The fields, not the compiled settings cached beside them (SETTINGS): those do not pickle."""
        return {k: v for k, v in self.__dict__.items() if k != SETTINGS}

    def grown(self, by: float) -> RobotParams:
        """A copy with the radius larger by ``by`` >= 0, unchecked: a late agent grows it every tick."""
        out = object.__new__(RobotParams)
        out.__dict__.update(self.__dict__, radius=self.radius + by)  # the settings too: the radius is not in them
        return out


def _check_parameter(name: str, value: Any, whole: bool) -> None:
    """ValueError unless ``value`` is a finite number > 0 (or 0 where that turns it off), whole if its field is
    an int: inf, nan, true or 2.5 neighbours pass the controller's comparisons and break the robot mid-run."""
    may_be_zero = name in _MAY_BE_ZERO
    number = isinstance(value, numbers.Integral if whole else numbers.Real) and not isinstance(value, bool)
    if number and math.isfinite(value) and (value > 0 or (may_be_zero and value == 0)):
        return
    what = "whole number" if whole else "number"
    what = f"a {what} >= 0" if may_be_zero else f"a positive {what}"
    raise ValueError(f"robot parameter {name} must be {what}, not {value!r}")


EPUCK = RobotParams()
