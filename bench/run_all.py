"""Run every benchmark; each writes its results, with its command and date, to bench/results/<name>.md.

BENCHMARKS.md holds today's figures, chosen from those by hand: it is not rebuilt from them.

make bench                      # everything (tens of minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from .common import REPO, RESULTS

BENCHES = [
    "bench.bench_world",
    "bench.bench_goals",
    "bench.bench_orca",
    "bench.bench_runtime",
    "bench.bench_agent_tick",
    "bench.bench_take",
    "bench.bench_auction",
    "bench.bench_sequence",
    "bench.bench_keyframes",
    "bench.bench_carry",
    "bench.bench_large",
    "bench.bench_hosted",
    "bench.paper_figures",
    "bench.bench_animation",
    "bench.bench_loss",
    "bench.bench_impaired",
    "bench.bench_speed_limit",
    "bench.bench_ros2",
    "bench.bench_epuck2",
    "bench.bench_hardware",
    "bench.bench_tracker",
    "bench.bench_outputs",
    "bench.bench_security",
    "bench.bench_study",
]


def main() -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    for module in BENCHES:
        print(f"== {module}", flush=True)
        code = subprocess.call([sys.executable, "-m", module], cwd=REPO)
        if code != 0:
            print(f"{module} failed with code {code}", file=sys.stderr)
            return code
    print(f"results in {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
