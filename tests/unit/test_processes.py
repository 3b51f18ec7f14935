"""A program started at a lower priority starts its processes' sessions at that priority (sim.processes)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

# The child waits for its stdin to close, so it reads its session's priority after start_session set it.
NICED_PARENT = """
import os, subprocess, sys
from sim.processes import start_session
os.nice(7)
child = "import sys; sys.stdin.read(); print(open('/proc/self/autogroup').read(), os.getsid(0) == os.getpid())"
child = start_session([sys.executable, "-c", "import os; " + child], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
print(child.communicate("")[0])
"""


@pytest.mark.skipif(not Path("/proc/self/autogroup").exists(), reason="a kernel without autogroup")
def test_a_niced_program_starts_sessions_at_its_own_priority():
    """Linux schedules a session as one group at nice 0 whatever its processes' nice: `nice pixelswarm
    run` lowered the launcher alone while its agents, each in a session of its own, ran at full weight."""
    done = subprocess.run([sys.executable, "-c", NICED_PARENT], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    autogroup, own_session = done.stdout.rsplit(maxsplit=1)
    assert autogroup.split()[-2:] == ["nice", "7"] and own_session == "True"
