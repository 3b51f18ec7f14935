"""What the browser- and Foxglove-ready outputs cost, side by side in one run.

Run from the repository root:

    .venv/bin/python bench/bench_outputs.py          # prints a table and writes bench/results/outputs.md
    .venv/bin/python bench/bench_outputs.py --mcap [--tree DIR]   # log.mcap of a 100-robot run: bench/results/mcap.md
    .venv/bin/python bench/bench_outputs.py --encode --tree DIR   # the recorder's protobuf encoding: mcap_encode.md

Video: the same frames (100 robots crossing a 4 x 3 m arena, 720 px, 300 frames = 30 s at 10 fps)
written as MPEG-4 part 2 with OpenCV (what display.mp4 was) and as H.264 with PyAV at two x264
presets (the first is what display.mp4 is now): seconds to write, file size.

Foxglove: building one ``foxglove.SceneUpdate`` (sim.outputs.foxglove.scene_update) and encoding it with
protobuf (Foxglove's SDK), as the recorder does at every recorded tick (10 a second), at 14, 100 and 1000 robots.

``--large``: every output of a run directory at 10,000 robots (paper-sequence-10000's arena) from
synthetic arrays of ``--ticks`` ticks, each written in a forked child: seconds, peak RSS above the
arrays', bytes, and per tick, so the whole sequence's (:data:`SEQUENCE_TICKS`) can be extrapolated;
the video over ``--frames`` frames only.

It also logs ``--log-ticks`` ticks of a 10-host run's messages (:func:`log_rows`) through the
recorder: log.mcap's bytes per message per channel and the whole sequence's log at that rate.

``--clearance``: the smallest clearance of one tick (metrics.clearance_at, on the world's grid) beside
scipy's k-d tree, CPU ms at 1000 and 10,000 robots, scattered and formed.

``--mcap``: the size of log.mcap for one 100-robot lock-step run (:data:`MCAP_RUN`, the same run bit
for bit each time), per channel: messages, their bytes, and those bytes compressed alone with zstd
(the file compresses the channels together, in chunks). ``--tree DIR`` runs the code of another
checkout (e.g. a ``git worktree`` of an earlier commit, its compiled core built) for a before figure.

``--encode``: what the recorder spends turning one per-tick message into its protobuf form for
log.mcap (sim.outputs.logschema), by table size, decoding it off the bus first (transport.codec),
and building the display's SceneUpdate (sim.outputs.foxglove), beside another checkout's modules
(``--tree``, loaded beside these in the same process): microseconds per message (median of 7
batches) and bytes.
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
from sim.outputs.foxglove import scene_update, swarm_scene  # noqa: E402
from tests.support.fake_bus import RecorderBus  # noqa: E402

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
            data = scene_update(1_000_000_000, pose[0], radius, color, goal=goal[0])
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


SEQUENCE_TICKS = 12350  # paper-sequence-10000: 1235 s of holds at dt = 0.1 s


def synthetic_run(ticks: int, robots: int = 10_000) -> tuple[object, dict[str, np.ndarray]]:
    """paper-sequence-10000's scene, and arrays as an engine records them: robots leave a grid for
    random goals at v_pref and stop there (most of a hold is robots at rest)."""
    from coordinator.scene import load_scene

    scene = load_scene("paper-sequence-10000", robots=robots)
    rng = np.random.default_rng(0)
    x0, y0, x1, y1 = scene.arena
    side = int(np.ceil(np.sqrt(robots)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:robots] * 0.8 - side * 0.4
    goal = rng.uniform([x0 + 1, y0 + 1], [x1 - 1, y1 - 1], (robots, 2))
    way = goal - grid
    dist = np.hypot(*way.T)
    travelled = np.minimum(np.arange(ticks)[:, None] * 0.045, dist)  # (T, N): 0.45 m/s for 0.1 s a tick
    xy = grid + travelled[..., None] * (way / np.maximum(dist, 1e-9)[:, None])
    pose = np.concatenate([xy, np.zeros((ticks, robots, 1))], -1)
    arrays = {
        "t": np.arange(ticks) * 0.1,
        "pose": pose,
        "velocity": np.gradient(xy, 0.1, axis=0),
        "color": np.broadcast_to(rng.integers(0, 256, (robots, 3), dtype=np.uint8), (ticks, robots, 3)).copy(),
        "goal": np.broadcast_to(goal, (ticks, robots, 2)).copy(),
        "assignment": np.broadcast_to(rng.permutation(robots), (ticks, robots)).copy(),
        "step": np.zeros(ticks, np.int64),
    }
    return scene, arrays


def _rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def _in_child(job, queue) -> None:  # type: ignore[no-untyped-def]
    import resource

    before = _rss_kb()
    start = time.perf_counter()
    size = job()
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    queue.put((seconds, (peak - before) / 1024, size))


def large_rows(ticks: int, frames: int) -> list[str]:
    """Each output of a 10,000-robot run directory from :func:`synthetic_run`, one forked child each."""
    import multiprocessing

    from sim.outputs import write
    from sim.outputs.metrics import TrueRecord, clearance_over_time, summarise

    scene, arrays = synthetic_run(ticks)
    radius = np.full(scene.robots, 0.037)
    tmp = Path(tempfile.mkdtemp())
    size = render.video_size(scene.arena, radius)

    def metrics() -> int:
        clearance = clearance_over_time(arrays["pose"], radius)
        record = TrueRecord(arrays["t"], arrays["pose"], radius, arrays["goal"], 0.01, clearance)
        return len(repr(summarise(record, wall_s=1.0, contacts=0)))

    def npz() -> int:
        path = tmp / "trajectory.npz"
        write.write_trajectory(path, arrays, radius)
        return path.stat().st_size

    def plots() -> int:
        clearance = np.zeros(ticks)
        paths = render.write_plots(tmp, write.recording_of(scene, arrays, radius), clearance)
        return sum(p.stat().st_size for p in paths.values())

    def video() -> int:
        rec = write.recording_of(scene, arrays, radius, np.arange(min(frames, ticks)))
        render.write_video(tmp / "display.mp4", rec, speed=None, max_frames=0, size_px=size)
        return (tmp / "display.mp4").stat().st_size

    def scene_message() -> int:  # what the recorder writes above LOG_ROBOTS robots
        return len(swarm_scene(0, arrays["pose"][-1], radius, arrays["color"][-1]))

    jobs = [("metrics + clearance", metrics, ticks), ("trajectory.npz", npz, ticks), ("plots", plots, ticks)]
    jobs += [
        (f"display.mp4 ({size} px)", video, min(frames, ticks)),
        ("a scene message", scene_message, 1),
    ]
    context = multiprocessing.get_context("fork")
    rows = [
        "| output | ticks | s | s per tick | peak RSS above arrays, MB | bytes | bytes per tick |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, job, count in jobs:
        queue = context.Queue()
        child = context.Process(target=_in_child, args=(job, queue))
        child.start()
        seconds, mb, written = queue.get()
        child.join()
        rows.append(
            f"| {name} | {count} | {seconds:.2f} | {seconds / count:.4f} | {mb:.0f} | {written:,} | {written // count:,} |"
        )
    for p in tmp.iterdir():
        p.unlink()
    tmp.rmdir()
    held = sum(a.nbytes for a in arrays.values()) / 1e6
    rows += ["", f"Arrays held (float64 as the engines record them): {held:.0f} MB for {ticks} ticks."]
    return rows


SEQUENCE_IMAGES = 6  # paper-sequence-10000's goal sets, one an image
PER_GOAL_SET = ("/goals", "/display/goals")  # channels with a message a goal set, not a tick
HOSTS = 10  # --large's log: agent hosts of paper-sequence-10000 with -k 1000, a States and a Commands frame each a tick


def _tick_messages(keys, arrays: dict[str, np.ndarray], k: int) -> list[tuple[str, bytes]]:  # type: ignore[no-untyped-def]
    """What a 10,000-robot run of :data:`HOSTS` agent hosts sends at tick k: the tracker's poses, each
    host's states and commands, the world's truth, and at tick 0 the goal set (no auction: its
    traffic is at image changes)."""
    from transport.codec import Commands, Goals, Poses, State, States, Timing, Truth

    pose, vel, goal = arrays["pose"][k], arrays["velocity"][k], arrays["goal"][k]
    n, stamp = len(pose), float(arrays["t"][k])
    poses = np.zeros(n, Poses.RECORD)
    poses["robot"], poses["x"], poses["y"], poses["theta"] = np.arange(n), *pose.T
    states = np.zeros(n, States.RECORD)
    states["robot"], states["x"], states["y"], states["vx"], states["vy"] = np.arange(n), *pose[:, :2].T, *vel.T
    states["radius"], states["goal_x"], states["goal_y"] = 0.037, *goal.T
    states["goal_index"], states["flags"], states["assign_epoch"] = arrays["assignment"][k], State.HAS_GOAL, 1
    commands = np.zeros(n, Commands.RECORD)
    commands["robot"], commands["a"], commands["b"] = np.arange(n), *vel.T
    commands["r"], commands["g"], commands["bl"] = arrays["color"][k].T
    truth = Truth(k, stamp, 0.1, n, pose, vel.astype(np.float32).astype(float))
    truth.color, truth.applied = arrays["color"][k], np.full(n, k, np.uint32)
    out = [(keys.poses, Poses(k, stamp, poses).encode())]
    for host, part in enumerate(np.array_split(np.arange(n), HOSTS)):
        out.append((keys.states(host), States(k, stamp, states[part]).encode()))
        out.append((keys.cmd(int(part[0])), Commands(k, stamp, commands[part]).encode()))
    if k == 0:  # the image's goal set, as the coordinator publishes it
        goals = Goals(1, 0, goal, arrays["color"][k], np.arange(n), Timing(stamp=stamp))
        out.insert(0, (keys.goals(1), goals.encode()))
    return [*out, (keys.truth, truth.encode())]


def log_rows(ticks: int) -> list[str]:
    """log.mcap of ``ticks`` ticks of :func:`synthetic_run` as the recorder writes it from a
    10-host run's messages: bytes per message per channel (before and after the file's zstd) and
    the whole sequence's log at the same rate."""
    import zstandard
    from mcap.reader import make_reader

    from sim.outputs.recorder import Recorder

    _, arrays = synthetic_run(ticks)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "log.mcap"
        bus = RecorderBus()  # what the recorder reads of a bus, fed in process
        rec = Recorder(bus, robots=arrays["pose"].shape[1], tolerance=0.01, log_path=str(path))  # type: ignore[arg-type]
        rec.out.heading = False  # paper-sequence-10000's robots are holonomic
        start = time.perf_counter()
        for k in range(ticks):
            bus.raw.items = [(key, data, 1000.0 + 0.1 * k) for key, data in _tick_messages(bus.keys, arrays, k)]
            rec.poll()
        rec.out.close()
        seconds = time.perf_counter() - start
        size = path.stat().st_size
        data: dict[str, list[bytes]] = {}
        with open(path, "rb") as fh:
            for _, channel, message in make_reader(fh).iter_messages():
                data.setdefault(channel.topic, []).append(message.data)
    compress = zstandard.ZstdCompressor(level=3).compress
    table, once = [], 0
    for topic, messages in sorted(data.items(), key=lambda kv: -sum(map(len, kv[1]))):
        raw, packed = sum(map(len, messages)), len(compress(b"".join(messages)))
        if topic in PER_GOAL_SET:
            once += packed
        whole = packed * (SEQUENCE_IMAGES if topic in PER_GOAL_SET else SEQUENCE_TICKS / ticks)
        table.append(
            f"| {topic} | {len(messages)} | {raw // len(messages):,} | {packed // len(messages):,} | {whole / 1e6:,.0f} |"
        )
    sequence = (size - once) / ticks * SEQUENCE_TICKS + once * SEQUENCE_IMAGES
    return [
        f"log.mcap of {ticks} ticks: {size:,} bytes, recorder {seconds / ticks * 1e3:.0f} ms a tick; the whole sequence"
        f" ({SEQUENCE_TICKS} ticks, {SEQUENCE_IMAGES} goal sets) at that rate: **{sequence / 1e9:.2f} GB**",
        "",
        "| channel | messages | bytes per message | zstd alone, per message | sequence, zstd alone, MB |",
        "|---|---|---|---|---|",
        *table,
    ]


def kdtree_clearance(xy: np.ndarray, radius: np.ndarray) -> float:
    """The reference of ``--clearance``: the smallest clearance from scipy's k-d tree (the pairs within
    touching distance plus 0.1 m, else each robot's nearest), for equal radii."""
    from scipy.spatial import cKDTree

    tree = cKDTree(xy, balanced_tree=False, compact_nodes=False)
    r = float(radius[0])
    near = tree.query_pairs(2 * r + 0.1, output_type="ndarray")
    if len(near):
        return float(np.sqrt(((xy[near[:, 0]] - xy[near[:, 1]]) ** 2).sum(-1)).min() - 2 * r)
    return float(tree.query(xy, k=2)[0][:, 1].min() - 2 * r)


def clearance_rows(repeat: int = 20) -> list[str]:
    """CPU ms per tick of metrics.clearance_at (the world's grid) beside scipy's k-d tree, at 1000 and
    10,000 robots (radius 0.045 m), scattered over paper-sequence-1000's arena scaled by sqrt(N) and
    formed on a 0.1 m lattice (jittered 3 mm): what clearance_over_time spends on each recorded tick."""
    from sim.outputs.metrics import clearance_at

    rng = np.random.default_rng(0)
    rows = ["| robots | layout | grid ms | k-d tree ms | the same clearance |", "|---|---|---|---|---|"]
    for n in (1000, 10000):
        side = int(np.ceil(np.sqrt(n)))
        lattice = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * 0.1
        layouts = {"scattered": rng.uniform(0, 48.9 * np.sqrt(n / 1000), (n, 2))}
        layouts["formed"] = lattice + rng.normal(0, 0.003, (n, 2))
        radius = np.full(n, 0.045)
        for name, xy in layouts.items():
            ms, got = [], []
            for f in (clearance_at, kdtree_clearance):
                got.append(f(xy, radius))
                start = time.process_time()
                for _ in range(repeat):
                    f(xy, radius)
                ms.append((time.process_time() - start) / repeat * 1e3)
            same = abs(got[0] - got[1]) <= 1e-12
            rows.append(f"| {n} | {name} | {ms[0]:.3f} | {ms[1]:.3f} | {'yes' if same else 'no'} |")
            print(rows[-1], flush=True)
    return rows


def _module_of(tree: Path, name: str, package: str = "sim/outputs"):  # type: ignore[no-untyped-def]
    """``tree``'s <package>/<name>.py as a module of its own (it imports this tree's other modules)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"{name}_{abs(hash(tree))}", tree / f"{package}/{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def encode_rows(before: Path) -> list[str]:
    from sim.outputs import logschema
    from transport.codec import Boards, Poses, States

    rng = np.random.default_rng(0)

    def table(dtype: np.dtype, n: int) -> np.ndarray:
        out = np.zeros(n, dtype)
        for name in dtype.names or ():
            wide = out[name].dtype
            out[name] = rng.normal(0, 2, n) if wide.kind == "f" else rng.integers(0, min(np.iinfo(wide).max, 1000), n)
        return out

    words = table(Boards.WORD, 50)
    words["flags"], words["records"] = Boards.FRESH, 100  # a host of 50 with every board record fresh
    messages = {f"States, {n} records": States(7, 0.7, table(States.RECORD, n)) for n in (1, 6, 250, 1000)}
    messages |= {f"Poses, {n} records": Poses(7, 0.7, table(Poses.RECORD, n)) for n in (1, 1000)}
    boards = Boards(1, 4, 0, 3, 100, 100, 50, words, np.zeros((0, 13), np.uint8), table(Boards.RECORD, 5000))
    messages["Boards, 50 words and 5000 records"] = boards
    codes = {"now": logschema, "before": _module_of(before, "logschema")}
    rows = ["| message | us now | us before | bytes now | bytes before |", "|---|---|---|---|---|"]
    for name, message in messages.items():
        us, size = {}, {}
        for code, module in codes.items():
            kind = module.kind_of(message)
            batches = []
            for _ in range(7):
                t = time.perf_counter()
                for _ in range(50):
                    encoded = kind.encode(message, "pixelswarm/state/0")
                batches.append((time.perf_counter() - t) / 50 * 1e6)
            us[code], size[code] = float(np.median(batches)), len(encoded)
        rows.append(f"| {name} | {us['now']:.0f} | {us['before']:.0f} | {size['now']} | {size['before']} |")
    rows += decode_rows(before, messages)
    scenes = {"now": scene_update, "before": _module_of(before, "foxglove").scene_update}
    for n in (14, 100, 1000):
        _, pose, radius, color, goal = crossing(2, n)
        for code, build in scenes.items():
            batches = []
            for _ in range(7):
                t = time.perf_counter()
                for _ in range(5):
                    scene = build(1_000_000_000, pose[0], radius, color, goal=goal[0])
                    encoded = scene if isinstance(scene, bytes) else scene.encode()
                batches.append((time.perf_counter() - t) / 5 * 1e6)
            us[code], size[code] = float(np.median(batches)), len(encoded)
        rows.append(
            f"| SceneUpdate, {n} robots | {us['now']:.0f} | {us['before']:.0f} | {size['now']} | {size['before']} |"
        )
    return rows


def decode_rows(before: Path, messages: dict) -> list[str]:
    """What the recorder spends decoding a frame off the bus before it logs it (transport.codec.decode),
    beside ``before``'s codec: the frames of one and of many records among ``messages``."""
    from transport import codec

    codecs = {"now": codec, "before": _module_of(before, "codec", "transport")}
    rows = []
    for name, message in messages.items():
        if not name.startswith("States") or message.count > 250:
            continue
        us = {}
        for code, module in codecs.items():
            data, kind = message.encode(), getattr(module, type(message).__name__)
            batches = []
            for _ in range(7):
                t = time.perf_counter()
                for _ in range(200):
                    module.decode(data, kind)
                batches.append((time.perf_counter() - t) / 200 * 1e6)
            us[code] = float(np.median(batches))
        rows.append(f"| decoding it: {name} | {us['now']:.1f} | {us['before']:.1f} | | |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--clearance", action="store_true", help="only the clearance of a tick, beside scipy's")
    parser.add_argument("--mcap", action="store_true", help="only log.mcap's size for one 100-robot run")
    parser.add_argument(
        "--tree", type=Path, default=REPO, help="--mcap: the checkout whose code runs; --encode: before"
    )
    parser.add_argument(
        "--encode", action="store_true", help="only the protobuf encoding of log.mcap's per-tick messages"
    )
    parser.add_argument("--large", action="store_true", help="each output of a 10,000-robot run directory")
    parser.add_argument("--ticks", type=int, default=300, help="--large: ticks of synthetic arrays")
    parser.add_argument("--frames", type=int, default=60, help="--large: frames of the video")
    parser.add_argument("--log-ticks", type=int, default=100, help="--large: ticks of log.mcap")
    args = parser.parse_args()
    if args.clearance:
        write_results(
            "clearance",
            "The smallest clearance of a recorded tick: the world's grid beside scipy's k-d tree",
            ".venv/bin/python bench/bench_outputs.py --clearance",
            [*clearance_rows(), "", f"Load average at the end: {os.getloadavg()[0]:.1f}."],
        )
        return
    if args.large:
        write_results(
            "outputs_large",
            "A 10,000-robot run directory's outputs, from synthetic arrays",
            f".venv/bin/python bench/bench_outputs.py --large --ticks {args.ticks} --frames {args.frames}",
            [
                *large_rows(args.ticks, args.frames),
                "",
                *log_rows(args.log_ticks),
                "",
                f"Load average at the end: {os.getloadavg()[0]:.1f}.",
            ],
        )
        return
    if args.encode:
        write_results(
            "mcap_encode",
            "The recorder's protobuf encoding of one per-tick message and scene, beside another checkout's",
            f".venv/bin/python bench/bench_outputs.py --encode --tree {args.tree}",
            encode_rows(args.tree.resolve()),
        )
        return
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
