"""Lost and late neighbour states without the bus: a study tool for what message loss does to ORCA.

The central engine with an impaired in-process link: deterministic and cheap enough to sweep loss rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coordinator.scene import Scene, scene_from_dict
from sim.central.engine import simulate
from sim.central.link import InProcessLink


@dataclass
class LossyResult:
    contacts: int  # pair-contact events (true poses, world sub-steps)
    min_clearance: float  # m, smallest gap between bodies over the run (negative: overlap)
    fallbacks: int  # robot-ticks where ORCA's program was infeasible
    robot_ticks: int
    heard_on_time: float  # share of (receiver, sender) states heard at the next tick
    progress: float  # share of the way to their goals the robots covered (1 - remaining / initial distance)


def circle_crossing(robots: int, kinematics: str, seed: int, duration: float = 25.0) -> Scene:
    """Robots on a circle (0.2 m apart) crossing to the antipodes, through the crowd where loss matters."""
    return scene_from_dict(
        {
            "robots": robots,
            "duration": duration,
            "robot": {"kinematics": kinematics},
            "layout": {"kind": "circle", "spacing": 0.2},
            "goals": {"kind": "antipodal"},
        },
        source="circle-crossing",
        seed=seed,
    )


def run_lossy(scene: Scene, drop: float, late: float, seed: int = 0) -> LossyResult:
    """Step the scene's robots toward their scene goals with states lost with probability ``drop`` and
    a tick late with probability ``late`` (per sender and receiver)."""
    link = InProcessLink(scene.robots, drop=drop, late=late, seed=seed)
    out = simulate(scene, link=link, progress=None)
    t, pose, goal = out.arrays["t"], out.arrays["pose"], out.arrays["goal"]
    remaining = np.hypot(*(pose[[0, -1], :, :2] - goal[[0, -1]]).transpose(2, 0, 1)).sum(axis=1)
    progress = float(1.0 - remaining[1] / remaining[0])
    return LossyResult(
        len(out.contacts), out.min_clearance, out.fallbacks, len(t) * scene.robots, link.heard_on_time, progress
    )
