"""Run every benchmark and assemble BENCHMARKS.md from their results (bench/results/*.md).

make bench                      # everything (tens of minutes on 2 cores)
.venv/bin/python -m bench.run_all --assemble   # only rebuild BENCHMARKS.md from stored results
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

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
ORDER = [
    "one-controller",
    "runtime",
    "agent_tick",
    "state_intake",
    "state_take",
    "auction",
    "sequence",
    "large",
    "large-trial",
    "hosted",
    "world",
    "orca",
    "loss",
    "impaired",
    "speed_limit",
    "goals",
    "keyframes",
    "animation",
    "carry",
    "ros2",
    "epuck2",
    "hardware",
    "tracker",
    "outputs",
    "security",
    "study",
    "paper_figures",
]


def assemble() -> Path:
    parts = [
        "# Benchmarks",
        "",
        "Every figure below was measured by the command shown with it, on the machine named (2 cores, "
        "shared with other work at the time, so expect +-30 % between runs). Each benchmark compares "
        "side by side in one run against its reference where there is one (RVO2 through pyrvo, "
        "scikit-learn's KMeans, scipy's linear_sum_assignment). `make bench` reruns them all.",
        "",
    ]
    files = sorted(RESULTS.glob("*.md"), key=lambda p: (ORDER.index(p.stem) if p.stem in ORDER else 99, p.stem))
    for f in files:
        parts += [f.read_text().strip(), ""]
    out = REPO / "BENCHMARKS.md"
    out.write_text("\n".join(parts))
    return out


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--assemble", action="store_true", help="only rebuild BENCHMARKS.md")
    args = parser.parse_args()
    if not args.assemble:
        for module in BENCHES:
            print(f"== {module}", flush=True)
            code = subprocess.call([sys.executable, "-m", module], cwd=REPO)
            if code != 0:
                print(f"{module} failed with code {code}", file=sys.stderr)
                return code
    print(assemble())
    return 0


if __name__ == "__main__":
    sys.exit(main())
