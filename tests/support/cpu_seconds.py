"""A pytest plugin: each test's wall and CPU seconds, the CPU of the test's process and of the children
it waited for (``resource.getrusage``), appended as a JSON line to the file ``$TEST_CPU_LOG``. Under
pytest-xdist each worker appends its own tests. docs/testing.md, "How long each pass takes":

    TEST_CPU_LOG=cpu.jsonl .venv/bin/python -m pytest -p tests.support.cpu_seconds -m "slow and wall_clock"
"""

from __future__ import annotations

import json
import os
import resource
import time

import pytest


def _cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def pytest_configure(config):
    if not os.environ.get("TEST_CPU_LOG"):
        raise pytest.UsageError("tests.support.cpu_seconds: set TEST_CPU_LOG to the file to append to")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    wall, cpu = time.monotonic(), _cpu_seconds()
    yield
    line = {"test": item.nodeid, "wall_s": time.monotonic() - wall, "cpu_s": _cpu_seconds() - cpu}
    with open(os.environ["TEST_CPU_LOG"], "a") as log:
        log.write(json.dumps(line) + "\n")
