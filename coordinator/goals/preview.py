"""Preview of a goal set: the image in the arena frame, the Voronoi cells of the goals within their
regions, and each goal drawn as a robot footprint (radius r_A) in its colour."""

from __future__ import annotations

import os

import numpy as np

from .colors import voronoi_cells
from .model import GoalSet
from .pipeline import PreparedImage
from .resize import from_arena


def render_preview(prep: PreparedImage, gs: GoalSet, path: str | os.PathLike[str], *, dpi: int = 120) -> None:
    """Write a PNG preview of goal set gs computed from prep."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PatchCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

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
    radius = float(gs.params.get("robot_radius", 0.0)) or 0.3 * (gs.min_spacing() if len(gs) > 1 else arena)
    patches = [Circle((x, y), radius) for x, y in gs.goals]
    pc = PatchCollection(patches, facecolors=gs.colors / 255.0, edgecolors="black", linewidths=0.6)
    ax.add_collection(pc)
    ax.set(xlim=(-arena / 2, arena / 2), ylim=(-arena / 2, arena / 2), aspect="equal", xlabel="x (m)", ylabel="y (m)")
    p = gs.params
    ax.set_title(
        f"{len(gs)} goals, {p.get('method', '?')}, arena {arena:g} m, {len(p.get('regions', []))} region(s)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(os.fspath(path), dpi=dpi, format="png")
