"""What lost, late and damaged messages cost, and what a secured bus costs. One module, a benchmark
per name; each writes bench/results/<name>.md (faulty-peer prints its table):

    .venv/bin/python -m bench.bench_faults loss [--seeds 10]                 # lost and late states, no bus
    .venv/bin/python -m bench.bench_faults impaired [--seeds 4]              # over the bus, with --faults
    .venv/bin/python -m bench.bench_faults speed-limit                       # the speed limit within hearing
    .venv/bin/python -m bench.bench_faults faulty-peer [--scene circle ...]  # a damaging peer on the bus
    .venv/bin/python -m bench.bench_faults soak [--minutes 60]               # an hour in real time with loss
    .venv/bin/python -m bench.bench_faults security [--messages 20000]       # mutual TLS beside plain TCP
"""

from __future__ import annotations

import argparse
import json
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psutil

import agent.core.policy as policy
from agent.core.params import DIFFDRIVE, HOLONOMIC
from coordinator.scene import load_scene
from sim.central.engine import simulate
from sim.central.link import InProcessLink
from sim.central.lossy import circle_crossing, run_lossy
from sim.emulators.faulty_peer import MODES_AND_ALL
from sim.outputs.metrics import step_metrics, time_to_converge
from sim.processes import stop_processes
from transport.bus import Bus
from transport.codec import Command, Contact, Tick
from transport.faults import format_faults, parse_faults
from transport.keys import Keys
from transport.security import client_config, make_certificates, router_config
from transport.session import TransportError, ZenohSettings, client_of, free_port, listening, open_session

from .common import REPO, RESULTS, machine, parser_for, run_cli_scene, run_subcommand, write_results

# --- lost and late states without the bus (loss) ----------------------------------------------
LOSS_DOC = """What lost and late neighbour states do to collision avoidance (sim.central.lossy): contacts and clearance
over seeded runs of the antipodal circle, per loss rate, beside perfect information (every state
heard at the next tick, what the central engine and a lock-step run without faults give).

    .venv/bin/python -m bench.bench_faults loss [--seeds 10]
"""


LOSS_CASES = [(HOLONOMIC, 50), (DIFFDRIVE, 30)]
# (lost, a tick late); first: the reference; the last ones leave most neighbours stale (robots stand for them)
LOSS_RATES = [(0.0, 0.0), (0.1, 0.5), (0.2, 0.5), (0.3, 0.5), (0.3, 0.7), (0.5, 0.5), (0.7, 0.3), (0.9, 0.1)]
LOSS_EXPLAIN = (
    "Antipodal circle (spacing 0.2 m, 25 s: past the crowd at the centre), tracking noise on. Each robot "
    "hears each neighbour's state of the tick before unless a seeded draw loses it or makes it one tick "
    "late (per sender and receiver; a robot uses the newest state it has, extrapolated and grown by its "
    "age, agent.core.control; it stands while a stale neighbour may be within touch). Contacts and "
    "clearance from the world's true poses at its sub-steps. Way covered: the share of the distance to "
    "their goals the robots covered in the 25 s (mean over runs). Fallbacks: robot-ticks whose ORCA "
    "program was infeasible at the full horizon. Before robots stood for stale neighbours (3fe43c6), "
    "runs touched with 70% lost (1 of 10 holonomic, 5 of 10 diffdrive) and every run with 90% lost, "
    "by up to 83 mm."
)


def loss_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_faults loss", LOSS_DOC)
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args(argv)
    lines = [
        "| robots | lost | late | heard on time | runs with contact | contacts | min clearance mm (worst, median) "
        "| way covered | fallbacks per robot-tick | s per run |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for kinematics, robots in LOSS_CASES:
        for drop, late in LOSS_RATES:
            rows, start = [], time.perf_counter()
            for seed in range(args.seeds):
                rows.append(run_lossy(circle_crossing(robots, kinematics, seed), drop, late, seed))
                print(f"{kinematics} {robots} lost {drop} late {late} seed {seed}: {rows[-1]}", flush=True)
            per_run = (time.perf_counter() - start) / args.seeds
            clear = np.array([r.min_clearance for r in rows]) * 1000
            lines.append(
                f"| {robots} {kinematics} | {drop:.0%} | {late:.0%} "
                f"| {np.mean([r.heard_on_time for r in rows]):.0%} "
                f"| {sum(r.contacts > 0 for r in rows)} of {len(rows)} | {sum(r.contacts for r in rows)} "
                f"| {clear.min():.1f}, {np.median(clear):.1f} | {np.mean([r.progress for r in rows]):.0%} "
                f"| {sum(r.fallbacks for r in rows) / sum(r.robot_ticks for r in rows):.3f} | {per_run:.1f} |"
            )
    write_results(
        "loss",
        "Lost and late neighbour states: contacts beside perfect information",
        f".venv/bin/python -m bench.bench_faults loss --seeds {args.seeds}",
        [*lines, "", LOSS_EXPLAIN],
    )
    return 0


# --- lost and late states over the bus (impaired) ---------------------------------------------
IMPAIRED_DOC = """Safe is not enough (issue 23): over the real bus, lost and late neighbour states must cost time,
not the picture. Lock-step runs of the 20-robot circle and the 14-robot paper sequence, one agent
process per robot, with and without `--faults state:drop=0.2,delay=0.1,jitter=0.02` (the faults
count in ticks, drawn per message: the same figures on any machine); per image, the time every
robot took to come within 1 cm of its goal, impaired over clear.

    .venv/bin/python -m bench.bench_faults impaired [--seeds 4]
"""


IMPAIRED_FAULTS = "state:drop=0.2,delay=0.1,jitter=0.02"
IMPAIRED_TOLERANCE = 0.01  # m: every robot within 1 cm of its goal
IMPAIRED_CASES = [("circle", 20), ("paper-sequence", 14)]


def formed_after(traj: dict) -> list[float | None]:
    """Per image: seconds from its change until every robot was within IMPAIRED_TOLERANCE (None: never)."""
    if "step" in traj and len(np.unique(traj["step"])) > 1:
        steps = step_metrics(traj["t"], traj["pose"], traj["goal"], traj["step"], IMPAIRED_TOLERANCE)
        return [s["converged_at"] for s in steps]
    return [time_to_converge(traj["t"], traj["pose"], traj["goal"], IMPAIRED_TOLERANCE)]


def impaired_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_faults impaired", IMPAIRED_DOC)
    parser.add_argument("--seeds", type=int, nargs="+", default=[4])
    args = parser.parse_args(argv)
    lines = [
        "| scene | seed | image | clear: formed after s | impaired: formed after s | impaired / clear | contacts (clear, impaired) | wall s (clear, impaired) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene, robots in IMPAIRED_CASES:
        for seed in args.seeds:
            common = [scene, "--robots", str(robots), "--seed", str(seed), "--clock", "lockstep"]
            runs = {}
            for name, extra in (("clear", []), ("impaired", ["--faults", IMPAIRED_FAULTS])):
                got = run_cli_scene(common + extra)
                if got is None:
                    return 1
                runs[name] = got
                print(f"{scene} seed {seed} {name}: formed {formed_after(got[1])}", flush=True)
            (m_clear, t_clear, w_clear), (m_bad, t_bad, w_bad) = runs["clear"], runs["impaired"]
            for k, (a, b) in enumerate(zip(formed_after(t_clear), formed_after(t_bad), strict=True)):
                ratio = "-" if a is None or b is None or a == 0 else f"{b / a:.2f}"
                lines.append(
                    f"| {scene} {robots} | {seed} | {k} | {'never' if a is None else f'{a:.1f}'} "
                    f"| {'never' if b is None else f'{b:.1f}'} | {ratio} "
                    f"| {m_clear['contacts']}, {m_bad['contacts']} | {w_clear:.0f}, {w_bad:.0f} |"
                )
    seeds = " ".join(map(str, args.seeds))
    write_results(
        "impaired",
        "Safe is not enough: lost and late states over the bus cost time, not the picture",
        f".venv/bin/python -m bench.bench_faults impaired --seeds {seeds}",
        [
            *lines,
            "",
            f"Impaired: `--faults {IMPAIRED_FAULTS}` (20 % of state messages lost per receiver, the rest 100 ms "
            "late with up to 20 ms jitter: a tick or two at 10 Hz), one agent process per robot, lock-step. "
            "Formed: every robot within 1 cm of its goal, seconds after the image changed "
            "(sim.outputs.metrics.step_metrics). Contacts from the world's true poses.",
        ],
    )
    return 0


# --- the speed limit within hearing (speed-limit) ---------------------------------------------
SPEED_LIMIT_DOC = """The speed limit within hearing (agent.core.policy.heard_speed_limit) side by side with none: a
20-robot circle crossing on the central engine, every state a tick late, hearing only within a short
range. Contacts and least clearance with the limit and with it lifted (patched to no limit).

    .venv/bin/python -m bench.bench_faults speed-limit
"""


LIMIT_REACHES = (0.12, 0.13, 0.15)
LIMIT_SEEDS = (4, 5)


def limit_run(reach: float, seed: int) -> tuple[int, float, float]:
    scene = load_scene("circle", robots=20, seed=seed, duration=60.0)
    out = simulate(scene, link=InProcessLink(20, late=1.0, reach=reach), progress=None)
    return len(out.contacts), out.min_clearance, float(out.arrays["t"][-1])


def speed_limit_main(argv: list[str] | None = None) -> int:
    parser_for("bench.bench_faults speed-limit", SPEED_LIMIT_DOC).parse_args(argv)
    limit = policy.heard_speed_limit
    lines = [
        "| range m | seed | contacts (limit, none) | least clearance mm (limit, none) | ended at s (limit, none) |",
        "|---|---|---|---|---|",
    ]
    for reach in LIMIT_REACHES:
        for seed in LIMIT_SEEDS:
            policy.heard_speed_limit = limit
            with_limit = limit_run(reach, seed)
            policy.heard_speed_limit = lambda params, reach, latency: np.full(np.shape(latency), np.inf)
            without = limit_run(reach, seed)
            policy.heard_speed_limit = limit
            lines.append(
                f"| {reach} | {seed} | {with_limit[0]}, {without[0]} | {1e3 * with_limit[1]:.1f}, {1e3 * without[1]:.1f} "
                f"| {with_limit[2]:.1f}, {without[2]:.1f} |"
            )
            print(lines[-1], flush=True)
    write_results(
        "speed_limit",
        "Speed within hearing: a short range with late states, with the limit and without",
        ".venv/bin/python -m bench.bench_faults speed-limit",
        [
            *lines,
            "",
            "Circle of 20 holonomic robots (RVO2's Circle at display scale), central engine, lock-step, every "
            "state heard a tick late (InProcessLink late=1.0) and only within the range. The limit caps the "
            "preferred velocity and ORCA's at (R - 2 r - noise) / (2 (age + 2 dt)); ended at: convergence or the "
            "60 s cap.",
        ],
    )
    return 0


# --- a faulty peer on the open bus (faulty-peer) ----------------------------------------------
FAULTY_PEER_DOC = """A faulty peer on the open bus (issue 40): the same run once per damage mode, with
sim.emulators.faulty_peer attached to its router after start-up, and what it cost: contacts, the
deepest overlap, whether (and when) the picture formed, and the messages dropped by reason.

    .venv/bin/python -m bench.bench_faults faulty-peer [--scene circle --robots 20 --seed 3 --duration 60]
        [--modes none future-pose ...] [-k K] [--rate 350] [--start-after 0.5] [--clock realtime]

Each run is `pixelswarm run SCENE --clock CLOCK -l tcp/127.0.0.1:PORT --no-video --no-plots`
on a free port; the peer connects to that port as a client once the router listens and damages
from --start-after seconds after the run's first tick until the run ends. Runs go one after the
other (never two at once). Progress on stderr, the markdown table on stdout.
"""


PEER_MODES = ["none", *MODES_AND_ALL]


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def peer_run_command(args: argparse.Namespace, port: int, out: Path) -> list[str]:
    cmd = [sys.executable, "-m", "sim.cli", "run", args.scene, "--clock", args.clock, "--seed", str(args.seed)]
    if args.robots:
        cmd += ["--robots", str(args.robots)]
    if args.duration:
        cmd += ["--duration", str(args.duration)]
    if args.k:
        cmd += ["-k", str(args.k)]
    return cmd + [
        "-l",
        f"tcp/127.0.0.1:{port}",
        "--display",
        args.display,
        "--out",
        str(out),
        "--no-video",
        "--no-plots",
    ]


def peer_command(args: argparse.Namespace, mode: str, port: int) -> list[str]:
    return [
        sys.executable,
        "-m",
        "sim.emulators.faulty_peer",
        "-e",
        f"tcp/127.0.0.1:{port}",
        "--display",
        args.display,
        "--mode",
        mode,
        "--rate",
        str(args.rate),
        "--start-after",
        str(args.start_after),
        "--seed",
        str(args.peer_seed),
        *(["--damage", args.damage] if args.damage else []),
    ]


def peer_run(args: argparse.Namespace, mode: str, where: Path) -> dict[str, Any]:
    """One run, with the peer in this mode ('none': no peer): its metrics, the peer's summary line,
    the wall time."""
    port = free_port()
    out = where / mode
    start = time.monotonic()
    run = subprocess.Popen(
        peer_run_command(args, port, out), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    peer: subprocess.Popen | None = None
    summary = ""
    try:
        if mode != "none":
            while run.poll() is None and not listening(port) and time.monotonic() - start < 60:
                time.sleep(0.1)
            peer = subprocess.Popen(
                peer_command(args, mode, port), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        try:
            _, run_err = run.communicate(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            stop_processes([run], 30)
            _, run_err = run.communicate()
            run_err += f"\n(bench: the run took over {args.timeout} s and was stopped)"
    finally:
        if peer is not None:
            stop_processes([peer], 10.0)
            peer_out, peer_err = peer.communicate()
            summary = (peer_out.strip().splitlines() or [peer_err.strip()[-300:]])[-1]
        stop_processes([run], 30)
    wall = time.monotonic() - start
    metrics_path = out / "metrics.json"
    if not metrics_path.exists():
        return {
            "mode": mode,
            "error": f"exit {run.returncode}: {run_err.strip()[-600:]}",
            "peer": summary,
            "wall": wall,
        }
    return {"mode": mode, "metrics": json.loads(metrics_path.read_text()), "peer": summary, "wall": wall}


def peer_formed(metrics: dict[str, Any]) -> str:
    """'yes (t s)' or 'no', per image for a sequence."""
    steps = metrics.get("steps") or []
    if len(steps) > 1:
        times = [s.get("converged_at") for s in steps]
        shown = ", ".join("never" if t is None else f"{t:.1f}" for t in times)
        return f"{'yes' if all(t is not None for t in times) else 'no'} ({shown} s)"
    t = metrics.get("time_to_converge_s")
    return f"yes ({t:.1f} s)" if metrics.get("converged") and t is not None else "no"


def peer_row(result: dict[str, Any]) -> str:
    peer = result["peer"]
    if result["mode"] == "none":
        sent = "-"
    elif peer.startswith("faulty-peer: mode") and ", sent " in peer:
        sent = peer.split(", sent ", 1)[1].split(" in ", 1)[0]
    else:
        sent = f"peer failed: {peer[-120:]}"
    if "error" in result:
        return f"| {result['mode']} | {sent} | run failed: {result['error'][-200:]} | | | | | | {result['wall']:.0f} |"
    m = result["metrics"]
    overlap = m.get("max_overlap_m") or 0.0
    events = m.get("contact_events") or []
    kinds = {k: sum(e.get("kind") == k for e in events) for k in ("robot", "obstacle", "wall")}
    contacts = str(m["contacts"])
    if kinds["obstacle"] or kinds["wall"]:
        others = [e for e in events if e.get("kind") != "robot"]
        deepest = max((e.get("max_depth") or 0.0 for e in others), default=0.0)
        shown = ", ".join(f"{v} {k}" for k, v in kinds.items() if v)
        contacts += f" ({shown}; past a wall or obstacle up to {deepest:.2f} m)"
    dropped = m.get("dropped_messages") or {}
    drops = ", ".join(f"{k} {v}" for k, v in sorted(dropped.items(), key=lambda kv: -kv[1])) or "-"
    return (
        f"| {result['mode']} | {sent} | {contacts} | {'-' if overlap <= 0 else f'{100 * overlap:.1f}'} "
        f"| {peer_formed(m)} | {drops} | {m.get('missed_ticks', 0)} | {m.get('stopped_ticks', 0)} "
        f"| {m.get('end_reason', '')}{'' if m.get('agents_crashed', 0) == 0 else ', ' + str(m['agents_crashed']) + ' crashed'} "
        f"| {result['wall']:.0f} |"
    )


PEER_HEADER = [
    "| faulty peer | copies sent | contacts | deepest robot overlap (cm) | picture formed (after) | dropped messages by reason "
    "| missed ticks | stopped robot-ticks | end | wall s |",
    "|---|---|---|---|---|---|---|---|---|---|",
]


def faulty_peer_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_faults faulty-peer", FAULTY_PEER_DOC)
    parser.add_argument("--scene", default="circle")
    parser.add_argument("--robots", type=int, default=20, help="robots (0: the scene's)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--duration", type=float, default=60.0, help="display seconds at most (0: the scene's)")
    parser.add_argument("--modes", nargs="+", default=PEER_MODES, choices=PEER_MODES)
    parser.add_argument("-k", type=int, default=0, help="robots per agent process (0: the scene's)")
    parser.add_argument("--rate", type=float, default=350.0, help="the peer's damaged copies a second")
    parser.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep", help="the runs' clock")
    parser.add_argument("--start-after", type=float, default=0.5, help="s after the first tick the damage begins")
    parser.add_argument("--peer-seed", type=int, default=0)
    parser.add_argument("--damage", help="the malformed modes' damages (the peer's --damage; default all)")
    parser.add_argument("--display", default="default")
    parser.add_argument("--timeout", type=float, default=900.0, help="wall seconds a run may take")
    parser.add_argument("--keep", type=Path, help="keep the run directories here")
    parser.add_argument("--peer-lines", action="store_true", help="print each peer's summary line under the table")
    args = parser.parse_args(argv)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        where = args.keep or Path(tmp)
        where.mkdir(parents=True, exist_ok=True)
        for mode in args.modes:
            _say(f"faulty-peer: {args.scene} {args.robots or ''} robots, faulty peer {mode} ...")
            result = peer_run(args, mode, where)
            results.append(result)
            _say(f"  {peer_row(result)}")
            if result["peer"]:
                _say(f"  {result['peer']}")
    command = " ".join(["python -m bench.bench_faults faulty-peer", *(argv if argv is not None else sys.argv[1:])])
    print(f"Command: `{command}`  \nMachine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}\n")
    print("\n".join(PEER_HEADER + [peer_row(r) for r in results]))
    if args.peer_lines:
        print()
        for r in results:
            if r["peer"]:
                print(f"- {r['mode']}: {r['peer']}")
    return 0


# --- an hour in real time with loss (soak) ----------------------------------------------------
SOAK_DOC = """Soak: agent processes in real time for a long show with message loss; memory, CPU, missed ticks
and contacts over time (issue 24).

A `pixelswarm run` of SOAK_ROBOTS robots, one agent process each, real-time clock, a scene that changes
image every SOAK_HOLD seconds for the whole length, and the fault plan dropping SOAK_LOSS of every message kind
an agent receives. Every SOAK_SAMPLE seconds the bench reads each agent process's resident memory and its
CPU share since the last sample (psutil). An observer on the run's router (loopback, no loss) counts,
per minute of display, the robot-ticks for which no command was sent at all (missed ticks) and the
contacts the world reports.

    .venv/bin/python -m bench.bench_faults soak --minutes 60      # the figures in BENCHMARKS.md: a quiet machine
    .venv/bin/python -m bench.bench_faults soak --minutes 3 --results /tmp/soak.md   # a check that it works
"""


SOAK_ROBOTS = 20
SOAK_LOSS = 0.05  # of every message kind an agent receives
LOSSY_KINDS = ("pose", "state", "auction", "goals")
SOAK_HOLD = 60.0  # s each image is held
SHAPES = ("disk", "ring", "line", "triangle")
SOAK_SAMPLE = 60.0  # s between samples of the agent processes
DT = 0.1  # s, the control period


def soak_scene(minutes: float, robots: int) -> str:
    steps = max(1, round(minutes * 60.0 / SOAK_HOLD))
    text = [
        'name = "soak"',
        f"robots = {robots}",
        "seed = 11",
        'clock = "realtime"',
        "[layout]",
        'kind = "grid"',
        "spacing = 0.2",
        "[end]",
        "converge_hold = 1e9",  # never ends early: the soak runs its whole length
    ]
    for k in range(steps):
        text += ["[[steps]]", f'shape = "{SHAPES[k % len(SHAPES)]}"', f"hold = {SOAK_HOLD}"]
    return "\n".join(text) + "\n"


@dataclass
class Observer:
    """Commands and contacts per minute of display, heard on the router without loss."""

    bus: Bus
    robots: int
    ticks: dict[int, set[int]] = field(default_factory=dict)  # minute -> ticks announced
    answered: dict[int, set[tuple[int, int]]] = field(default_factory=dict)  # minute -> (robot, tick) commanded
    contacts: dict[int, int] = field(default_factory=dict)  # minute -> contacts that began in it

    def __post_init__(self) -> None:
        keys = self.bus.keys
        self.clock = self.bus.subscribe(keys.clock, Tick)
        self.cmd = self.bus.subscribe(keys.all_of("cmd"), Command)
        self.contact = self.bus.subscribe(keys.contact, Contact)

    def poll(self) -> None:
        for _, tick in self.clock.drain():
            self.ticks.setdefault(minute_of(tick.tick), set()).add(tick.tick)
        for _, cmd in self.cmd.drain():
            self.answered.setdefault(minute_of(cmd.tick), set()).add((cmd.robot, cmd.tick))
        for _, c in self.contact.drain():
            self.contacts[int(c.t_start // 60.0)] = self.contacts.get(int(c.t_start // 60.0), 0) + 1

    def missed(self, minute: int) -> int:
        return self.robots * len(self.ticks.get(minute, ())) - len(self.answered.get(minute, ()))


def minute_of(tick: int) -> int:
    return int(tick * DT // 60.0)


def agent_processes(pid: int) -> list[psutil.Process]:
    out = []
    for p in psutil.Process(pid).children(recursive=True):
        try:
            if "agent" in p.cmdline():
                out.append(p)
        except psutil.Error:
            pass
    return out


def soak_sample(agents: dict[int, psutil.Process]) -> tuple[np.ndarray, np.ndarray]:
    """Each live agent process's RSS (MB) and CPU % since the last sample."""
    rss, cpu = [], []
    for pid, p in list(agents.items()):
        try:
            rss.append(p.memory_info().rss / 2**20)
            cpu.append(p.cpu_percent())
        except psutil.Error:
            agents.pop(pid)
    return np.array(rss), np.array(cpu)


def join(endpoint: str, proc: subprocess.Popen) -> Bus:
    """A session on the run's router, once the run has opened it."""
    end = time.monotonic() + 120.0
    while True:
        try:
            return Bus(ZenohSettings(mode="client", connect=[endpoint]), name="soak")
        except TransportError:
            if proc.poll() is not None or time.monotonic() > end:
                proc.kill()
                raise SystemExit("soak: the run's router never came up") from None
            time.sleep(0.5)


def soak(minutes: float, robots: int, every: float) -> tuple[dict, list[dict], Observer]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    plan = parse_faults(";".join(f"{kind}:drop={SOAK_LOSS}" for kind in LOSSY_KINDS))
    with tempfile.TemporaryDirectory() as tmp:
        scene, out = Path(tmp) / "soak.toml", Path(tmp) / "run"
        scene.write_text(soak_scene(minutes, robots))
        command = [sys.executable, "-m", "sim.cli", "run", str(scene), "--out", str(out), "--no-video", "-q"]
        command += ["-l", endpoint, "--faults", format_faults(plan), "--duration", str(minutes * 60.0)]
        proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rows: list[dict] = []
        with join(endpoint, proc) as bus:
            observer = Observer(bus, robots)
            agents: dict[int, psutil.Process] = {}
            started = time.monotonic()
            due = started
            while proc.poll() is None:
                observer.poll()
                for p in agent_processes(proc.pid):
                    if p.pid not in agents:
                        p.cpu_percent()  # starts its CPU counter
                        agents[p.pid] = p
                if time.monotonic() >= due and len(agents) == robots:
                    rss, cpu = soak_sample(agents)
                    if due > started and len(rss) == robots:  # the first sample only starts the CPU counters
                        rows.append({"wall_min": (time.monotonic() - started) / 60.0, "rss": rss, "cpu": cpu})
                        print(f"soak: {rows[-1]['wall_min']:.1f} min, RSS {np.median(rss):.0f} MB", flush=True)
                    due = time.monotonic() + every
                time.sleep(0.1)
            observer.poll()
        _, stderr = proc.communicate()
        if proc.returncode != 0:
            raise SystemExit(f"soak: the run failed: {stderr.strip().splitlines()[-1:]}")
        return json.loads((out / "metrics.json").read_text()), rows, observer


def soak_report(minutes: float, robots: int, every: float, metrics: dict, rows: list[dict], obs: Observer) -> list[str]:
    lines = [
        f"{robots} agent processes, one robot each, real-time clock, {minutes:g} min of display (an image every "
        f"{SOAK_HOLD:g} s), {SOAK_LOSS:.0%} of every {', '.join(LOSSY_KINDS)} message dropped where an agent receives it. "
        f"Load average at the end: {', '.join(f'{x:.1f}' for x in psutil.getloadavg())}.",
        "",
        f"Contacts: {metrics['contacts']}; missed ticks in the world (no command in time): {metrics['missed_ticks']}; "
        f"commands expired: {metrics.get('expired_commands', 0)}; real-time factor "
        f"{metrics.get('stepping_realtime_factor') or 0:.2f}.",
        "",
        "| wall min | RSS per agent MB (median, max) | CPU per agent % (median, max) |",
        "|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['wall_min']:.1f} | {np.median(r['rss']):.0f}, {r['rss'].max():.0f} "
            f"| {np.median(r['cpu']):.1f}, {r['cpu'].max():.1f} |"
        )
    lines += ["", "| display minute | ticks | missed ticks (no command sent) | contacts |", "|---|---|---|---|"]
    for minute in sorted(obs.ticks):
        lines.append(f"| {minute} | {len(obs.ticks[minute])} | {obs.missed(minute)} | {obs.contacts.get(minute, 0)} |")
    return lines


def soak_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_faults soak", SOAK_DOC)
    parser.add_argument("--minutes", type=float, default=60.0, help="length of the show (default 60)")
    parser.add_argument("--robots", type=int, default=SOAK_ROBOTS)
    parser.add_argument("--sample", type=float, default=SOAK_SAMPLE, help="seconds between samples (default 60)")
    parser.add_argument("--results", type=Path, default=RESULTS / "soak.md")
    args = parser.parse_args(argv)
    if not (args.minutes > 0 and args.robots > 0 and args.sample > 0):
        print("soak: error: --minutes, --robots and --sample must be positive", file=sys.stderr)
        return 2
    metrics, rows, obs = soak(args.minutes, args.robots, args.sample)
    command = f".venv/bin/python -m bench.bench_faults soak --minutes {args.minutes:g} --robots {args.robots}"
    if args.sample != SOAK_SAMPLE:
        command += f" --sample {args.sample:g}"
    text = [
        f"## Soak: {args.robots} agent processes for {args.minutes:g} min with {SOAK_LOSS:.0%} message loss",
        "",
        f"Command: `{command}`",
        f"Machine: {machine()}; measured {time.strftime('%Y-%m-%d', time.gmtime())}.",
        "",
        *soak_report(args.minutes, args.robots, args.sample, metrics, rows, obs),
        "",
    ]
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text("\n".join(text))
    print("\n".join(text))
    return 0


# --- the secured bus (security) ---------------------------------------------------------------
SECURITY_DOC = """What a secured bus costs: robot 3's state messages through a router to the recorder, on plain TCP
without rules (the default) beside mutual TLS or user/password with the access rules of 10 and 1000
robots, side by side in one run (cases interleaved, rounds repeated).

    .venv/bin/python -m bench.bench_faults security [--messages 20000] [--rounds 5]
"""


SECURITY_KEYS = Keys("default")
SECURITY_PAYLOAD = 64  # bytes, about a state message
SECURITY_PACED = 500  # messages sent one by one for latency
SECURITY_PACE = 0.001  # s between paced messages


def security_sessions(case: str, folders: dict[int, Path]) -> tuple[ZenohSettings, ZenohSettings, ZenohSettings]:
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


def security_measure(case: str, folders: dict[int, Path], messages: int) -> tuple[float, float]:
    """Messages per second delivered, and the median one-way latency in microseconds."""
    router_settings, pub_settings, sub_settings = security_sessions(case, folders)
    router = open_session(router_settings)
    try:
        with Bus(pub_settings) as robot, Bus(sub_settings) as recorder:
            inbox = recorder.subscribe_raw(SECURITY_KEYS.everything)
            key = SECURITY_KEYS.state((0, 0), 3)
            deadline = time.monotonic() + 10
            while not inbox.drain() and time.monotonic() < deadline:  # until the route exists
                robot.put(key, bytes(SECURITY_PAYLOAD))
                time.sleep(0.01)
            time.sleep(0.2)
            inbox.drain()
            filler = bytes(SECURITY_PAYLOAD - 8)
            got, start = 0, time.perf_counter()
            for _ in range(messages):
                robot.put(key, struct.pack("<d", 0.0) + filler)
            while got < messages and time.perf_counter() - start < 60:
                got += len(inbox.drain())
                time.sleep(0.001)
            rate = got / (time.perf_counter() - start)
            delays = []
            for _ in range(SECURITY_PACED):
                robot.put(key, struct.pack("<d", time.time()) + filler)
                time.sleep(SECURITY_PACE)
                delays += [(t - struct.unpack("<d", payload[:8])[0]) * 1e6 for _, payload, t in inbox.drain()]
            time.sleep(0.1)
            delays += [(t - struct.unpack("<d", payload[:8])[0]) * 1e6 for _, payload, t in inbox.drain()]
            return rate, statistics.median(delays)
    finally:
        router.close()


def security_main(argv: list[str] | None = None) -> int:
    parser = parser_for("bench.bench_faults security", SECURITY_DOC)
    parser.add_argument("--messages", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
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
                results[case].append(security_measure(case, folders, args.messages))
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
        f"{args.messages} messages of {SECURITY_PAYLOAD} bytes from a robot-3 session to a recorder session subscribed to "
        f"everything, through a router, all three in one process on 127.0.0.1; latency from {SECURITY_PACED} messages "
        f"sent {SECURITY_PACE * 1000:.0f} ms apart. Cases interleaved over {args.rounds} rounds; the machine is shared, "
        "so the spread between rounds is wide.",
    ]
    write_results(
        "security",
        "Secured bus: throughput and latency beside plain TCP",
        f".venv/bin/python -m bench.bench_faults security --messages {args.messages} --rounds {args.rounds}",
        lines,
    )
    return 0


COMMANDS = {
    "loss": loss_main,
    "impaired": impaired_main,
    "speed-limit": speed_limit_main,
    "faulty-peer": faulty_peer_main,
    "soak": soak_main,
    "security": security_main,
}


if __name__ == "__main__":
    sys.exit(run_subcommand("bench.bench_faults", COMMANDS, None))
