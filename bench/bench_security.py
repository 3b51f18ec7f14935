"""What a secured bus costs: robot 3's state messages through a router to the recorder, on plain TCP
without rules (the default) beside mutual TLS or user/password with the access rules of 10 and 1000
robots, side by side in one run (cases interleaved, rounds repeated).

    .venv/bin/python -m bench.bench_security [--messages 20000] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import struct
import tempfile
import time
from pathlib import Path

from transport.bus import Bus
from transport.keys import Keys
from transport.security import client_config, make_certificates, router_config
from transport.session import ZenohSettings, client_of, free_port, open_session

from .common import write_results

KEYS = Keys("default")
PAYLOAD = 64  # bytes, about a state message
PACED = 500  # messages sent one by one for latency
PACE = 0.001  # s between paced messages


def _sessions(case: str, folders: dict[int, Path]) -> tuple[ZenohSettings, ZenohSettings, ZenohSettings]:
    """Router, robot-3 publisher and recorder subscriber settings for a case."""
    if case == "tcp":
        router = ZenohSettings(mode="router", listen=[f"tcp/127.0.0.1:{free_port()}"])
        return router, client_of(router), client_of(router)
    kind, robots = case.split("-")
    auth = "tls" if kind == "mtls" else "usrpwd"
    folder = folders[int(robots)]
    endpoint = f"tls/127.0.0.1:{free_port()}"
    return (
        router_config(folder, endpoint, auth=auth),
        client_config(folder, "robot-3", endpoint, auth=auth),
        client_config(folder, "recorder", endpoint, auth=auth),
    )


def _measure(case: str, folders: dict[int, Path], messages: int) -> tuple[float, float]:
    """Messages per second delivered, and the median one-way latency in microseconds."""
    router_settings, pub_settings, sub_settings = _sessions(case, folders)
    router = open_session(router_settings)
    try:
        with Bus(pub_settings) as robot, Bus(sub_settings) as recorder:
            inbox = recorder.subscribe_raw(KEYS.everything)
            key = KEYS.state((0, 0), 3)
            deadline = time.monotonic() + 10
            while not inbox.drain() and time.monotonic() < deadline:  # until the route exists
                robot.put(key, bytes(PAYLOAD))
                time.sleep(0.01)
            time.sleep(0.2)
            inbox.drain()
            filler = bytes(PAYLOAD - 8)
            got, start = 0, time.perf_counter()
            for _ in range(messages):
                robot.put(key, struct.pack("<d", 0.0) + filler)
            while got < messages and time.perf_counter() - start < 60:
                got += len(inbox.drain())
                time.sleep(0.001)
            rate = got / (time.perf_counter() - start)
            delays = []
            for _ in range(PACED):
                robot.put(key, struct.pack("<d", time.time()) + filler)
                time.sleep(PACE)
                delays += [(t - struct.unpack("<d", payload[:8])[0]) * 1e6 for _, payload, t in inbox.drain()]
            time.sleep(0.1)
            delays += [(t - struct.unpack("<d", payload[:8])[0]) * 1e6 for _, payload, t in inbox.drain()]
            return rate, statistics.median(delays)
    finally:
        router.close()


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--messages", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    cases = ["tcp", "mtls-10", "usrpwd-10", "mtls-1000"]
    results: dict[str, list[tuple[float, float]]] = {c: [] for c in cases}
    with tempfile.TemporaryDirectory() as tmp:
        folders = {n: make_certificates(Path(tmp) / f"certs-{n}", n) for n in (10, 1000)}
        rules = {
            n: len(json.loads((folders[n] / "router.json5").read_text().split("\n", 1)[1])["access_control"]["rules"])
            for n in folders
        }
        for r in range(args.rounds):
            for case in cases:
                results[case].append(_measure(case, folders, args.messages))
                print(f"round {r} {case}: {results[case][-1][0]:.0f} msg/s, {results[case][-1][1]:.0f} us", flush=True)
    labels = {
        "tcp": "plain TCP, no rules (default)",
        "mtls-10": f"mutual TLS, rules of 10 robots ({rules[10]} rules)",
        "usrpwd-10": f"TLS + user/password, rules of 10 robots ({rules[10]} rules)",
        "mtls-1000": f"mutual TLS, rules of 1000 robots ({rules[1000]} rules)",
    }
    base = statistics.median(rate for rate, _ in results["tcp"])
    lines = [
        "| bus | messages/s, median (min-max) of rounds | vs plain | one-way latency us, median (min-max) |",
        "|---|---|---|---|",
    ]
    for case in cases:
        rates = [r for r, _ in results[case]]
        latencies = [d for _, d in results[case]]
        rate = statistics.median(rates)
        lines.append(
            f"| {labels[case]} | {rate:,.0f} ({min(rates):,.0f}-{max(rates):,.0f}) | {rate / base:.2f} "
            f"| {statistics.median(latencies):.0f} ({min(latencies):.0f}-{max(latencies):.0f}) |"
        )
    lines += [
        "",
        f"{args.messages} messages of {PAYLOAD} bytes from a robot-3 session to a recorder session subscribed to "
        f"everything, through a router, all three in one process on 127.0.0.1; latency from {PACED} messages "
        f"sent {PACE * 1000:.0f} ms apart. Cases interleaved over {args.rounds} rounds; the machine is shared, "
        "so the spread between rounds is wide.",
    ]
    write_results(
        "security",
        "Secured bus: throughput and latency beside plain TCP",
        f".venv/bin/python -m bench.bench_security --messages {args.messages} --rounds {args.rounds}",
        lines,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
