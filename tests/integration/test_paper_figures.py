"""bench.paper_figures --quick: the paper's Figs. 13-15 pipeline end to end, small (2 runs x 2 epsilons,
3 short steps), into a temporary directory."""

from __future__ import annotations

import numpy as np
import pytest

from agent.core.params import EPUCK
from bench import paper_figures


# About 15 s on an idle 2-core machine; the timeout leaves room for a loaded one (no wall-time assertion).
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_quick_reproduction_writes_sane_figures(tmp_path):
    summary = paper_figures.main(["--quick", "--out", str(tmp_path)])

    for name in ("fig13_path_length.png", "fig14_epsilon.png", "fig15_trajectories.png"):
        png = tmp_path / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 30_000  # drawn, not an empty canvas
    text = (tmp_path / "paper_figures.md").read_text()
    assert "Command: `.venv/bin/python -m bench.paper_figures --quick" in text and "### Fig. 14" in text

    assert sorted(summary.runs) == [0.001, 1.0] and all(len(v) == 2 for v in summary.runs.values())
    poor, good = summary.per_eps(1.0), summary.per_eps(0.001)
    for runs in summary.runs.values():
        for run in runs:
            assert run.path.shape == (3, 14) and (run.path > 0).all()
            assert run.contacts == 0
            assert np.array(run.calls.cold).sum() == 3  # one cold start per image
    # The auction never beats the optimum, and a poor epsilon_A costs at least as much as a good one.
    for st in (poor, good):
        assert (st["ratio_first"] >= 1 - 1e-9).all()
    assert poor["first_cost"].mean() >= good["first_cost"].mean()
    assert poor["ratio_first"].mean() >= good["ratio_first"].mean()
    for run in summary.runs[0.001]:  # paper 5.1.1: within N (epsilon_A + Delta C) of the optimum
        cold = np.array(run.calls.cold)
        gap = np.array(run.calls.cost)[cold] - np.array(run.calls.optimum)[cold]
        assert (gap <= 14 * (0.001 + EPUCK.assign_hysteresis) + 1e-9).all()
    # Cold starts scale epsilon down: more rounds for the small epsilon_A.
    assert good["rounds"][good["cold"]].mean() > poor["rounds"][poor["cold"]].mean()
