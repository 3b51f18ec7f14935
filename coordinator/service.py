"""The coordinator service: publishes what the display should show (goal sets, with an epoch).

Late joiners ask for the current goal set with a query; the set is also re-published every second,
so a lost message costs at most a second.
"""
from __future__ import annotations

import argparse
import colorsys
import os
import signal
import sys
import time

import numpy as np

from transport.bus import Bus
from transport.codec import Goals
from transport.session import TransportError, add_zenoh_args, settings_from_args

from .scene import Scene, SceneError, load_scene


def palette(n: int) -> np.ndarray:
    """Distinct, bright LED colours for robots with individual goals (hue around the circle)."""
    rgb = [colorsys.hsv_to_rgb(k / max(n, 1), 0.85, 1.0) for k in range(n)]
    return (np.array(rgb).reshape(-1, 3) * 255).round().astype(np.uint8)


def scene_goal_message(scene: Scene, epoch: int = 1) -> Goals | None:
    """Per-robot goals of a scene (RVO2-style examples), or None when the scene has none."""
    goals = scene.goal_positions
    if np.isnan(goals).all():
        return None
    # Robots without a goal of their own (scripted obstacles, pursuers) are told to stay put: a goal
    # message carries finite numbers only.
    none = np.isnan(goals).any(axis=1)
    goals = np.where(none[:, None], scene.poses[:, :2], goals)
    return Goals(epoch, 1, 0.0, len(goals), goals, palette(len(goals)))


class Coordinator:
    def __init__(self, bus: Bus, scene: Scene) -> None:
        self.bus, self.scene = bus, scene
        self.current = scene_goal_message(scene)
        bus.serve(bus.keys.all_of("goals"), self._answer)
        self.running = True
        self.parent_pid: int | None = None

    def _answer(self) -> list[tuple[str, bytes]]:
        if self.current is None:
            return []
        return [(self.bus.keys.goals(self.current.epoch), self.current.encode())]

    def run(self, period: float = 1.0) -> None:
        self.bus.declare_alive("coordinator", 0)
        while self.running:
            if self.current is not None:
                self.bus.publish(self.bus.keys.goals(self.current.epoch), self.current)
            end = time.monotonic() + period
            while self.running and time.monotonic() < end:
                time.sleep(0.05)
            if self.parent_pid is not None and os.getppid() != self.parent_pid:
                self.running = False  # orphaned: the launcher died without stopping us


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m coordinator.service")
    parser.add_argument("--scene", required=True)
    parser.add_argument("--robots", type=int)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--display", default="default")
    parser.add_argument("--exit-with-parent", action="store_true")
    add_zenoh_args(parser)
    args = parser.parse_args(argv)
    try:
        scene = load_scene(args.scene, robots=args.robots, seed=args.seed)
        bus = Bus(settings_from_args(args), args.display, name="coordinator")
    except (SceneError, TransportError) as err:
        print(f"coordinator: error: {err}", file=sys.stderr)
        return 2
    with bus:
        coordinator = Coordinator(bus, scene)
        if args.exit_with_parent:
            coordinator.parent_pid = os.getppid()

        def stop(signum: int, frame: object) -> None:
            coordinator.running = False

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        coordinator.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
