"""A robot's process started as `python -m agent` (as a robot's computer may start it, not through
`pixelswarm`) loads OpenBLAS with one thread: a thread per core doubled the process's start-up CPU,
for no large product an agent makes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import REPO

PROBE = """
import runpy, sys
sys.argv = ["agent", "--help"]
try:
    runpy.run_module("agent", run_name="__main__")
except SystemExit:
    pass
from threadpoolctl import threadpool_info
print(max(i["num_threads"] for i in threadpool_info() if i["internal_api"] == "openblas"))
"""


@pytest.mark.parametrize("given, threads", [(None, "1"), ("2", "2")])  # a user's own setting stands
def test_an_agent_process_loads_openblas_with_one_thread_unless_told(given, threads):
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    env |= {} if given is None else {"OPENBLAS_NUM_THREADS": given}
    got = subprocess.run([sys.executable, "-c", PROBE], env=env, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert got.returncode == 0, got.stderr[-2000:]
    assert got.stdout.split()[-1] == threads, got.stdout
