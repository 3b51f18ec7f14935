"""RVO2's Circle scenario on the central engine, scaled down to 64 agents (radius 51.2, the same
spacing as the 250-agent original) to stay within seconds; the full Circle and Blocks run side by
side with RVO2 in bench/bench_orca.py."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from agent.core.control import preferred_velocity
from sim.central.rvo import CentralOrca, Options

# RVO2 (pyrvo 0.4.3) on the same 64-agent Circle: steps to completion (`bench_orca.py --quick`)
RVO2_STEPS = 1727


def test_scaled_circle_completes_within_a_tenth_over_rvo2s_steps_without_any_overlap():
    n, radius = 64, 1.5
    angle = np.arange(n) * 2.0 * np.pi / n
    start = 51.2 * np.stack([np.cos(angle), np.sin(angle)], -1)
    goal = -start
    sim = CentralOrca(0.25, 15.0, 10, 10.0, 10.0, radius, 2.0, Options(safety_margin=0.1, perturbation=1e-4, seed=0))
    for p in start:
        sim.add_agent(p)
    done_at = None
    for step in range(1, int(1.1 * RVO2_STEPS) + 1):
        sim.set_pref_velocities(preferred_velocity(sim.position, goal, 1.0, 1.0))
        sim.do_step()
        d, _ = cKDTree(sim.position).query(sim.position, k=2)
        assert d[:, 1].min() >= 2 * radius, f"overlap at step {step}"
        assert np.all(np.linalg.norm(sim.velocity, axis=1) <= 2.0 + 1e-9)
        if np.all(np.linalg.norm(sim.position - goal, axis=1) <= radius):
            done_at = step
            break
    assert done_at is not None, "not at the goals within 1.1x RVO2's steps"
    assert sim.fallback_count > 0  # the crowded centre exercised the fallback
