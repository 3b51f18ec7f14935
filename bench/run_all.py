"""Run the maintained benchmarks one after the other (those that take less than an hour, and no checkout but
the ones they make themselves).

Each writes its results, with its command and date, to bench/results/<name>.md.

BENCHMARKS.md holds today's figures, chosen from those by hand: it is not rebuilt from them.

make bench                      # everything (tens of minutes on 2 cores): python -m bench.run_all
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from .common import REPO, RESULTS

# Each a command line after `python -m`. Left out: those that need a checkout given by hand (--before DIR:
# bench_hosted sync and scenes), take an hour (bench_faults soak), print only (bench_faults faulty-peer),
# or time the live view (bench_view); and paper_figures fig4, which redraws a figure in docs/.
BENCHES = [
    ["bench.bench_world"],
    ["bench.bench_goals"],
    ["bench.bench_orca"],
    ["bench.bench_runtime"],
    ["bench.bench_agent_tick"],
    ["bench.bench_auction"],
    ["bench.bench_large"],
    ["bench.bench_hosted"],
    ["bench.bench_hosted", "sequence"],
    ["bench.bench_hosted", "animation"],
    ["bench.bench_hosted", "processes"],
    ["bench.paper_figures"],
    ["bench.paper_figures", "keyframes"],
    ["bench.paper_figures", "carry"],
    ["bench.bench_faults", "loss"],
    ["bench.bench_faults", "impaired"],
    ["bench.bench_faults", "speed-limit"],
    ["bench.bench_faults", "security"],
    ["bench.bench_hardware"],
    ["bench.bench_hardware", "epuck2"],
    ["bench.bench_hardware", "tracker"],
    ["bench.bench_hardware", "ros2"],
    ["bench.bench_outputs"],
    ["bench.bench_study"],
]


def main() -> int:
    listed = "\n".join(f"  python -m {' '.join(bench)}" for bench in BENCHES)
    argparse.ArgumentParser(
        prog="python -m bench.run_all",
        description=__doc__.splitlines()[0],
        epilog=f"in this order:\n{listed}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    ).parse_args()
    for bench in BENCHES:
        print(f"== {' '.join(bench)}", flush=True)
        code = subprocess.call([sys.executable, "-m", *bench], cwd=REPO)
        if code != 0:
            print(f"{' '.join(bench)} failed with code {code}", file=sys.stderr)
            return code
    print(f"results in {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
