"""Fixtures shared by end-to-end test modules."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.study import GRID, study


@pytest.fixture(scope="module")
def grid(shared_runs) -> Path:
    """The 2 x 2 x 2-seed study, run once per session for the tests that read its outputs (a module
    fixture alone is made once per xdist worker)."""

    def make(root: Path) -> None:
        spec = root / "grid.toml"
        spec.write_text(GRID)
        result = study(spec, root / "out", "--jobs", "2")
        assert result.returncode == 0, result.stderr[-3000:]
        assert result.stdout.strip().splitlines()[-1] == str(root / "out" / "report.html")

    return shared_runs.once("study-grid", make)
