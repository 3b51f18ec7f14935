"""Is the central engine's run the same, to the bit, as another checkout's? A speed-up of the engine
must not change a single recorded number: run this in both checkouts (a git worktree of the other
commit, the same `.venv`) and compare the two files.

    cd OTHER_WORKTREE && .venv/bin/python -m bench.central_same --save /tmp/before.npz
    .venv/bin/python -m bench.central_same --save /tmp/after.npz --compare /tmp/before.npz

By default the paper's sequence with 100 robots through its first two images (the auction beside
the control core, deadlock watching, an image change); ``--robots`` and ``--images`` change that.
Prints the SHA-256 of every recorded array (sim.central.simulate's Outcome) and, with
``--compare``, the first tick where an array differs.
"""

from __future__ import annotations

import argparse
import hashlib
import sys

import numpy as np

from sim.central import Outcome, simulate

from .bench_large import SCENE, scene_for

ROBOTS, IMAGES = 100, 2  # a sequence short enough to run in seconds, with an image change


def recorded(outcome: Outcome) -> dict[str, np.ndarray]:
    """What a run recorded: its arrays, and what the world and the robots counted."""
    counts = [len(outcome.contacts), outcome.min_clearance, outcome.fallbacks, outcome.penalties]
    return {**outcome.arrays, "counts": np.array(counts, float), "end": np.array(outcome.end_reason)}


def digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def first_difference(mine: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> list[str]:
    """One line per array that differs: where it differs first (the tick, for per-tick arrays)."""
    lines = []
    for name in sorted(set(mine) | set(other)):
        a, b = mine.get(name), other.get(name)
        if a is None or b is None:
            lines.append(f"{name}: only in {'this run' if b is None else 'the other'}")
        elif a.shape != b.shape or a.dtype != b.dtype:
            lines.append(f"{name}: shape {a.shape} {a.dtype} against {b.shape} {b.dtype}")
        elif a.tobytes() != b.tobytes():
            rows = np.flatnonzero(
                [x.tobytes() != y.tobytes() for x, y in zip(a.reshape(len(a), -1), b.reshape(len(b), -1))]
            )
            lines.append(f"{name}: differs first at row {rows[0]} of {len(a)}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default=SCENE)
    parser.add_argument("--robots", type=int, default=ROBOTS)
    parser.add_argument("--images", type=int, default=IMAGES)
    parser.add_argument("--save", help="write the recorded arrays here (.npz)")
    parser.add_argument("--compare", help="an .npz another checkout saved: exit 1 unless every bit is the same")
    args = parser.parse_args()
    scene, _ = scene_for(args.scene, args.robots, args.images)
    mine = recorded(simulate(scene, progress=None))
    for name, a in mine.items():
        print(f"{name:12s} {str(a.shape):14s} {digest(a)}")
    if args.save:
        np.savez(args.save, **mine)
    if args.compare:
        with np.load(args.compare) as z:
            other = {name: np.array(z[name]) for name in z.files}
        differ = first_difference(mine, other)
        print("\n".join(differ) if differ else f"the same to the bit as {args.compare}")
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
