"""A clone that was never installed has no compiled robot core: it stops with one line saying how
to build it, not with a traceback."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_a_clone_without_the_compiled_core_says_how_to_build_it(tmp_path):
    for package in ("agent", "transport"):
        shutil.copytree(REPO / package, tmp_path / package, ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    out = subprocess.run(
        [sys.executable, "-c", "import agent.core.step"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "make run" in lines[0] and "Traceback" not in out.stderr
