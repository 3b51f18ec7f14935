"""What a Rerun recording (.rrd) of the view holds, read back by Rerun's own reader (test_view,
test_view_connect)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


def recorded_swarm(path: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """tick -> (positions (N,2), colours (N,3)) of ``swarm/robots``, as Rerun reads its own file. The view
    logs colours at the ticks they change: a tick's colours are the newest at or before it, as Rerun's
    viewer shows them."""
    positions: dict[int, np.ndarray] = {}
    colors: dict[int, np.ndarray] = {}
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        if chunk.entity_path != "/swarm/robots":
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        ticks = batch.column(names.index("tick")).to_pylist()
        if "Points2D:positions" in names:
            for k, xy in zip(ticks, batch.column(names.index("Points2D:positions")).to_pylist()):
                if xy is not None:
                    positions[k] = np.array(xy, dtype=float)
        if "Points2D:colors" in names:
            for k, rgba in zip(ticks, batch.column(names.index("Points2D:colors")).to_pylist()):
                if rgba is not None:
                    packed = np.array(rgba, dtype=np.uint32)  # 0xRRGGBBAA
                    rgb = np.column_stack([(packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255])
                    colors[k] = rgb.astype(np.uint8)
    out = {}
    for k in sorted(positions):
        newest = max((c for c in colors if c <= k), default=None)
        assert newest is not None, f"no colours at or before tick {k}"
        out[k] = (positions[k], colors[newest])
    return out
