"""The paper's image sequence with 100 robots in agent hosts, distributed, checked against issue 5's
acceptance: zero contacts, every robot within 1 cm of its goal at the end of each hold, no
unresolved deadlock, every agreed assignment within N (epsilon_A + Delta C) + penalties of scipy's
optimum on the positions the robots bid from. Too long for the test suite (about 6 minutes on 2
cores), so it lives here; the suite runs its first two images (test_image_display_distributed.py).

    .venv/bin/python -m bench.bench_sequence [--scene paper-sequence-100] [-k 10]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from tests.assignment_quality import agreements

from .common import run_cli_scene, steps_table, write_results

EPS_A, DELTA_C = 1e-3, 5e-3  # agent.core.params defaults


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scene", default="paper-sequence-100")
    parser.add_argument("-k", type=int, default=10, help="robots per agent process")
    args = parser.parse_args()
    ran = run_cli_scene([args.scene, "-k", str(args.k)])
    if ran is None:
        return 1
    m, traj, wall = ran
    rep = agreements(traj)
    complete = [a for a in rep.agreements if np.isfinite(a.cost)]
    beyond = [a for a in complete if a.cost > a.optimum + len(a.members) * (EPS_A + DELTA_C) + a.penalties + 1e-6]
    gaps = rep.gaps()
    ok_steps = all(s["converged_at"] is not None and s["max_goal_error_at_end"] <= 0.01 for s in m["steps"])
    passed = m["contacts"] == 0 and ok_steps and not beyond and rep.inconsistent == 0 and rep.shared_goals == 0
    rows = steps_table(m)
    notes = [
        "",
        f"Scene `{args.scene}`, {m['robots']} robots, {args.k} per agent process; wall {wall:.0f} s for "
        f"{m['duration_s']:.0f} s of display time; contacts {m['contacts']}; min clearance "
        f"{m['min_clearance_m'] * 1e3:.1f} mm.",
        f"Agreements: {len(complete)} complete, {len(beyond)} beyond N (eps_A + Delta C) + penalties, "
        f"{np.mean(gaps <= 1e-9) * 100:.1f} % equal to scipy's optimum, largest gap {np.max(gaps):.4f} m^2; "
        f"a robot announcing two goals for one instance: {rep.inconsistent}; two robots on one goal: "
        f"{rep.shared_goals}.",
        f"Acceptance (issue 5): {'PASS' if passed else 'FAIL'}.",
    ]
    write_results(
        "sequence",
        "The paper's sequence with 100 robots, distributed in agent hosts (issue 5)",
        f".venv/bin/python -m bench.bench_sequence --scene {args.scene} -k {args.k}",
        rows + notes,
    )
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
