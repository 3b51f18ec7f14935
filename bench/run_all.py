"""Run the maintained benchmarks one after the other (those that need no other checkout or hour).

Each writes its results, with its command and date, to bench/results/<name>.md.

BENCHMARKS.md holds today's figures, chosen from those by hand: it is not rebuilt from them.

make bench                      # everything (tens of minutes on 2 cores): python -m bench.run_all
"""

from __future__ import annotations

import argparse
import subprocess
import sys

from .common import REPO, RESULTS

# Each a command line after `python -m`. Left out, as they compare with another checkout (--before)
# or take an hour: bench_hosted sync and scenes, bench_faults faulty-peer and soak, paper_figures fig4
# (it redraws a figure in docs/), bench_view.
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
