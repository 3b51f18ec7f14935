"""What the browser- and Foxglove-ready outputs cost, side by side in one run.

Run from the repository root:

    .venv/bin/python bench/bench_outputs.py          # prints a table and writes bench/results/outputs.md
    .venv/bin/python bench/bench_outputs.py --mcap [--tree DIR]   # log.mcap of a 100-robot run: bench/results/mcap.md

Video: the same frames (100 robots crossing a 4 x 3 m arena, 720 px, 300 frames = 30 s at 10 fps)
written as MPEG-4 part 2 with OpenCV (what display.mp4 was) and as H.264 with PyAV at two x264
presets (the first is what display.mp4 is now): seconds to write, file size.

Foxglove: building one ``foxglove.SceneUpdate`` (sim.outputs.foxglove.scene_update) and encoding it with
protobuf (Foxglove's SDK), as the recorder does at every recorded tick (10 a second), at 14, 100 and 1000 robots.

``--mcap``: the size of log.mcap for one 100-robot lock-step run (:data:`MCAP_RUN`, the same run bit
for bit each time), per channel: messages, their bytes, and those bytes compressed alone with zstd
(the file compresses the channels together, in chunks). ``--tree DIR`` runs the code of another
checkout (e.g. a ``git worktree`` of an earlier commit, its compiled core built) for a before figure.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import av
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import REPO, write_results  # noqa: E402
from sim.outputs import render  # noqa: E402
from sim.outputs.foxglove import scene_update  # noqa: E402

ARENA = (0.0, 0.0, 4.0, 3.0)
FRAMES, ROBOTS, SIZE_PX, FPS = 300, 100, 720, 10
REPEATS = 3


def crossing(T: int, N: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    start = rng.uniform([0.2, 0.2], [3.8, 2.8], (N, 2))
    end = rng.uniform([0.2, 0.2], [3.8, 2.8], (N, 2))
    s = np.linspace(0.0, 1.0, T)[:, None, None]
    xy = start + s * (end - start)
    theta = np.broadcast_to(np.arctan2(*(end - start).T[::-1]), (T, N))
    pose = np.concatenate([xy, theta[..., None]], axis=-1)
    color = rng.integers(0, 256, (N, 3), dtype=np.uint8)
    return np.arange(T) / FPS, pose, np.full(N, 0.045), color, np.broadcast_to(end, (T, N, 2))


def video_rows(tmp: Path) -> list[tuple[str, float, float]]:
    t, pose, radius, color, goal = crossing(FRAMES, ROBOTS)
    variants = [
        ("MPEG-4 part 2, OpenCV 'mp4v'", {"fourcc": "mp4v"}, None),
        (f"H.264, PyAV libx264 preset {render.H264_OPTIONS['preset']} (display.mp4)", {}, None),
        ("H.264, PyAV libx264 preset medium", {}, "medium"),
    ]
    rows = []
    for name, kwargs, preset in variants:
        options = dict(render.H264_OPTIONS, **({"preset": preset} if preset else {}))
        saved, render.H264_OPTIONS = render.H264_OPTIONS, options
        try:
            times = []
            for k in range(REPEATS):
                path = tmp / f"v{len(rows)}-{k}.mp4"
                start = time.perf_counter()
                render.write_video(
                    path, render.Recording(t, pose, radius, ARENA, (), goal, color), fps=FPS, size_px=SIZE_PX, **kwargs
                )
                times.append(time.perf_counter() - start)
        finally:
            render.H264_OPTIONS = saved
        rows.append((name, float(np.median(times)), path.stat().st_size / 1e6))
    return rows


def scene_rows() -> list[tuple[int, float, int]]:
    rows = []
    for n in (14, 100, 1000):
        _, pose, radius, color, goal = crossing(2, n)
        times = []
        for _ in range(20):
            start = time.perf_counter()
            data = scene_update(1_000_000_000, pose[0], radius, color, goal=goal[0]).encode()
            times.append(time.perf_counter() - start)
        rows.append((n, float(np.median(times)) * 1e3, len(data)))
    return rows


MCAP_RUN = ["paper-sequence-100", "-k", "50", "--duration", "30", "--no-video", "--no-plots", "-q"]


def mcap_rows(tree: Path) -> list[str]:
    """log.mcap of :data:`MCAP_RUN` run from ``tree``: its bytes, and per channel what it holds."""
    import zstandard
    from mcap.reader import make_reader

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        command = [sys.executable, "-m", "sim.cli", "run", *MCAP_RUN, "--out", str(out)]
        subprocess.run(command, cwd=tree, check=True, capture_output=True)
        size = (out / "log.mcap").stat().st_size
        data: dict[str, list[bytes]] = {}
        with open(out / "log.mcap", "rb") as fh:
            reader = make_reader(fh)
            schemas: dict[str, str] = {}
            for schema, channel, message in reader.iter_messages():
                data.setdefault(channel.topic, []).append(message.data)
                schemas[channel.topic] = f"{schema.name} ({schema.encoding})" if schema else ""
    rows = [
        f"log.mcap: **{size:,} bytes** (`{' '.join(MCAP_RUN)}`)",
        "",
        "| channel | schema | messages | message bytes | zstd alone |",
        "|---|---|---|---|---|",
    ]
    compress = zstandard.ZstdCompressor(level=3).compress
    for topic, messages in sorted(data.items(), key=lambda kv: -sum(map(len, kv[1]))):
        raw = b"".join(messages)
        rows.append(f"| {topic} | {schemas[topic]} | {len(messages)} | {len(raw):,} | {len(compress(raw)):,} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--mcap", action="store_true", help="only log.mcap's size for one 100-robot run")
    parser.add_argument("--tree", type=Path, default=REPO, help="--mcap: the checkout whose code runs")
    args = parser.parse_args()
    if args.mcap:
        describe = ["git", "describe", "--always", "--dirty"]
        commit = subprocess.run(describe, cwd=args.tree, capture_output=True, text=True)
        write_results(
            "mcap",
            f"log.mcap of a 100-robot run, code at {commit.stdout.strip()}",
            ".venv/bin/python bench/bench_outputs.py --mcap" + ("" if args.tree == REPO else f" --tree {args.tree}"),
            mcap_rows(args.tree.resolve()),
        )
        return
    with tempfile.TemporaryDirectory() as tmp:
        video = video_rows(Path(tmp))
    scene = scene_rows()
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    lines = [
        "## Run outputs: display.mp4 encoders and the Foxglove scene channel",
        "",
        "Command: `.venv/bin/python bench/bench_outputs.py`",
        "",
        f"Python {platform.python_version()}, PyAV {av.__version__}, {platform.machine()}; "
        f"median of {REPEATS} runs per video row, of 20 per scene row; load average at the end {load} "
        "(other work on the machine inflates the figures).",
        "",
        f"Video: {FRAMES} frames of {ROBOTS} robots, {SIZE_PX} px, {FPS} fps (drawing included, same in every row).",
        "",
        "| encoder | seconds to write | MB |",
        "|---|---|---|",
        *(f"| {name} | {s:.2f} | {mb:.2f} |" for name, s, mb in video),
        "",
        "foxglove.SceneUpdate per recorded tick (build + protobuf encode), as the recorder writes it:",
        "",
        "| robots | ms per message | bytes per message |",
        "|---|---|---|",
        *(f"| {n} | {ms:.2f} | {size} |" for n, ms, size in scene),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    (Path(__file__).resolve().parent / "results" / "outputs.md").write_text(text)


if __name__ == "__main__":
    main()
