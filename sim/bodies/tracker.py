"""The central tracker (paper 7.1: an overhead camera, with seeded noise) and the bodies of a scene."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agent.core.params import HOLONOMIC, RobotParams
from coordinator.scene import Scene
from sim.bodies.geometry import wrap_angle
from sim.bodies.movers import scripted_speed_limit
from sim.bodies.world import ActuationNoise, Body, World


def bodies_of(scene: Scene) -> tuple[RobotParams, list[Body]]:
    """Every robot's body; scripted robots (dynamic obstacles) move holonomically along their path, as
    fast as their script says (not capped at the robot pixels' v_max)."""
    params = RobotParams.from_dict(scene.robot)
    bodies = [Body.from_params(params)] * scene.robots
    for i, waypoints in scene.scripted.items():
        bodies[i] = Body(HOLONOMIC, params.radius, scripted_speed_limit(waypoints, params.v_max))
    return params, bodies


def world_of(scene: Scene) -> tuple[RobotParams, World]:
    params, bodies = bodies_of(scene)
    noise = ActuationNoise(relative=scene.noise.actuation, seed=scene.seed)
    return params, World(bodies, scene.poses, arena=scene.arena, obstacles=scene.obstacles, noise=noise)


def tracker_of(scene: Scene) -> Tracker:
    return Tracker(
        scene.noise.tracking_xy, math.radians(scene.noise.tracking_theta_deg), np.random.default_rng([scene.seed, 1])
    )


@dataclass
class Tracker:
    """True poses plus seeded Gaussian noise, drawn for every robot every tick (reproducible)."""

    sigma_xy: float
    sigma_theta: float
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def measure(self, poses: np.ndarray) -> np.ndarray:
        noise = self.rng.standard_normal(poses.shape)
        noise *= (self.sigma_xy, self.sigma_xy, self.sigma_theta)
        out = np.add(poses, noise, out=noise)
        out[:, 2] = wrap_angle(out[:, 2])
        return out
