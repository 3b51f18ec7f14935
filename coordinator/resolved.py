"""A resolved scene: a scene with its goal sets, saved in a run directory as scene.json and goal_sets.npz
(docs/outputs.md), so the world and coordinator read it without TOML or the image pipeline."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from .motion import StepMotion
from .scene import CLOCKS, Noise, Overrides, Scene, SceneError, goal_pipeline, load_scene, parse_scene
from .steps import GoalSets, ImageStep

SCENE_FILE = "scene.json"
GOAL_SETS_FILE = "goal_sets.npz"
FORMAT = "pixelswarm.scene/1"


class StoredGoals(GoalSets):
    """Goal sets read from a run directory; a count not stored is made by the image pipeline when asked for."""

    def __init__(self, path: Path, scene: Scene, arena: float) -> None:
        super().__init__(len(scene.steps), scene.robots, scene.seed, scene.radius, None)
        self.arena, self.scene = arena, scene
        self._pipeline: GoalSets | None = None
        try:
            with np.load(path) as npz:
                for name in npz.files:
                    if name.startswith("goals_"):
                        k, n = (int(v) for v in name.removeprefix("goals_").split("_"))
                        self._keep(k, n, npz[name], npz[f"colors_{k}_{n}"])
        except (OSError, ValueError, KeyError) as err:
            raise SceneError(f"{path}: cannot read the run's goal sets: {err}") from None

    @property
    def counts(self) -> list[int]:
        """The robot counts whose goal sets were stored."""
        return sorted({n for _, n in self._sets})

    def _made(self, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        if self._pipeline is None:  # the scene as the run parsed it, in the run's arena K_r
            s = self.scene
            self._pipeline = goal_pipeline(
                parse_scene(s.source, robots=s.robots, seed=s.seed, duration=s.duration), self.arena
            )
        return self._pipeline.goal_set(step, n)


def stored_counts(scene: Scene) -> list[int]:
    """The robot counts a run saves goal sets for: every robot (the arena's) and the robot pixels."""
    return sorted({scene.robots, len(scene.pixel_robots)} - {0})


# the scene's settings that scene.json holds as they are, in its order, each with its type
_AS_IS = {"name": str, "source": str, "robots": int, "seed": int, "clock": str, "engine": str, "assignment": str}
_AS_IS |= {"agents_per_process": int, "deadline": float, "duration": float, "converge_hold": float}


def save_resolved(scene: Scene, folder: Path, robot: dict[str, Any] | None = None) -> None:
    """Write scene.json and, for an image scene, goal_sets.npz into ``folder`` (``robot``: else the scene's)."""
    folder = Path(folder)
    image = None
    if scene.image_goals is not None:
        counts = stored_counts(scene)
        arrays: dict[str, np.ndarray] = {"arena": np.array(scene.image_goals.arena)}
        for k in range(len(scene.steps)):
            for n in counts:
                arrays[f"goals_{k}_{n}"], arrays[f"colors_{k}_{n}"] = scene.image_goals.goal_set(k, n)
        np.savez(folder / GOAL_SETS_FILE, **arrays)  # type: ignore[arg-type]  # numpy types **kwds as its allow_pickle
        image = {"arena": float(scene.image_goals.arena), "counts": counts, "file": GOAL_SETS_FILE}
    record = {
        "format": FORMAT,
        **{key: getattr(scene, key) for key in _AS_IS},
        "arena": list(scene.arena),
        "obstacles": [[list(v) for v in o] for o in scene.obstacles],
        "robot": dict(scene.robot if robot is None else robot),
        "layout": scene.layout,
        "goals": scene.goals,
        "events": scene.events,
        "noise": dataclasses.asdict(scene.noise),
        "scripted": {str(r): w.tolist() for r, w in scene.scripted.items()},
        "pursuers": {str(r): t for r, t in scene.pursuers.items()},
        "poses": scene.poses.tolist(),
        "goal_positions": [[None if math.isnan(v) else float(v) for v in row] for row in scene.goal_positions],
        "steps": [dataclasses.asdict(s) for s in scene.steps],  # json writes region ids and paths as strings
        "image_goals": image,
    }
    (folder / SCENE_FILE).write_text(json.dumps(record, indent=1, default=str) + "\n")


def load_resolved(folder: Path | str, *, clock: str | None = None, duration: float | None = None) -> Scene:
    """The scene a run directory holds, with its goal sets and overrides. SceneError (one line) if none."""
    path = Path(folder) / SCENE_FILE
    try:
        data = json.loads(path.read_text())
    except OSError as err:
        raise SceneError(f"{path}: cannot read: {err.strerror}") from None
    except json.JSONDecodeError as err:
        raise SceneError(f"{path}: not valid JSON: {err}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SceneError(f"{path}: not a resolved scene ({FORMAT}): write it with `pixelswarm run`")
    try:
        scene = _scene_of(data)
    except (KeyError, TypeError, ValueError) as err:
        raise SceneError(f"{path}: incomplete resolved scene ({type(err).__name__}: {err})") from None
    scene.clock = clock or scene.clock
    scene.duration = float(duration) if duration is not None else scene.duration
    image = data.get("image_goals")
    if image is not None:
        scene.image_goals = StoredGoals(Path(folder) / image["file"], scene, float(image["arena"]))
        scene.goal_set, scene.goal_colors = scene.image_goals.goal_set(0, scene.robots)
    return scene


def _scene_of(data: dict[str, Any]) -> Scene:
    goal_positions = np.array(data["goal_positions"], float).reshape(-1, 2)  # JSON's null: NaN, no goal
    xmin, ymin, xmax, ymax = (float(v) for v in data["arena"])
    return Scene(
        **{key: kind(data[key]) for key, kind in _AS_IS.items()},
        robot=dict(data["robot"]),
        layout=dict(data["layout"]),
        goals=dict(data["goals"]),
        arena=(xmin, ymin, xmax, ymax),
        obstacles=[[(float(x), float(y)) for x, y in o] for o in data["obstacles"]],
        events=list(data["events"]),
        noise=Noise(**data["noise"]),
        scripted={int(r): np.array(w, float) for r, w in data["scripted"].items()},
        pursuers={int(r): int(t) for r, t in data["pursuers"].items()},
        steps=[_step_of(s) for s in data["steps"]],
        poses=np.array(data["poses"], float).reshape(-1, 3),
        goal_positions=goal_positions,
    )


def _step_of(data: dict[str, Any]) -> ImageStep:
    """An ImageStep as save_resolved wrote it (its fields by name, JSON's lists and strings made over)."""
    image, counts, motion = data["image"], data.get("region_counts"), data.get("motion")
    if motion is not None:
        motion = StepMotion(**motion | {"velocity": tuple(motion["velocity"]), "center": tuple(motion["center"])})
    return ImageStep(
        **data
        | {
            "image": None if image is None else Path(image),
            "region_counts": None if counts is None else {int(k): int(v) for k, v in counts.items()},
            "motion": motion,
        }
    )


def add_scene_args(parser: argparse.ArgumentParser) -> None:
    """A run's child process's scene: resolved in the run directory, or by name, with overrides."""
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--run-dir", help="a run directory holding the resolved scene (no image pipeline)")
    where.add_argument("--scene", help="a scene to load (with its goal sets: the image pipeline)")
    parser.add_argument("--robots", type=int)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--clock", choices=CLOCKS)
    parser.add_argument("--duration", type=float)
    parser.add_argument("--display", default="default", help="the display's name (key prefix)")


def scene_of_args(args: argparse.Namespace, **fixed: Unpack[Overrides]) -> Scene:
    """The scene add_scene_args's arguments name, ``fixed`` winning (hardware: its robots, the wall clock)."""
    given: Overrides = {"robots": args.robots, "seed": args.seed, "clock": args.clock, "duration": args.duration}
    given.update(fixed)
    if getattr(args, "run_dir", None) is not None:
        return load_resolved(args.run_dir, clock=given.get("clock"), duration=given.get("duration"))
    return load_scene(args.scene, **given)
