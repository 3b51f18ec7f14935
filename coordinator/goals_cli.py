"""`pixelswarm goals IMAGE -n N ...`: an image to goal positions and colours (goals.json). Bad input prints
one line `pixelswarm goals: error: ...` and returns 2, writing no file."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from transport import epuck

from .goals import GoalError, GoalSet
from .goals.defaults import MAX_ITER, METHODS, RELAX, TOLERANCE

if TYPE_CHECKING:
    from .goals import PreparedImage

PROG = "pixelswarm goals"


def _region_counts(text: str) -> dict[int, int]:
    out: dict[int, int] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        rid, sep, count = item.partition("=")
        if not sep:
            raise GoalError(f"bad --region-counts item {item!r}: use REGION=COUNT, e.g. 0=10,1=4")
        try:
            out[int(rid)] = int(count)
        except ValueError:
            raise GoalError(f"bad --region-counts item {item!r}: region and count must be integers") from None
    return out


def add_goals_parser(subparsers: Any) -> None:
    """Add the `goals` subcommand to an argparse subparsers object (sets func=run_goals)."""
    p = subparsers.add_parser(
        "goals",
        help="turn an image into N goal positions and colours",
        description="Turn an image into N goal positions and colours (Alonso-Mora et al. 2012, section 4).",
    )
    p.add_argument("image", help="PNG, JPEG, BMP or TIFF image (transparent pixels are background)")
    p.add_argument("-n", "--robots", dest="n", type=int, required=True, help="number of robots N")
    p.add_argument(
        "-o", "--output", default="goals.json", metavar="goals.json", help="output file (default goals.json)"
    )
    p.add_argument(
        "--preview",
        metavar="preview.png",
        help="also draw the image, the goals in their colours and their Voronoi cells",
    )
    p.add_argument(
        "--background",
        metavar="COLOUR",
        help="background colour (#rrggbb, r,g,b or a name); default: alpha, else the border colour",
    )
    _add_arena_flags(p.add_argument_group("arena (paper 4.4)"))
    _add_placement_flags(p.add_argument_group("goal placement (paper 4.1-4.3)"))
    p.set_defaults(func=run_goals)


def _add_arena_flags(g: argparse._ArgumentGroup) -> None:
    g.add_argument(
        "--arena",
        type=float,
        metavar="METRES",
        help="side K_r of the square arena; default: the conservative 2 K_r for the robot radius "
        "(paper 4.4), rounded up to a centimetre",
    )
    g.add_argument(
        "--robot-radius",
        type=float,
        default=epuck.RADIUS,
        metavar="METRES",
        help=f"robot radius r_A (default {epuck.RADIUS}, the e-puck)",
    )
    g.add_argument(
        "--conservative", action="store_true", help="with --arena, require twice the minimum arena (2 K_r, paper 4.4)"
    )


def _add_placement_flags(g: argparse._ArgumentGroup) -> None:
    g.add_argument(
        "--method",
        choices=METHODS,
        default="cvt",
        help="cvt: Lloyd with the mass density of eq. 2; kmeans: binary density (faster)",
    )
    g.add_argument("--seed", type=int, default=0, help="seed of the initial samples (default 0)")
    g.add_argument(
        "--region-counts",
        metavar="ID=N,...",
        help="the artist's robots per region, e.g. 0=10,1=4 (region 0 is the largest)",
    )
    g.add_argument(
        "--tol",
        type=float,
        default=TOLERANCE,
        help=f"stop when the cost of eq. 1 falls by less than this fraction (default {TOLERANCE:g})",
    )
    g.add_argument("--max-iter", type=int, default=MAX_ITER, help=f"most Lloyd iterations (default {MAX_ITER})")
    g.add_argument(
        "--relax",
        type=float,
        default=RELAX,
        help=f"over-relaxation of the Lloyd step, 1 to 4 (default {RELAX}; 1 = plain Lloyd)",
    )


def _write_all(jobs: list[tuple[Path, Callable[[Path], object]]]) -> None:
    """Write every file to a temporary one beside it, then rename them all: a failure leaves no output file."""
    temps: list[Path] = []
    umask = os.umask(0)
    os.umask(umask)
    try:
        for path, write in jobs:
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
            os.close(fd)
            os.chmod(name, 0o666 & ~umask)
            temps.append(Path(name))
            write(Path(name))
        for (path, _), tmp in zip(jobs, temps):
            os.replace(tmp, path)
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)


def _check_output(path: Path, what: str) -> None:
    if path.is_dir():
        raise GoalError(f"{what} {path} is a directory")
    if not path.parent.is_dir():
        raise GoalError(f"cannot write {what} {path}: no such directory {path.parent}")


def run_goals(args: argparse.Namespace) -> int:
    """Run the goals command; returns the exit code (2 on bad input, with one line on stderr)."""
    from .goals import GoalOptions, goals_from_prepared, prepare_image  # here only: OpenCV, SciPy

    try:
        out = Path(args.output)
        preview = Path(args.preview) if args.preview else None
        _check_output(out, "output")
        if preview is not None:
            _check_output(preview, "preview")
            if preview.resolve() == out.resolve():  # the preview would be written over the goals
                raise GoalError(f"--preview {preview} is the goals file -o {out}: give them different names")
        counts = _region_counts(args.region_counts) if args.region_counts else None
        prep = prepare_image(args.image, background=args.background)
        options = GoalOptions(  # each option is the flag of its name
            **{f.name: getattr(args, f.name) for f in fields(GoalOptions)} | {"region_counts": counts}
        )
        gs = goals_from_prepared(prep, args.n, options)
        text = gs.to_json(indent=1) + "\n"
        jobs: list[tuple[Path, Callable[[Path], object]]] = [(out, lambda p: p.write_text(text))]
        if preview is not None:
            jobs.append((preview, lambda p: render_preview(prep, gs, p)))
        _write_all(jobs)
    except GoalError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{PROG}: error: cannot write output: {exc.strerror or exc}", file=sys.stderr)
        return 2
    for note in gs.params["notes"]:
        print(f"{PROG}: note: {note}", file=sys.stderr)
    p = gs.params
    print(
        f"{len(gs)} goals in {len(p['regions'])} region(s), arena {p['arena']:g} m, min spacing "
        f"{p['min_spacing'] if p['min_spacing'] is not None else float('nan'):.3f} m, "
        f"{p['iterations']} Lloyd iterations -> {out}" + (f", preview {preview}" if preview else "")
    )
    return 0


def render_preview(prep: PreparedImage, gs: GoalSet, path: str | os.PathLike[str]) -> None:
    """Write a PNG preview of goal set gs computed from prep: the image in the arena frame, the Voronoi cells of
    the goals within their regions, and each goal drawn as a robot footprint (radius r_A) in its colour."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PatchCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    from .goals.colors import voronoi_cells
    from .goals.resize import from_arena

    h, w = prep.shape
    s = prep.scale
    arena = gs.arena
    goals_px = from_arena(gs.goals, prep.shape, arena)
    cells = voronoi_cells(prep.seg, goals_px, gs.regions)
    edge = np.zeros((h, w), bool)
    edge[:, 1:] |= cells[:, 1:] != cells[:, :-1]
    edge[1:, :] |= cells[1:, :] != cells[:-1, :]
    img = prep.rgb.astype(float) / 255.0
    img = 0.55 * img + 0.45  # faded so the goals stand out
    img[edge] = (0.15, 0.15, 0.15)
    half_w, half_h = arena * w / (2 * s), arena * h / (2 * s)
    fig = Figure(figsize=(7, 7))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.imshow(img, extent=(-half_w, half_w, -half_h, half_h), origin="upper", interpolation="nearest")
    patches = [Circle((x, y), gs.params["robot_radius"]) for x, y in gs.goals]
    pc = PatchCollection(patches, facecolors=gs.colors / 255.0, edgecolors="black", linewidths=0.6)
    ax.add_collection(pc)
    ax.set(xlim=(-arena / 2, arena / 2), ylim=(-arena / 2, arena / 2), aspect="equal", xlabel="x (m)", ylabel="y (m)")
    p = gs.params
    ax.set_title(
        f"{len(gs)} goals, {p['method']}, arena {arena:g} m, {len(p['regions'])} region(s)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(os.fspath(path), dpi=120, format="png")
