"""Each Python process's CPU seconds and command line, appended as a JSON line to ``$PROCESS_CPU_LOG``
when it exits, for every process started with this folder on ``PYTHONPATH`` (docs/testing.md):

    PYTHONPATH=tests/support/process_cpu PROCESS_CPU_LOG=$PWD/procs.jsonl .venv/bin/python -m pytest ...

A process killed by a signal it does not handle writes nothing."""

import atexit
import json
import os
import resource
import sys


def _log() -> None:
    used = resource.getrusage(resource.RUSAGE_SELF)
    with open(os.environ["PROCESS_CPU_LOG"], "a") as log:
        log.write(json.dumps({"argv": sys.argv, "cpu_s": used.ru_utime + used.ru_stime}) + "\n")


if os.environ.get("PROCESS_CPU_LOG"):
    atexit.register(_log)
