"""`python -m tests.support.end_to_end`: the end-to-end passes of `make test`, side by side.

The serial tests run one at a time at this process's priority: what they check happens on the wall
clock. Beside them, the lock-step tests run on every core at the lowest priority, in a session of their
own (sim.processes.start_session gives every session their runs start the same priority), so they take
only the CPU the serial runs leave; a lock-step run is the same run however late it is. The lock-step
pass prints as it goes, the serial pass's report follows it; the exit status is the first failure's.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile

from sim.processes import start_session

PYTEST = [sys.executable, "-m", "pytest", "-q"]
SERIAL = [*PYTEST, "-m", "slow and serial", "--durations=5"]
LOCKSTEP = [*PYTEST, "-m", "slow and not serial", "-n", "3", "--dist", "loadgroup", "--durations=10"]
LOWEST = 19  # nice


def main() -> int:
    with tempfile.TemporaryFile() as report:
        serial = subprocess.Popen(SERIAL, stdout=report, stderr=subprocess.STDOUT)
        os.nice(LOWEST)  # after the serial pass started: only the lock-step pass inherits it
        lockstep = start_session(LOCKSTEP)
        try:
            codes = lockstep.wait(), serial.wait()
        except KeyboardInterrupt:  # the serial pass, in our session, has its own; the lock-step one has not
            lockstep.send_signal(signal.SIGINT)
            codes = lockstep.wait(), serial.wait()
        report.seek(0)
        print("\nthe serial tests, beside the lock-step ones:", flush=True)
        sys.stdout.buffer.write(report.read())
    return next((code for code in codes if code != 0), 0)


if __name__ == "__main__":
    sys.exit(main())
