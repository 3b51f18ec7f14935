"""Per-robot control-step time (issue 3): what one agent spends per tick on preferred velocity,
ORCA / NH-ORCA and controls, with 10 neighbours; alone (B = 1, one process per robot) and per
robot in a host batch (B = 250). Reference in the same run: RVO2's per-agent share of `do_step`
(pyrvo, 250 agents with 10 neighbours each).

    .venv/bin/python -m bench.bench_control_step
    .venv/bin/python -m bench.bench_control_step --before HEAD~3

With ``--before REV`` the control step of agent/core at git revision REV is loaded beside the
current one; both are first checked for identical outputs, every bit of every StepResult field, on
seeded random cases (`harness_cases`), then timed side by side in the same run.
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from agent.core import step as current_step
from agent.core.params import DIFFDRIVE, HOLONOMIC, KINEMATICS, RobotParams
from agent.core.step import NeighbourStates, static_segments

from .common import REPO, write_results

HARNESS_CASES = 2000
# batch sizes of the harness and their odds: most cases are an agent's batch of one
_BATCHES, _BATCH_ODDS = (1, 2, 7, 250), (0.6, 0.17, 0.18, 0.05)


def neighbours(batch: int, m: int, rng: np.random.Generator) -> NeighbourStates:
    nb = NeighbourStates.empty(batch, m)
    ang = rng.uniform(0, 2 * np.pi, (batch, m))
    dist = rng.uniform(0.1, 0.5, (batch, m))
    nb.position[:] = np.stack([dist * np.cos(ang), dist * np.sin(ang)], axis=-1)
    nb.velocity[:] = rng.normal(0, 0.05, (batch, m, 2))
    nb.radius[:] = 0.045
    nb.age[:] = 0.1
    nb.valid[:] = True
    return nb


def bench_args(kinematics: str, batch: int) -> tuple:
    """control_step's arguments of the timed case: B robots at the origin, 10 neighbours each."""
    rng = np.random.default_rng(0)
    p = RobotParams(kinematics=kinematics)
    nb = neighbours(batch, 10, rng)
    return (
        p,
        np.arange(batch),
        np.zeros((batch, 2)),
        rng.uniform(-3, 3, batch),
        rng.normal(0, 0.05, (batch, 2)),
        rng.uniform(-1, 1, (batch, 2)),
        nb,
        None,
    )


def per_robot_ms(steps: list[tuple[ModuleType, tuple]], repeat: int, rounds: int = 5) -> list[float]:
    """Best over ``rounds`` of the mean CPU ms per robot of ``repeat`` calls of each
    ``step.control_step`` on its arguments; the steps take turns in every round. CPU time of this
    process, not wall time: other load on the machine then hardly counts."""
    best = [np.inf] * len(steps)
    for step, args in steps:
        step.control_step(*args)
    for _ in range(rounds):
        for k, (step, args) in enumerate(steps):
            t = time.process_time()
            for _ in range(repeat):
                step.control_step(*args)
            best[k] = min(best[k], (time.process_time() - t) / repeat / len(args[1]) * 1000)
    return best


def harness_cases(n: int = HARNESS_CASES, seed: int = 0) -> Iterator[dict[str, Any]]:
    """Seeded random control_step calls: batch 1 to 250, 0 to 16 neighbours (some invalid, stale,
    overlapping or not finite), arena walls and an obstacle or none, preferred rows given or NaN,
    no goal, blocked robots in a crowd, both kinematics. Keyword arguments, params as a dict."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        kin = KINEMATICS[k % 2]
        b = int(rng.choice(_BATCHES, p=_BATCH_ODDS))
        m = int(rng.integers(0, 17))
        crowd = rng.random() < 0.2  # close neighbours, robots barely moving: jams and fallbacks
        position = rng.uniform(-0.8, 0.8, (b, 2))
        ang = rng.uniform(0, 2 * np.pi, (b, m))
        dist = rng.uniform(0.06, 0.2, (b, m)) if crowd else rng.uniform(0.05, 0.9, (b, m))
        nb = NeighbourStates(
            position[:, None, :] + np.stack([dist * np.cos(ang), dist * np.sin(ang)], axis=-1),
            rng.normal(0, 0.06, (b, m, 2)),
            rng.uniform(0.03, 0.05, (b, m)),
            rng.choice([-0.05, 0.0, 0.1, 0.3, 0.7], (b, m)) + rng.uniform(0, 0.1, (b, m)),
            rng.random((b, m)) < 0.85,
            rng.random((b, m)) < 0.9,
        )
        bad = ~nb.valid & (rng.random((b, m)) < 0.3)
        nb.position[bad] = np.nan  # invalid entries may hold anything
        velocity = rng.normal(0, 0.001 if crowd else 0.06, (b, 2))
        goal = rng.uniform(-1.5, 1.5, (b, 2))
        goal[rng.random(b) < 0.1] = np.nan  # no goal
        near = rng.random(b) < 0.1
        goal[near] = position[near] + rng.normal(0, 0.01, (int(near.sum()), 2))
        preferred = None
        if rng.random() < 0.25:
            preferred = rng.uniform(-0.12, 0.12, (b, 2))
            preferred[rng.random(b) < 0.5] = np.nan
        walls = rng.random()
        segments = None
        if walls < 0.3:
            segments = static_segments((-1.0, -1.0, 1.0, 1.0), [])
        elif walls < 0.5:
            segments = static_segments((-1.0, -1.0, 1.0, 1.0), [[(0.1, 0.1), (0.3, 0.1), (0.3, 0.3), (0.1, 0.3)]])
        yield dict(
            params=RobotParams(kinematics=kin).to_dict(),
            robot_ids=rng.integers(0, 1000, b),
            position=position,
            heading=rng.uniform(-np.pi, np.pi, b),
            velocity=velocity,
            goal=goal,
            neighbours=nb,
            segments=segments,
            seed=int(rng.integers(0, 2**32)),
            tick=int(rng.integers(0, 10**6)),
            preferred=preferred,
        )


def call(step: ModuleType, case: dict[str, Any]):
    """``step.control_step`` on a harness case, with ``step``'s own RobotParams."""
    params = importlib.import_module(step.__name__.rsplit(".", 1)[0] + ".params").RobotParams(**case["params"])
    return step.control_step(params, **{k: v for k, v in case.items() if k != "params"})


def same_bits(a, b) -> bool:
    """Every field of two StepResults holds the same bytes (NaN payloads included)."""
    fields = ("velocity", "command", "pref_velocity", "fallback")
    return all(
        getattr(a, f).dtype == getattr(b, f).dtype
        and getattr(a, f).shape == getattr(b, f).shape
        and np.ascontiguousarray(getattr(a, f)).tobytes() == np.ascontiguousarray(getattr(b, f)).tobytes()
        for f in fields
    )


def load_revision(rev: str, into: Path) -> ModuleType:
    """agent/core as of git revision ``rev``, importable beside the current one: its step module."""
    sha = subprocess.run(["git", "rev-parse", "--short", rev], cwd=REPO, capture_output=True, text=True)
    if sha.returncode != 0:
        raise ValueError(f"not a git revision: {rev!r}")
    name = f"_before_{sha.stdout.strip()}"
    core = into / name / "core"
    core.mkdir(parents=True)
    (into / name / "__init__.py").write_text("")
    files = subprocess.run(
        ["git", "ls-tree", "--name-only", f"{rev}:agent/core"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.split()
    for f in files:
        if f.endswith(".py"):
            text = subprocess.run(
                ["git", "show", f"{rev}:agent/core/{f}"], cwd=REPO, capture_output=True, text=True, check=True
            ).stdout
            (core / f).write_text(text.replace("agent.core", f"{name}.core"))
    sys.path.insert(0, str(into))
    return importlib.import_module(f"{name}.core.step")


def check_identical(before: ModuleType, n: int = HARNESS_CASES) -> int:
    """Run every harness case through both; raise on the first that differs. Returns the count."""
    count = 0
    for k, case in enumerate(harness_cases(n)):
        if not same_bits(call(before, case), call(current_step, case)):
            raise AssertionError(f"harness case {k} differs from the revision before")
        count += 1
    return count


def rvo2_per_agent_ms() -> float | None:
    try:
        import pyrvo
    except ImportError:
        return None

    sim = pyrvo.RVOSimulator(0.1, 0.6, 10, 2.0, 2.0, 0.045, 0.13)
    rng = np.random.default_rng(0)
    side = 16
    for k in range(250):
        sim.add_agent((float((k % side) * 0.12 + rng.uniform(0, 0.01)), float((k // side) * 0.12)))
    for k in range(250):
        vx, vy = rng.normal(0, 0.1, 2)
        sim.set_agent_pref_velocity(k, (float(vx), float(vy)))
    t = time.process_time()
    for _ in range(50):
        sim.do_step()
    return (time.process_time() - t) / 50 / 250 * 1000


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_control_step", description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", metavar="REV", help="also time agent/core at this git revision, side by side")
    parser.add_argument("--cases", type=int, default=HARNESS_CASES, help="harness cases checked before timing")
    args = parser.parse_args(argv)
    if args.cases < 0:
        print("error: --cases must be at least 0", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        before = None
        if args.before:
            try:
                before = load_revision(args.before, Path(tmp))
            except (ValueError, subprocess.CalledProcessError):
                print(f"error: cannot load agent/core at revision {args.before!r}", file=sys.stderr)
                return 2
            checked = check_identical(before, args.cases)
            print(f"identical outputs on {checked} harness cases", flush=True)
        rows = _timings(before)
    ref = rvo2_per_agent_ms()
    width = 5 if before else 3
    rows.append(
        f"| RVO2 (pyrvo), holonomic | 250 (do_step) | {ref:.4f} |" + " |" * (width - 3)
        if ref is not None
        else "| RVO2 (pyrvo) | - | not installed |" + " |" * (width - 3)
    )
    command = ".venv/bin/python -m bench.bench_control_step" + (f" --before {args.before}" if before else "")
    notes = ["", "Target: at most 1 ms per robot with 10 neighbours inside an agent process (batch 1)."]
    if before:
        notes.insert(1, f"before: agent/core at {args.before}, timed in the same run after {checked} harness cases")
        notes.insert(2, "gave bit-identical step results (bench.bench_control_step.harness_cases).")
    write_results("control_step", "Control step per robot, 10 neighbours (issue 3)", command, rows + notes)
    return 0


def _timings(before: ModuleType | None) -> list[str]:
    if before is None:
        rows = ["| kinematics | batch (robots per call) | ms per robot per step |", "|---|---|---|"]
    else:
        rows = [
            "| kinematics | batch (robots per call) | CPU ms per robot per step | before | speed-up |",
            "|---|---|---|---|---|",
        ]
    for kin in [HOLONOMIC, DIFFDRIVE]:
        for batch, repeat in [(1, 100), (250, 2)]:
            args = bench_args(kin, batch)
            if before is None:
                (ms,) = per_robot_ms([(current_step, args)], repeat)
                rows.append(f"| {kin} | {batch} | {ms:.3f} |")
            else:
                old_params = importlib.import_module(before.__name__.rsplit(".", 1)[0] + ".params")
                old_args = (old_params.RobotParams(kinematics=kin), *args[1:])
                ms, old = per_robot_ms([(current_step, args), (before, old_args)], repeat)
                rows.append(f"| {kin} | {batch} | {ms:.3f} | {old:.3f} | {old / ms:.1f}x |")
            print(rows[-1], flush=True)
    return rows


if __name__ == "__main__":
    sys.exit(main())
