"""A lab without robots (docs/hardware.md): emulated e-puck2 robots at a scene's start layout, their true poses
on emulated motion capture, the contacts between their bodies reported on exit.

    python -m sim.emulators.lab --scene paper-sequence -m router -l tcp/127.0.0.1:7447 --write-hardware hw.toml
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent.core.params import RobotParams
from coordinator.scene import Scene, SceneError, load_scene
from hardware.config import Started
from sim.args import OneLineParser, UsageError, positive_int, positive_number, refuse
from sim.processes import stopped_by_signals
from transport.session import TransportError, ZenohSettings, add_zenoh_args, settings_from_args

from .epuck2 import Epuck2Emulator, say_final, write_atomically
from .mocap import MocapEmulator

MOCAP_RATE = 50.0  # Hz: PoseStamped per robot
RECORD_RATE = 50.0  # Hz: true poses kept for the trajectory and the contact watch
RETRY_EVERY = 0.5  # s: a client lab waits for its router to come up
HIGHEST_PORT = 65535


@dataclass
class ContactEpisode:
    """Two bodies overlapping from t_start to t_end (s since the lab started), at most max_depth (m) deep."""

    i: int
    j: int
    t_start: float
    t_end: float
    max_depth: float


class Lab(Started):
    """N emulated e-puck2 robots at the scene's start poses, their true poses on motion capture."""

    def __init__(
        self, scene: Scene, settings: ZenohSettings, *, rate: float = MOCAP_RATE, first_port: int | None = None
    ) -> None:
        """``first_port``: robot i listens on first_port + i (a static hardware file); None: free ports."""
        self.scene = scene
        self.params = RobotParams.from_dict(scene.robot)
        n = scene.robots
        ports = [first_port + i for i in range(n)] if first_port else None
        poses = [(float(x), float(y), float(t)) for x, y, t in np.asarray(scene.poses, float)]
        self.emulator = Epuck2Emulator(n, poses=poses, ports=ports, params=self.params)
        self.mocap = MocapEmulator(self.true_poses, settings, rate=rate)
        self.t: list[float] = []
        self.poses: list[np.ndarray] = []
        self.contacts: list[ContactEpisode] = []
        self._open: dict[tuple[int, int], ContactEpisode] = {}
        self._halt = threading.Event()
        self._final: dict[str, Any] | None = None  # the report, once closed
        self._recorder = threading.Thread(target=self._record, name="lab-recorder", daemon=True)
        self.started = time.monotonic()

    def true_poses(self, t: float | None = None) -> np.ndarray:
        """Every robot's true pose now, rows of x (m), y (m), theta (rad)."""
        return np.array([self.emulator.pose(i) for i in range(self.scene.robots)])

    def hardware_toml(self) -> str:
        """A hardware file for this lab: the robots' addresses and the motion capture's topic."""
        return (
            self.emulator.hardware_toml()
            + f'\n# their true poses, from python -m sim.emulators.lab\n[poses]\nkind = "ros2"\ntopic = "{self.mocap.config.topic}"\n'
        )

    def start(self) -> Lab:
        self.emulator.start()
        try:
            self.mocap.start()
        except BaseException:
            self.emulator.close()
            raise
        self.started = time.monotonic()
        self._recorder.start()
        return self

    def close(self) -> dict[str, Any]:
        """Stop everything; returns the final report() (again, if already closed)."""
        if self._final is not None:
            return self._final
        self._halt.set()
        if self._recorder.is_alive():
            self._recorder.join()
        self.mocap.close()
        self.contacts.extend(self._open.values())  # still open: they end here
        self._open.clear()
        self._final = self.report()
        self.emulator.close()
        return self._final

    def report(self) -> dict[str, Any]:
        """Each robot's address, final pose and received commands (time.monotonic() s, steps/s), the
        recorded true trajectory and the contacts between bodies."""
        return {
            "robots": self.emulator.report()["robots"],
            "started": self.started,
            "trajectory": {"t": self.t, "pose": [p.tolist() for p in self.poses]},
            "contacts": [vars(c) for c in self.contacts],
        }

    def _record(self) -> None:
        period = 1.0 / RECORD_RATE
        while not self._halt.wait(period):
            t, pose = time.monotonic() - self.started, self.true_poses()
            self.t.append(t)
            self.poses.append(pose)
            self._watch_contacts(t, pose)

    def _watch_contacts(self, t: float, pose: np.ndarray) -> None:
        xy = pose[:, :2]
        gaps = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) - 2 * self.params.radius
        overlapping = set(zip(*np.nonzero(np.triu(gaps < 0, 1))))
        for i, j in overlapping:
            pair = (int(i), int(j))
            episode = self._open.setdefault(pair, ContactEpisode(*pair, t, t, 0.0))
            episode.t_end, episode.max_depth = t, max(episode.max_depth, float(-gaps[i, j]))
        for pair in [p for p in self._open if p not in overlapping]:
            self.contacts.append(self._open.pop(pair))


def open_lab(args: argparse.Namespace, settings: ZenohSettings, stop: threading.Event) -> Lab | None:
    """The lab, started; a client lab waits for its router (None if stopped while waiting)."""
    scene = load_scene(args.scene, robots=args.robots, seed=args.seed)
    n = scene.robots
    if args.port is not None and args.port + n - 1 > HIGHEST_PORT:  # robot i listens on PORT + i
        raise UsageError(
            f"--port {args.port}: robots 0-{n - 1} would listen on ports {args.port}-{args.port + n - 1}, "
            f"beyond {HIGHEST_PORT}; give --port at most {HIGHEST_PORT - n + 1}"
        )
    said = False
    while not stop.is_set():
        lab = Lab(scene, settings, rate=args.rate, first_port=args.port)
        try:
            return lab.start()
        except TransportError as err:
            if settings.mode != "client":
                raise
            if not said:
                print(f"lab: waiting for the router ({err})", flush=True)
                said = True
            stop.wait(RETRY_EVERY)
    return None


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m sim.emulators.lab",
        description="Emulated e-puck2 robots at a scene's start layout and motion capture of their true poses "
        "(PoseStamped over rmw_zenoh), until SIGINT or SIGTERM.",
    )
    parser.add_argument("--scene", required=True, help="a shipped scene or a scene file: its start layout")
    parser.add_argument("--robots", "-n", type=positive_int, help="number of robots (overrides the scene)")
    parser.add_argument("--seed", type=int, help="random seed (overrides the scene's, for random layouts)")
    parser.add_argument(
        "--rate", type=positive_number, default=MOCAP_RATE, help=f"motion capture Hz (default {MOCAP_RATE:g})"
    )
    parser.add_argument("--port", type=positive_int, help="robot i listens on PORT + i (default: free ports)")
    parser.add_argument("--write-hardware", type=Path, metavar="FILE.toml", help="write a hardware file for the lab")
    parser.add_argument(
        "--log", type=Path, metavar="FILE.json", help="on exit, write commands, final and recorded true poses, contacts"
    )
    add_zenoh_args(parser, default_mode="client")
    args = parser.parse_args(argv)
    settings = settings_from_args(args)
    if settings.mode == "client" and not settings.connect:
        parser.error("a client lab needs its router: -e ENDPOINT (or -m router -l ENDPOINT to be the router)")
    with stopped_by_signals() as stop:
        try:
            lab = open_lab(args, settings, stop)
            if lab is None:
                return 0
            try:
                if args.write_hardware:
                    write_atomically(args.write_hardware, lab.hardware_toml())
                where = ", ".join(settings.listen or settings.connect)
                print(f"lab: {lab.scene.robots} emulated e-puck2 robots, motion capture on {where}", flush=True)
                stop.wait()
            finally:
                report = lab.close()
            say_final(report, args.log)
            print(f"contacts: {len(report['contacts'])}", flush=True)
        except (UsageError, SceneError, TransportError, OSError, ValueError) as err:
            return refuse(parser.prog, err)
    return 0


if __name__ == "__main__":
    sys.exit(main())
