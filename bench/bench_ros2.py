"""What one control tick costs on the ROS 2 path, against the 0.1 s tick of the paper's 10 Hz loop.

Side by side in one run, through an embedded Zenoh router on loopback:

* `Ros2Backend.set_commands` for N robots with a Twist only, and with a Twist and a ColorRGBA
  (rosbags encodes each message; each is one Zenoh put with rmw_zenoh's attachment);
* `Ros2PoseSource.latest` after one PoseStamped per robot has arrived (rosbags decodes each).

The variants alternate round by round so that both see the same machine load; the median of the
rounds is reported.

    .venv/bin/python -m bench.bench_ros2            # writes bench/results/ros2.md
    .venv/bin/python -m bench.bench_ros2 --quick    # a short smoke run, prints only
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from bench.common import write_results
from hardware.ros2 import Ros2Backend, Ros2BackendConfig, Ros2PosesConfig, Ros2PoseSource
from sim.emulators.mocap import MocapEmulator
from transport.session import client_of, loopback_router, open_session

TICK = 0.1  # s: the paper's 10 Hz control loop
ARRIVAL = 0.5  # s allowed for N poses to cross the loopback router before they are read


def time_commands(backend: Ros2Backend, n: int, with_colors: bool) -> float:
    ids = np.arange(n)
    v, w = np.full(n, 0.05), np.full(n, 0.2)
    colors = np.tile([255.0, 128.0, 0.0], (n, 1)) if with_colors else None
    start = time.perf_counter()
    backend.set_commands(ids, v, w, colors)
    return time.perf_counter() - start


def time_poses(source: Ros2PoseSource, mocap: MocapEmulator, n: int) -> float:
    """Time of the one latest() that reads the n poses just published (given time to arrive first)."""
    before = source.stats()["received"]
    mocap.publish_once(0.0)
    time.sleep(ARRIVAL)
    start = time.perf_counter()
    source.latest()
    elapsed = time.perf_counter() - start
    if source.stats()["received"] != before + n:
        raise RuntimeError(f"{source.stats()['received'] - before} of {n} poses arrived within {ARRIVAL} s")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_ros2")
    parser.add_argument("--quick", action="store_true", help="few rounds, small N, print only")
    args = parser.parse_args()
    sizes, rounds = ((10, 100), 5) if args.quick else ((10, 100, 1000), 30)
    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    router = loopback_router()
    rows = []
    with open_session(router):
        for n in sizes:
            config = Ros2BackendConfig(namespaces=[f"robot{i}" for i in range(n)], watchdog=60.0)
            rows_of_n: dict[str, list[float]] = {"twist": [], "twist+color": [], "poses": []}
            with (
                Ros2Backend(config, client_of(router)) as backend,
                Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as source,
                MocapEmulator(
                    lambda t, n=n: np.zeros((n, 3)), client_of(router), rate=1e-3
                ) as mocap,  # once at start, then by hand
            ):
                deadline = time.monotonic() + 30.0  # the emulator's first publication, at start, all read
                while len(source.latest()) < n or mocap.published < n:
                    if time.monotonic() > deadline:
                        raise RuntimeError("the emulator's first poses did not all arrive")
                    time.sleep(0.05)
                time.sleep(ARRIVAL)
                source.latest()
                for _ in range(rounds):
                    rows_of_n["twist"].append(time_commands(backend, n, with_colors=False))
                    rows_of_n["twist+color"].append(time_commands(backend, n, with_colors=True))
                    rows_of_n["poses"].append(time_poses(source, mocap, n))
            medians = {k: statistics.median(v) for k, v in rows_of_n.items()}
            rows.append(
                f"| {n} | {medians['twist'] * 1e3:.2f} | {medians['twist+color'] * 1e3:.2f} | "
                f"{medians['poses'] * 1e3:.2f} | {(medians['twist+color'] + medians['poses']) / TICK * 100:.1f}% |"
            )
    lines = [
        f"Median of {rounds} alternating rounds; times in ms per tick for all N robots. "
        f"Load average when the run began: {load:.1f}.",
        "",
        "| N robots | set_commands, Twist | set_commands, Twist + ColorRGBA | latest() of N poses | both, share of a 0.1 s tick |",
        "|---|---|---|---|---|",
        *rows,
    ]
    if args.quick:
        print("\n".join(lines))
    else:
        write_results("ros2", "ROS 2 over rmw_zenoh: the cost of a control tick", "python -m bench.bench_ros2", lines)


if __name__ == "__main__":
    main()
