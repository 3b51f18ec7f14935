"""The uncontrolled robots of a scene (paper 7.4.2, Fig. 19), as the simulation drives them.

A scripted mover (``[[scripted]]``) has no agent: it follows its waypoints and avoids nobody. A pursuer
(``[[pursuers]]``) is an agent whose goal is its target. Neither takes a goal of the image's goal set.
"""

from __future__ import annotations

import numpy as np

from coordinator.scene import Scene, scripted_position

# A mover's body allows this much more than its script's top speed, to make up the actuation noise's drift.
CATCH_UP = 1.25


def scripted_velocity(waypoints: np.ndarray, position: np.ndarray, t: float, dt: float) -> np.ndarray:
    """The world-frame velocity that takes a scripted mover from `position` at time t to where its
    script puts it at t + dt (so any drift is made up at once)."""
    return (scripted_position(waypoints, t + dt) - np.asarray(position, float)[:2]) / dt


def scripted_speed_limit(waypoints: np.ndarray, floor: float) -> float:
    """The top speed of a scripted mover's body: its script's fastest segment with CATCH_UP room, and at
    least `floor` (the robots' v_max); a body capped below its script would lag behind its broadcast state."""
    segment = np.diff(np.asarray(waypoints, float), axis=0)
    speed = np.hypot(segment[:, 1], segment[:, 2]) / segment[:, 0]
    return max(float(floor), CATCH_UP * float(speed.max(initial=0.0)))


class Movers:
    """A scene's scripted movers and pursuers for the central engine, which steps every robot with the
    same control core."""

    def __init__(self, scene: Scene) -> None:
        self.scripted = dict(scene.scripted)
        self.pursuers = dict(scene.pursuers)
        self.pixels = np.array(scene.pixel_robots, np.int64)  # the robots the goal set is auctioned to
        self.cooperative = np.ones(scene.robots, bool)  # runs the same ORCA; a scripted mover avoids nobody
        self.cooperative[list(self.scripted)] = False

    def pixel_assignment(self, chosen: np.ndarray) -> np.ndarray:
        """Goal index per robot (-1: none) from the goal indices `chosen` for the pixels, in order."""
        out = np.full(len(self.cooperative), -1)
        out[self.pixels] = chosen
        return out

    def goals(self, goal: np.ndarray, color: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Goals and LED colours: each pursuer's goal its target's tracked position, no goal for the
        scripted movers, and the scripted movers white (as the world process shows them)."""
        goal, color = np.array(goal, float), np.array(color, np.uint8)
        for robot, target in self.pursuers.items():
            goal[robot] = position[target, :2]
        goal[list(self.scripted)] = np.nan
        color[list(self.scripted)] = 255
        return goal, color

    def commands(
        self, command: np.ndarray, velocity: np.ndarray, poses: np.ndarray, t: float, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The robots' commands and collision-free velocities, each scripted mover's replaced by its
        scripted velocity for the period from t (what its neighbours hear, as in the world process)."""
        command, velocity = np.array(command, float), np.array(velocity, float)
        for robot, waypoints in self.scripted.items():
            command[robot] = velocity[robot] = scripted_velocity(waypoints, poses[robot], t, dt)
        return command, velocity
