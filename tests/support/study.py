"""`pixelswarm study` as a user runs it, and the small grid the study tests share (test_study,
test_study_cluster)."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

GRID = """
name = "grid"
seeds = [1, 2]
[base]
scene = "swap"
engine = "central"
[axes]
robots = [2, 4]
duration = [1.0, 1.5]
"""


def study(
    spec: Path, out: Path, *extra: str, timeout: float = 300, tmpdir: Path | None = None
) -> subprocess.CompletedProcess:
    """The study command; ``tmpdir``: its TMPDIR, to see what it leaves there."""
    command = [sys.executable, "-m", "sim.cli", "study", str(spec), "--out", str(out), *extra]
    env = dict(os.environ, TMPDIR=str(tmpdir)) if tmpdir is not None else None
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout, cwd=REPO, env=env)


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
