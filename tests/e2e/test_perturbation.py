"""Perturbation recovery (paper 7.4.3, Fig. 20), distributed: the shipped scene `perturbation` has 14
e-puck agents form a disk; at t = 10 s two of them are picked up and put down outside it (teleport
events of the world). The swarm re-forms the disk through goal reassignment, without contact."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.scene import load_scene
from tests.conftest import run_scene
from tests.support.formation import first_formed_after, formed, stays_formed_from

TOLERANCE = 0.01  # m: every robot within 1 cm of its agreed goal


@pytest.mark.slow
def test_two_robots_teleported_out_of_a_disk_of_14_recover_within_10_s_without_contact(tmp_path):
    scene = load_scene("perturbation")
    moves = [e for e in scene.events if e["kind"] == "teleport"]
    assert len(moves) == 2 and len({e["t"] for e in moves}) == 1
    t_move = moves[0]["t"]

    # two agent hosts of seven: a lock-step run is the same run with a process per robot
    # (test_one_controller.py), at a fraction of the CPU
    m, traj = run_scene(tmp_path, "perturbation", "-k", "7", timeout=300)
    assert m["engine"] == "distributed" and m["agent_processes"] == 2

    assert m["contacts"] == 0, m["contact_events"][:5]
    assert m["min_clearance_m"] > 0 and m["min_clearance_substep_m"] > 0

    t, pose = traj["t"], traj["pose"]
    k = int(np.searchsorted(t, t_move - 1e-9))
    for e in moves:  # the robots really were moved, at that tick
        assert np.allclose(pose[k, e["robot"], :2], e["pose"][:2])
        assert np.hypot(*(pose[k - 1, e["robot"], :2] - e["pose"][:2])) > 0.4
    ok = formed(traj, TOLERANCE)
    assert ok[k - 1], "the disk was not formed when the robots were picked up"
    assert not ok[k]

    recovery = first_formed_after(traj, t_move, TOLERANCE)
    print(
        f"\nperturbation: disk formed at {m['steps'][0]['converged_at']} s, recovered {recovery} s after "
        f"the two robots were moved; contacts {m['contacts']}, min clearance {m['min_clearance_m']:.4f} m"
    )
    assert recovery is not None and recovery <= 10.0
    assert stays_formed_from(traj, t_move + recovery, TOLERANCE), "the disk came apart again"

    # Recovery by reassignment: the agreed goals after differ from those before the robots were moved.
    before, after = traj["assignment"][k - 1], traj["assignment"][-1]
    assert sorted(before.tolist()) == sorted(after.tolist()) == list(range(14))
    assert (before != after).sum() >= 2
