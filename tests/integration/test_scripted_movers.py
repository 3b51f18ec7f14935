"""Uncontrolled robots (paper 7.4.2, Fig. 19): scripted movers follow their waypoints at the scripted
speed, and neither they nor pursuers are robot pixels of the image."""

from __future__ import annotations

import json

import numpy as np

from coordinator.scene import scene_from_dict, scene_goal_set, scripted_position
from coordinator.service import Coordinator
from sim.bodies.movers import Movers, scripted_velocity
from sim.bodies.tracker import bodies_of, world_of
from sim.central.engine import run_central
from tests.support.fake_bus import Bus
from transport.codec import Tick

DT = 0.1


def mover_scene(**extra) -> dict:
    """Three e-pucks (v_max 0.13 m/s) in a row and a scripted mover that crosses below them at 0.5 m/s."""
    return {
        "robots": 4,
        "seed": 3,
        "robot": {"kinematics": "diffdrive"},
        "layout": {"kind": "list", "poses": [[-0.2, 0.3, 0.0], [0.0, 0.3, 0.0], [0.2, 0.3, 0.0], [-0.8, -0.3, 0.0]]},
        "arena": {"size": [2.4, 1.6]},
        "scripted": [{"robot": 3, "waypoints": [[0.0, -0.8, -0.3], [1.0, -0.8, -0.3], [4.0, 0.7, -0.3]]}],
        **extra,
    }


def test_a_scripted_mover_moves_at_its_scripted_speed_not_the_robots_v_max():
    scene = scene_from_dict(mover_scene(goals={"kind": "stay"}))
    params, bodies = bodies_of(scene)
    assert params.v_max == 0.13 and bodies[0].v_max == 0.13  # the robots keep theirs
    _, world = world_of(scene)
    wp = scene.scripted[3]
    worst = 0.0
    for tick in range(50):
        t = tick * DT
        v = scripted_velocity(wp, world.poses[3], t, DT)  # as the world process drives it
        world.set_command(3, float(v[0]), float(v[1]))
        world.step(DT)
        worst = max(worst, float(np.hypot(*(world.poses[3, :2] - scripted_position(wp, t + DT)))))
    assert worst < 0.01, f"the mover fell {worst:.3f} m behind its script (0.5 m/s)"


# --- the coordinator: movers are not robot pixels ----------------------------------------------------


def test_the_goal_set_goes_to_the_robot_pixels_only():
    """Robot 3 is scripted (no agent), robot 4 pursues it (an agent that declares itself alive): the
    disk's goal set is for robots 0-2 alone, three goals."""
    scene = scene_from_dict(
        mover_scene(
            robots=5,
            steps=[{"shape": "disk", "hold": 20.0}],
            pursuers=[{"robot": 4, "target": 3}],
            layout={
                "kind": "list",
                "poses": [[-0.2, 0.3, 0.0], [0.0, 0.3, 0.0], [0.2, 0.3, 0.0], [-0.8, -0.3, 0.0], [-0.8, 0.0, 0.0]],
            },
        )
    )
    assert scene.pixel_robots == [0, 1, 2]
    bus = Bus()
    coordinator = Coordinator(bus, scene)
    bus.alive.items = [("agent", str(r), True, 0.0, "a") for r in (0, 1, 2, 4)]
    bus.clock.items = [("clock", Tick(0, 0.0, DT))]
    assert coordinator._follow_show()
    goals = bus.published[-1]
    assert goals.robots.tolist() == [0, 1, 2] and len(goals.positions) == 3
    np.testing.assert_array_equal(goals.positions, scene_goal_set(scene, 0, 3)[0])


# --- the central engine ----------------------------------------------------------------------------
def chase_scene() -> dict:
    """Robots 0-2 show a disk; robot 3 is scripted across below them at 0.2 m/s, robot 4 pursues it."""
    return mover_scene(
        robots=5,
        steps=[{"shape": "disk", "hold": 8.0}],
        pursuers=[{"robot": 4, "target": 3}],
        end={"converge_hold": 60.0},  # the whole 8 s, not just until the disk has formed
        scripted=[{"robot": 3, "waypoints": [[0.0, -0.8, -0.3], [1.0, -0.8, -0.3], [8.0, 0.6, -0.3]]}],
        layout={
            "kind": "list",
            "poses": [[-0.2, 0.3, 0.0], [0.0, 0.3, 0.0], [0.2, 0.3, 0.0], [-0.8, -0.3, 0.0], [-0.9, 0.0, 0.0]],
        },
    )


def test_movers_give_the_central_engine_goals_commands_and_who_avoids_whom():
    scene = scene_from_dict(chase_scene())
    movers = Movers(scene)
    assert movers.pixels.tolist() == [0, 1, 2] and movers.cooperative.tolist() == [True] * 3 + [False, True]
    assert movers.pixel_assignment(np.array([2, 0, 1])).tolist() == [2, 0, 1, -1, -1]
    _, world = world_of(scene)
    goal, color = movers.goals(np.zeros((5, 2)), np.full((5, 3), 40), world.poses)
    np.testing.assert_array_equal(goal[4], world.poses[3, :2])  # the pursuer heads for its target
    assert np.isnan(goal[3]).all() and (goal[:3] == 0).all()  # the mover has none; the pixels keep theirs
    assert (color[3] == 255).all() and (color[[0, 1, 2, 4]] == 40).all()
    command, velocity = movers.commands(np.ones((5, 2)), np.zeros((5, 2)), world.poses, 1.0, DT)  # it sets off
    np.testing.assert_allclose(command[3], [0.2, 0.0])
    np.testing.assert_array_equal(velocity[3], command[3])
    assert (command[[0, 1, 2, 4]] == 1).all() and (velocity[[0, 1, 2, 4]] == 0).all()
    world.set_commands(command)
    world.step(DT)
    assert np.hypot(*(world.poses[3, :2] - scripted_position(scene.scripted[3], 1.1))) < 0.001


def test_the_central_engine_drives_scripted_movers_and_pursuers(tmp_path):
    scene = scene_from_dict(chase_scene(), source=str(tmp_path / "chase.toml"))
    out = run_central(scene, tmp_path / "run", video=False, progress=None)
    traj = dict(np.load(out / "trajectory.npz"))
    m = json.loads((out / "metrics.json").read_text())
    assert m["contacts"] == 0
    t, pose, goal, assignment = traj["t"], traj["pose"][:, :, :2], traj["goal"], traj["assignment"]
    assert t[-1] == 8.0
    path = np.array([scripted_position(scene.scripted[3], s) for s in t])
    assert np.hypot(*(pose[:, 3] - path).T).max() < 0.01  # the mover keeps to its script
    assert (assignment[:, 3:] == -1).all() and set(assignment[-1, :3].tolist()) == {0, 1, 2}  # 3 goals, 3 pixels
    assert np.hypot(*(goal[:, 4] - pose[:, 3]).T).max() < 0.01  # the pursuer's goal: where the mover is
    assert pose[-1, 4, 0] - pose[0, 4, 0] > 0.6  # it followed it across (at an e-puck's 0.12 m/s)
