"""Dynamic obstacles (paper 7.4.2, Fig. 19), distributed: in the shipped scene `dynamic-obstacles` 14
e-puck agents hold a disk while two uncontrolled movers (scripted robots: no agent, they follow their
waypoints and avoid nobody) cross it, the second pursuing the first. The agents take full
responsibility for avoiding them; the world counts every contact (robot-robot, movers included,
robot-wall, robot-obstacle) in metrics.json's `contacts`."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.scene import load_scene
from tests.conftest import run_scene, run_scenes
from tests.support.formation import first_formed_after, formed, goal_error, members_and_current, stays_formed_from

TOLERANCE = 0.01  # m
CLEAR_OF_DISK = 0.3  # m of clearance from every controlled robot: a mover has left the disk


@pytest.mark.slow
def test_fourteen_hold_a_disk_while_two_movers_cross_it_without_contact(tmp_path):
    scene = load_scene("dynamic-obstacles")
    movers = sorted(scene.scripted)
    assert len(movers) == 2
    controlled = [i for i in range(scene.robots) if i not in scene.scripted]
    assert len(controlled) == 14

    # two agent hosts of seven: a lock-step run is the same run with a process per robot
    # (test_one_controller.py), at a fraction of the CPU
    m, traj = run_scene(tmp_path, "dynamic-obstacles", "-k", "7", timeout=300)
    assert m["engine"] == "distributed" and m["agent_processes"] == 2

    # No contact of any kind: between agents, between agents and movers, with the walls.
    assert m["contacts"] == 0, m["contact_events"][:5]
    assert m["min_clearance_m"] > 0 and m["min_clearance_substep_m"] > 0
    t, pose, radius = traj["t"], traj["pose"], traj["radius"]
    gap = (
        np.hypot(*(pose[:, controlled, None, :2] - pose[:, None, movers, :2]).transpose(3, 0, 1, 2))
        - radius[controlled][None, :, None]
        - radius[movers][None, None, :]
    )  # (T, 14, 2)
    assert gap.min() > 0

    # The movers are uncontrolled (not in the goal set) and really crossed the disk, close enough
    # that the disk had to make way.
    members, _ = members_and_current(traj)
    assert not members[:, movers].any() and members[-1, controlled].all()
    assert pose[-1, movers[0], 0] > 1.1 and pose[-1, movers[1], 0] > 0.8
    assert gap.min(axis=1).min(axis=0).max() < 0.1  # each mover came within 10 cm of a robot
    ok = formed(traj, TOLERANCE)
    near = gap.min(axis=(1, 2)) < CLEAR_OF_DISK
    arrive = t[np.flatnonzero(near)[0]]
    leave = t[np.flatnonzero(near)[-1] + 1]
    assert ok[t < arrive].any(), "the disk was not formed before the movers arrived"
    err = goal_error(traj)[:, controlled]
    assert np.nanmax(err[(t >= arrive) & (t < leave)]) > 0.05, "the movers did not disturb the disk"

    # Once the movers have left, the disk re-forms within 1 cm and stays formed.
    reform = first_formed_after(traj, leave, TOLERANCE)
    print(
        f"\ndynamic obstacles: movers near the disk from {arrive:.1f} s to {leave:.1f} s, disk re-formed "
        f"{reform} s after they left; contacts {m['contacts']}, closest mover-robot gap {gap.min():.4f} m, "
        f"min clearance {m['min_clearance_m']:.4f} m"
    )
    assert reform is not None
    assert stays_formed_from(traj, leave + reform, TOLERANCE)
    assert ok[-1]


@pytest.mark.slow
def test_the_movers_touch_no_robot_whatever_the_seed(tmp_path):
    """The seed moves every robot a little differently, and so where each stands when the movers come:
    the central engine's runs (the agents' own policy, in one process) have no contact. Robots boxed in
    by the disk used to shrink the movers' horizon with the rest: seeds 2, 3, 4 and 11 touched a mover,
    up to 2.8 cm deep, and seed 12 passed it 0.2 mm apart (seeds 1-12 all clear now, 1.7 cm or more when
    this was written; asserted: above 0)."""
    seeds = (1, 2, 3, 4, 11, 12)
    runs = run_scenes(
        tmp_path, {f"seed{s}": ("dynamic-obstacles", "--engine", "central", "--seed", str(s)) for s in seeds}
    )
    contacts = {name: m["contacts"] for name, (m, _) in runs.items()}
    assert not any(contacts.values()), contacts
    assert min(m["min_clearance_m"] for m, _ in runs.values()) > 0
