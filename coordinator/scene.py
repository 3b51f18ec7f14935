"""Scenes: TOML files naming the robots, their layout and goals, the arena, obstacles, events and clock
(every key: docs/scenes.md). Errors are SceneError, one line saying what is wrong and how to fix it."""

from __future__ import annotations

import bisect
import math
import tomllib
from dataclasses import dataclass, field, fields
from itertools import accumulate
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np

from transport import epuck
from transport.codec import MAX_ROBOTS

from .goals import IMAGE_SUFFIXES, GoalError
from .motion import check_keys, check_window, is_number, is_positive, one_of, positive
from .steps import Animation, FrameGoals, GoalSets, ImageStep, StepGoals, parse_animation, parse_step, scene_relative

SCENE_DIR = Path(__file__).parent / "scenes"
# m from the origin that an arena may reach: positions cross the bus as 32-bit floats (transport.codec), which
# step at most a quarter of a millimetre within it, and twice as coarsely with each doubling beyond
FARTHEST = 4096.0
# each kind of [layout], [goals] and [[events]] table and the keys it takes besides kind: any other is a mistake
LAYOUT_KEYS = {
    "circle": ("spacing", "radius"),
    "grid": ("spacing", "cols", "heading"),
    "random": ("spacing", "size"),
    "rows": ("spacing", "gap"),
    "blocks": ("spacing", "offset"),
    "file": ("path",),
    "list": ("poses",),
}
GOAL_KEYS = {
    "antipodal": (),
    "swap": (),
    "list": ("positions",),
    "stay": (),
    "none": (),
    "image": ("image", "shape", "region_counts", "method", "name", "arena"),
}
CLOCKS = ("lockstep", "realtime")
ENGINES = ("distributed", "central")
ASSIGNMENTS = ("auction", "optimal")


class SceneError(ValueError):
    """A scene cannot be run; the message is one line for the user."""


@dataclass
class Noise:
    tracking_xy: float = 0.002  # paper 7.1: localised with a precision of 2 mm ...
    tracking_theta_deg: float = 3.0  # ... and 3 degrees
    actuation: float = 0.02  # relative std of wheel-speed / velocity execution


@dataclass
class GoalPlan:
    """How an image scene's goal sets are made, as parsing found it (make_goal_sets follows it)."""

    animation: Animation | None  # the [animation]'s keyframes, or None for [[steps]] / [goals]
    labels: list[str] | None  # how errors name each step
    counts_for: int  # the robot count the artist's region_counts were written for
    arena: float | None  # K_r as the scene gives it ([goals] arena), None: the largest any step needs
    arena_spec: Any = "auto"  # the scene's [arena]: "auto" or a table with size


@dataclass
class Scene:
    """A parsed scene: one attribute per scene-file key, plus what parsing derives (poses, goals, steps)."""

    name: str
    robots: int
    robot: dict[str, Any]
    layout: dict[str, Any]
    goals: dict[str, Any]
    arena: tuple[float, float, float, float]
    obstacles: list[list[tuple[float, float]]]
    events: list[dict[str, Any]]
    clock: str = "lockstep"
    engine: str = "distributed"  # the default of `pixelswarm run --engine` for this scene
    assignment: str = "auction"  # central engine: the auction protocol, or scipy's optimum with Delta C
    agents_per_process: int = 1  # the default of `pixelswarm run -k` for this scene
    deadline: float = 2.0  # lock-step: seconds the world waits for a late command (a missed tick after)
    duration: float = 120.0
    seed: int = 1
    noise: Noise = field(default_factory=Noise)
    converge_hold: float = 1.0
    source: str = ""
    scripted: dict[int, np.ndarray] = field(default_factory=dict)  # robot -> waypoints (K,3) of t, x, y
    pursuers: dict[int, int] = field(default_factory=dict)  # robot -> the robot it pursues
    goal_set: np.ndarray | None = None  # (N,2) goals the robots assign themselves to (image scenes): step 0's
    goal_colors: np.ndarray | None = None  # (N,3) uint8 LED colours of those goals
    steps: list[ImageStep] = field(default_factory=list)  # image scenes: the images in order, with hold times
    image_goals: GoalSets | None = field(default=None, repr=False)  # every step's goal sets, shared K_r
    goal_plan: GoalPlan | None = field(default=None, repr=False)  # image scenes: how their goal sets are made
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # initial poses (N,3)
    goal_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # per-robot goals (N,2), NaN: none

    @property
    def radius(self) -> float:
        return float(self.robot.get("radius", epuck.RADIUS))

    @property
    def pixel_robots(self) -> list[int]:
        """The robots that show the image: all but the scripted movers and pursuers (paper Fig. 19)."""
        return [i for i in range(self.robots) if i not in self.scripted and i not in self.pursuers]

    @property
    def step_starts(self) -> list[float]:
        """When each step's hold begins: step k spans [sum of the previous holds, + hold_k)."""
        return list(accumulate((s.hold for s in self.steps[:-1]), initial=0.0)) if self.steps else []

    def step_at(self, t: float) -> int:
        """The step shown at time t (the last one stays after its hold ends); 0 without steps."""
        return max(bisect.bisect_right(self.step_starts, t + 1e-9) - 1, 0)

    @property
    def ends_on_convergence(self) -> bool:
        """A run ends early once the robots hold the last image, unless it moves (no final position)."""
        return not (self.steps and self.steps[-1].motion is not None)

    def step_window(self, k: int) -> float:
        """How long step k is shown: its hold, the last step until the run ends (if later)."""
        if k < len(self.steps) - 1:
            return self.steps[k].hold
        return max(self.steps[k].hold, self.duration - self.step_starts[k])


def shipped_scenes() -> list[str]:
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))


def resolve_scene_path(name_or_path: str) -> Path:
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise SceneError(f"scene file {name_or_path} not found (shipped scenes: {', '.join(shipped_scenes())})")
        return path
    shipped = SCENE_DIR / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    raise SceneError(f"unknown scene {name_or_path!r}: give a .toml path or one of {', '.join(shipped_scenes())}")


class Overrides(TypedDict, total=False):
    """What the command line may set over a scene's file (None: the file's)."""

    robots: int | None
    seed: int | None
    clock: str | None
    duration: float | None


def load_scene(name_or_path: str, **overrides: Unpack[Overrides]) -> Scene:
    """Read and validate a scene (or an image: its goals, a grid of robots) with its goal sets."""
    return make_goal_sets(parse_scene(name_or_path, **overrides))


def parse_scene(name_or_path: str, **overrides: Unpack[Overrides]) -> Scene:
    """Read and validate a scene without making its goal sets (make_goal_sets does, and their arena)."""
    is_image = Path(name_or_path).suffix.lower() in IMAGE_SUFFIXES
    if is_image and not Path(name_or_path).is_file():
        raise SceneError(f"image {name_or_path} not found")
    if is_image or Path(name_or_path).is_dir():  # a picture, or a folder of keyframes with the default timing
        table = _file_scene(name_or_path, overrides.pop("robots", None) or 14, is_image)
        return parse_scene_dict(table, name_or_path, **overrides)
    path = resolve_scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}") from None
    except OSError as err:
        raise SceneError(f"{path}: cannot read: {err.strerror}") from None
    return parse_scene_dict(data, str(path), **overrides)


def scene_from_dict(data: dict[str, Any], source: str = "<dict>", **overrides: Unpack[Overrides]) -> Scene:
    """A scene from its table (as the TOML file holds it), with its goal sets."""
    return make_goal_sets(parse_scene_dict(data, source, **overrides))


# a scene table's keys: any other is a mistake
SCENE_KEYS = frozenset(
    "name robots seed clock duration robot layout goals arena obstacles events noise end description scripted "
    "pursuers steps animation engine assignment agents_per_process deadline".split()
)


def parse_scene_dict(data: dict[str, Any], source: str = "<dict>", **overrides: Unpack[Overrides]) -> Scene:
    """A scene from its table, validated, without its goal sets (no image is read)."""
    return _wrap(lambda: _parse(data, source, overrides), source)


def _parse(data: dict[str, Any], source: str, overrides: Overrides) -> Scene:
    """parse_scene_dict's scene; its errors are GoalErrors, which parse_scene_dict names the scene in."""
    robots, seed, duration = overrides.get("robots"), overrides.get("seed"), overrides.get("duration")
    if unknown := set(data) - SCENE_KEYS:
        raise GoalError(f"unknown key(s) {', '.join(sorted(unknown))}")
    n = _whole(robots if robots is not None else data.get("robots", 14), "robots", 1)
    if n > MAX_ROBOTS:
        raise GoalError(f"robots must be at most {MAX_ROBOTS} (robot ids are 16-bit on the bus), not {n}")
    robot = _table(data, "robot", {})
    radius = positive(robot.get("radius", epuck.RADIUS), "robot radius", "metres")
    animation = parse_animation(data["animation"], source) if "animation" in data else None
    steps = list(animation.steps) if animation is not None else _steps(data, source)
    if animation is not None and ("steps" in data or "goals" in data):
        raise GoalError("give one of [animation], [[steps]] or [goals], not several")
    if duration is None:
        duration = data.get("duration", sum(s.hold for s in steps) if steps else Scene.duration)
    if not is_positive(duration):
        raise GoalError("duration must be a positive number of seconds")
    seed = _whole(seed if seed is not None else data.get("seed", Scene.seed), "seed", 0)
    scene = Scene(
        name=str(data.get("name", Path(source).stem)),
        robots=n,
        robot=robot,
        layout=_table(data, "layout", {"kind": "grid"}),
        goals=_table(data, "goals", {"kind": "none"}),
        arena=(0.0, 0.0, 0.0, 0.0),
        obstacles=[],
        events=_tables(data, "events"),
        clock=overrides.get("clock") or data.get("clock", Scene.clock),
        engine=data.get("engine", Scene.engine),
        assignment=data.get("assignment", Scene.assignment),
        agents_per_process=data.get("agents_per_process", Scene.agents_per_process),
        deadline=data.get("deadline", Scene.deadline),
        duration=float(duration),
        seed=seed,
        noise=_noise(_table(data, "noise", {})),
        converge_hold=_converge_hold(_table(data, "end", {})),
        source=source,
    )
    for key, choices in (("clock", CLOCKS), ("engine", ENGINES), ("assignment", ASSIGNMENTS)):
        one_of(getattr(scene, key), choices, key)
    scene.agents_per_process = _whole(scene.agents_per_process, "agents_per_process", 1)
    scene.deadline = positive(scene.deadline, "deadline")
    _kind_keys(scene.goals, GOAL_KEYS, "none", "goals")
    obstacles = _tables(data, "obstacles", ("vertices",))
    scene.obstacles = [_polygon(o, f"obstacles[{k}]") for k, o in enumerate(obstacles)]
    scene.poses = initial_poses(scene.layout, n, radius, scene.seed, source)
    if scene.goals.get("kind") == "image":  # one image: a sequence of one step, shown for the whole run
        steps = [parse_step(_image_step(scene.goals, scene.duration), "goals", source)]
    if steps:
        _plan_steps(scene, data, steps, animation)
    else:
        scene.goal_positions = scene_goals(scene.goals, scene.poses)
        _fit_arena(scene, data.get("arena", "auto"))  # image scenes: make_goal_sets
    _add_uncontrolled(scene, data)
    if not steps:
        _check_placed_inside(scene)
    return scene


def _add_uncontrolled(scene: Scene, data: dict[str, Any]) -> None:
    """The scene's events, checked, and its scripted movers and pursuers (paper Fig. 19), which take no goal."""
    for k, event in enumerate(scene.events):
        _check_event(event, f"events[{k}]", scene)
    scripted, pursuers = _tables(data, "scripted", MOVER_KEYS), _tables(data, "pursuers", PURSUER_KEYS)
    scene.scripted = {
        _robot_index(e, scene, f"scripted[{k}]"): _waypoints(e, f"scripted[{k}]") for k, e in enumerate(scripted)
    }
    scene.pursuers = {
        _robot_index(e, scene, f"pursuers[{k}]"): _robot_index(e, scene, f"pursuers[{k}]", "target")
        for k, e in enumerate(pursuers)
    }
    for r in scene.scripted:
        scene.goal_positions[r] = np.nan  # a scripted robot follows its path, not a goal


def _check_placed_inside(scene: Scene) -> None:
    """Teleports and scripted movers keep their robot inside the arena: beyond it, it would drive into the wall
    (or, far off, be a pose no agent believes: a lock-step world would wait for its command every tick)."""
    x0, y0, x1, y1 = scene.arena
    r = scene.radius
    places = [
        (f"events[{k}] (teleport) pose", e["pose"][:2]) for k, e in enumerate(scene.events) if e["kind"] == "teleport"
    ]
    places += [(f"scripted robot {m}'s waypoint", w[1:]) for m, path in scene.scripted.items() for w in path]
    for label, (x, y) in places:
        if not (x0 + r <= x <= x1 - r and y0 + r <= y <= y1 - r):
            raise GoalError(
                f"{label} ({x:g}, {y:g}) puts the robot outside the {x1 - x0:.2f} x {y1 - y0:.2f} m arena "
                f"[{x0:.2f}, {y0:.2f}] to [{x1:.2f}, {y1:.2f}]; move it inside or enlarge [arena] size"
            )


def _whole(value: Any, key: str, least: int) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < least:
        raise GoalError(f"{key} must be a whole number >= {least}, not {value!r}")
    return int(value)


def _finite(value: Any, label: str, unit: str) -> float:
    """A number the scene gives, any sign; TOML's nan and inf would reach the robots and stop the run mid-way."""
    if not is_number(value):
        raise GoalError(f"{label} must be a finite number of {unit}, not {value!r}")
    return float(value)


def _row(value: Any, names: str, label: str) -> np.ndarray:
    """A list of finite numbers, one per name in ``names`` (e.g. "x, y, theta"), as floats."""
    if not (isinstance(value, list) and len(value) == len(names.split(", ")) and all(is_number(v) for v in value)):
        raise GoalError(f"{label} must be [{names}] (finite numbers), not {value!r}")
    return np.array(value, float)


def _rows(value: Any, names: str, least: int, label: str) -> np.ndarray:
    """At least ``least`` rows of _row's, as an array (K, len(names))."""
    if not (isinstance(value, list) and len(value) >= least):
        given = f"{len(value)}" if isinstance(value, list) else repr(value)
        raise GoalError(f"{label} needs {least} [{names}] rows, not {given}")
    return np.array([_row(v, names, f"{label}[{k}]") for k, v in enumerate(value)])


def _kind_keys(table: dict[str, Any], kinds: dict[str, tuple[str, ...]], default: str | None, label: str) -> str:
    """A table's kind, one of ``kinds``, whose keys are checked against that kind's (a typo would be ignored)."""
    kind: str = one_of(table.get("kind", default), tuple(kinds), f"{label} kind")
    check_keys(table, ("kind", *kinds[kind]), f'{label} of kind "{kind}"')
    return kind


def _plan_steps(scene: Scene, data: dict[str, Any], steps: list[ImageStep], animation: Animation | None) -> None:
    """An image or animation scene's steps, and the plan make_goal_sets follows for their goal sets."""
    n = scene.robots
    scene.steps = steps
    written_for = data.get("robots", n)  # region_counts were written for the file's count: --robots scales them
    k_r = scene.goals.get("arena")
    scene.goal_plan = GoalPlan(
        animation,
        ["goals"] if "steps" not in data else None,
        written_for if isinstance(written_for, int) and written_for >= 1 else n,
        positive(k_r, "goals arena", "metres") if k_r is not None else None,
        data.get("arena", "auto"),
    )
    for k, step in enumerate(steps):
        if step.motion is not None:
            check_window(step.motion, f"steps[{k}]", scene.step_window(k))
    scene.goal_positions = np.full((n, 2), np.nan)


def make_goal_sets(scene: Scene) -> Scene:
    """An image scene's goal sets and the arena holding them, checked; other scenes are returned as they are."""
    if scene.goal_plan is None or scene.image_goals is not None:
        return scene
    scene.image_goals = goal_pipeline(scene)
    scene.goal_set, scene.goal_colors = scene_goal_set(scene, 0, scene.robots)
    spec = scene.goal_plan.arena_spec
    _wrap(lambda: _fit_arena(scene, spec), scene.source)
    _wrap(lambda: _check_placed_inside(scene), scene.source)
    return scene


def goal_pipeline(scene: Scene, arena: float | None = None) -> StepGoals | FrameGoals:
    """The image pipeline for a parsed image scene's goal sets, in arena K_r (None: the scene's, or the largest)."""
    plan = scene.goal_plan
    if plan is None:
        raise SceneError(f'{scene.name}: the scene shows no image (no [[steps]] or [goals] kind = "image")')
    try:
        if plan.animation is not None:
            return FrameGoals(plan.animation, scene.robots, scene.seed, scene.radius, arena, counts_for=plan.counts_for)
        k_r = arena if arena is not None else plan.arena
        return StepGoals(scene.steps, scene.robots, scene.seed, scene.radius, k_r, plan.labels, plan.counts_for)
    except GoalError as err:
        raise SceneError(f"{scene.source}: {err}") from None


def initial_poses(layout: dict[str, Any], n: int, radius: float, seed: int, source: str = "scene") -> np.ndarray:
    """Initial poses (N,3) of a layout (``source``: the scene file); headings face the centre for circle and rows."""
    kind = _kind_keys(layout, LAYOUT_KEYS, "grid", "layout")
    for key in ("spacing", "radius", "offset", "gap"):
        if key in layout:
            positive(layout[key], f"layout {key}", "metres")
    spacing = float(layout.get("spacing", 4.0 * radius))
    if kind == "circle":
        # Auto radius keeps neighbours on the circle `spacing` apart (RVO2's Circle, at display scale).
        r = float(layout.get("radius", max(spacing * n / (2 * math.pi), 2 * spacing)))
        a = 2 * math.pi * np.arange(n) / n
        return np.stack([r * np.cos(a), r * np.sin(a), a + math.pi], axis=1)
    if kind == "grid":
        cols = _whole(layout.get("cols", math.ceil(math.sqrt(n))), "layout cols", 1)
        heading = _finite(layout.get("heading", math.pi / 2), "layout heading", "radians")
        rows = math.ceil(n / cols)
        i = np.arange(n)
        x = (i % cols - (cols - 1) / 2) * spacing
        y = ((rows - 1) / 2 - i // cols) * spacing
        return np.stack([x, y, np.full(n, heading)], axis=1)
    if kind == "rows":
        # Two facing rows: robots 0..n/2-1 at the bottom facing up, the rest at the top facing down.
        gap = float(layout.get("gap", 1.0))
        bottom = (n + 1) // 2
        xs_b = (np.arange(bottom) - (bottom - 1) / 2) * spacing
        xs_t = (np.arange(n - bottom) - (n - bottom - 1) / 2) * spacing
        y = np.r_[np.full(bottom, -gap / 2), np.full(n - bottom, gap / 2)]
        th = np.r_[np.full(bottom, math.pi / 2), np.full(n - bottom, -math.pi / 2)]
        return np.stack([np.r_[xs_b, xs_t], y, th], axis=1)
    if kind == "blocks":
        return _blocks(n, spacing, float(layout.get("offset", 1.7)))
    if kind == "random":
        return _scattered(layout, n, spacing, seed)
    return _listed(layout, n, source)  # kind "list" or "file"


def _blocks(n: int, spacing: float, offset: float) -> np.ndarray:
    """RVO2's Blocks: four square groups in the corners, centre `offset` from the origin."""
    per = math.ceil(n / 4)
    side = math.ceil(math.sqrt(per))
    block = [((k % side - (side - 1) / 2) * spacing, (k // side - (side - 1) / 2) * spacing) for k in range(per)]
    corners = [(1, 1), (-1, 1), (1, -1), (-1, -1)]
    poses = [(sx * offset + gx, sy * offset + gy, math.atan2(-sy, -sx)) for sx, sy in corners for gx, gy in block]
    return np.array(poses[:n], float)


def _scattered(layout: dict[str, Any], n: int, spacing: float, seed: int) -> np.ndarray:
    """Random positions at least `spacing` apart in the layout's area, random headings."""
    side = max(1.0, spacing * math.sqrt(n) * 1.5)
    width, height = _row(layout["size"], "width, height", "layout size") if "size" in layout else (side, side)
    if min(width, height) <= 0:
        raise GoalError(f"layout size must be [width, height] in metres, above 0, not {layout['size']!r}")
    rng = np.random.default_rng(seed)
    pts: list[tuple[float, float]] = []
    tries = 0
    while len(pts) < n:
        tries += 1
        if tries > 200 * n:
            raise GoalError(f"cannot place {n} robots {spacing} m apart in a {width} x {height} m area")
        p = (rng.uniform(-width / 2, width / 2), rng.uniform(-height / 2, height / 2))
        if all((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 >= spacing**2 for q in pts):
            pts.append(p)
    th = rng.uniform(-math.pi, math.pi, n)
    return np.column_stack([np.array(pts), th])


def _listed(layout: dict[str, Any], n: int, source: str) -> np.ndarray:
    """The first N poses the layout lists (kind 'list') or a CSV file (relative to the scene) of x,y[,theta] holds."""
    if layout.get("kind") == "list":
        return _rows(layout.get("poses"), "x, y, theta", n, "layout poses")[:n]
    path = layout.get("path")
    if not isinstance(path, str):
        raise GoalError(f'layout of kind "file" needs path = "a CSV file of x,y[,theta] rows", not {path!r}')
    try:
        arr = np.loadtxt(scene_relative(path, source), delimiter=",", ndmin=2)
    except (OSError, ValueError) as err:
        raise GoalError(f"layout file {path}: {err}") from None
    if arr.shape[1] == 2:
        arr = np.column_stack([arr, np.zeros(len(arr))])
    if arr.shape[1] != 3 or len(arr) < n or not np.isfinite(arr[:n]).all():
        raise GoalError(f"layout file {path} needs {n} rows of x,y[,theta] (finite numbers)")
    return arr[:n].astype(float)


def scene_goals(goals: dict[str, Any], poses: np.ndarray) -> np.ndarray:
    """Per-robot goals (N,2) of a scene whose [goals] kind is checked and no image; NaN rows where a robot has none."""
    kind = goals.get("kind", "none")
    xy = poses[:, :2]
    if kind == "antipodal":
        return -xy.copy()
    if kind == "swap":
        return np.column_stack([xy[:, 0], -xy[:, 1]])
    if kind == "stay":
        return xy.copy()
    if kind == "none":
        return np.full_like(xy, np.nan)
    return _rows(goals.get("positions"), "x, y", len(xy), "goals positions")[: len(xy)]  # kind "list"


def _steps(data: dict[str, Any], source: str) -> list[ImageStep]:
    if "steps" not in data:
        return []
    if "goals" in data:
        raise GoalError("give either [[steps]] (an image sequence) or [goals], not both")
    entries = data["steps"]
    if not (isinstance(entries, list) and entries):
        raise GoalError("steps must be one or more [[steps]] tables")
    return [parse_step(e, f"steps[{k}]", source) for k, e in enumerate(entries)]


def _image_step(goals: dict[str, Any], hold: float) -> dict[str, Any]:
    """The [goals] kind = "image" table as a step (its own `arena` is K_r, read by StepGoals)."""
    if "shape" not in goals and "image" not in goals:
        raise GoalError('image goals need image = "path" or shape = "name"')
    keys = ("name", "image", "shape", "region_counts", "method")
    return {k: goals[k] for k in keys if k in goals} | {"hold": hold}


def _wrap(make: Any, where: str) -> Any:
    """Run a parsing or goal-generation call, its GoalError becoming the one-line SceneError of the scene ``where``."""
    try:
        return make()
    except GoalError as err:
        raise SceneError(f"{where}: {err}") from None


def scene_goal_set(scene: Scene, step: int, robots: int) -> tuple[np.ndarray, np.ndarray]:
    """Goals (n,2) and colours (n,3) uint8 of image step `step` for n robots (paper 5.1.2), cached, read-only."""
    source = scene.image_goals
    if source is None:
        raise SceneError(f'{scene.name}: the scene shows no image (no [[steps]] or [goals] kind = "image")')
    return _wrap(lambda: source.goal_set(step, robots), scene.name)


def _file_scene(path: str, robots: int, image: bool) -> dict[str, Any]:
    """The scene of `pixelswarm run picture.png` or `run folder/` (its keyframes): a grid of e-pucks."""
    full = Path(path).resolve()
    name = Path(path).stem if image else full.name
    table = {"name": name, "robots": robots, "layout": {"kind": "grid", "spacing": 0.2}}
    if image:
        return table | {"goals": {"kind": "image", "image": str(full)}, "duration": 120.0}
    return table | {"animation": {"keyframes": str(full)}}


def _arena(spec: Any, scene: Scene) -> tuple[float, float, float, float]:
    if spec == "auto" or spec is None:
        pts = [scene.poses[:, :2]]
        if scene.image_goals is not None:  # every step's picture, all robots (fewer robots: inside it)
            pts += [scene_goal_set(scene, k, scene.robots)[0] for k in range(len(scene.steps))]
            pts += list(_swept(scene).values())  # a moving picture: wherever it goes
        pts.append(scene.goal_positions[~np.isnan(scene.goal_positions).any(axis=1)])
        allp = np.vstack(pts + [np.asarray(o) for o in scene.obstacles])
        margin = 4 * scene.radius + 0.1
        lo, hi = allp.min(axis=0) - margin, allp.max(axis=0) + margin
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    if isinstance(spec, dict):
        check_keys(spec, ("size",), "arena")
    size = spec.get("size") if isinstance(spec, dict) else None
    if not (isinstance(size, list) and len(size) == 2 and all(is_positive(s) for s in size)):
        raise GoalError('arena must be "auto" or have size = [width, height] in metres')
    w, h = float(size[0]), float(size[1])
    for k, box in _swept(scene).items():
        box = box + np.array([[-scene.radius], [scene.radius]])  # the robots on the goals, too
        if box[0, 0] < -w / 2 or box[0, 1] < -h / 2 or box[1, 0] > w / 2 or box[1, 1] > h / 2:
            raise GoalError(
                f"the moving image of steps[{k}] leaves the {w:g} x {h:g} m arena "
                f"(it reaches [{box[0, 0]:.2f}, {box[0, 1]:.2f}] to [{box[1, 0]:.2f}, {box[1, 1]:.2f}]); "
                "enlarge [arena] size or slow the [steps.motion]"
            )
    return (-w / 2, -h / 2, w / 2, h / 2)


def _swept(scene: Scene) -> dict[int, np.ndarray]:
    """Per moving step (by its index in steps), a box (2,2) holding its goal set for as long as it is shown."""
    return {
        k: s.motion.swept_box(scene_goal_set(scene, k, scene.robots)[0], scene.step_window(k))
        for k, s in enumerate(scene.steps)
        if s.motion is not None
    }


def _fit_arena(scene: Scene, spec: Any) -> None:
    """The scene's arena from its [arena] ("auto": round everything it shows), which its robots must fit."""
    scene.arena = _arena(spec, scene)
    xmin, ymin, xmax, ymax = scene.arena
    farthest = max(abs(v) for v in scene.arena)
    if farthest > FARTHEST:
        raise GoalError(
            f"the arena reaches {farthest:.6g} m from the origin, beyond {FARTHEST:g} m, where the bus's 32-bit "
            "floats no longer place a robot to the millimetre; place the robots, goals and obstacles nearer (0, 0)"
        )
    r = scene.radius
    xy = scene.poses[:, :2]
    outside = (xy[:, 0] - r < xmin) | (xy[:, 0] + r > xmax) | (xy[:, 1] - r < ymin) | (xy[:, 1] + r > ymax)
    if outside.any():
        raise GoalError(
            f"{int(outside.sum())} of {scene.robots} robots do not fit in the "
            f"{xmax - xmin:.2f} x {ymax - ymin:.2f} m arena; enlarge [arena] size or use fewer robots"
        )
    import shapely  # here only; SciPy's k-d tree would load SciPy into the start of every run

    points = shapely.points(xy)
    i, j = shapely.STRtree(points).query(points, predicate="dwithin", distance=2 * r)
    apart = np.hypot(*(xy[i[i < j]] - xy[j[i < j]]).T)
    if (apart < 2 * r).any():
        raise GoalError(
            f"robots start overlapping (closest centres {float(apart.min()):.3f} m, "
            f"diameter {2 * r:.3f} m); increase layout spacing"
        )


# each kind of [[events]] and the keys it takes besides kind; [[scripted]] movers' and [[pursuers]]' keys
EVENT_KEYS = {
    "teleport": ("t", "robot", "pose"),
    "fail": ("t", "robot"),
    "tracker-outage": ("t", "duration"),
    "tracker-glitch": ("t", "robot", "offset"),
}
MOVER_KEYS = ("robot", "waypoints")
PURSUER_KEYS = ("robot", "target")
EVENT_SLACK = 1e-9  # s: an event at t is due at the tick stamped t, however tick x dt rounds


def events_of(scene: Scene, kind: str) -> list[dict[str, Any]]:
    """The scene's events of one kind, in order of time (for take_due)."""
    return sorted((e for e in scene.events if e["kind"] == kind), key=lambda e: e["t"])


def count_due(events: list[dict[str, Any]], t: float) -> int:
    """How many of ``events`` (events_of's, in order of time) are due by time t."""
    return bisect.bisect_right(events, t + EVENT_SLACK, key=lambda e: e["t"])


def take_due(events: list[dict[str, Any]], t: float) -> list[dict[str, Any]]:
    """The events due by time t, taken off ``events``."""
    taken = events[: count_due(events, t)]
    del events[: len(taken)]
    return taken


def _check_event(event: dict[str, Any], label: str, scene: Scene) -> None:
    kind = _kind_keys(event, EVENT_KEYS, None, label)
    positive(event.get("t"), f"{label} ({kind}) t")
    if kind == "tracker-outage":
        positive(event.get("duration"), f"{label} ({kind}) duration")
        return
    _robot_index(event, scene, f"{label} ({kind})")
    if kind == "teleport":
        _row(event.get("pose"), "x, y, theta", f"{label} ({kind}) pose")
    if kind == "tracker-glitch":
        _row(event.get("offset"), "dx, dy", f"{label} ({kind}) offset")


def _robot_index(entry: dict[str, Any], scene: Scene, label: str, key: str = "robot") -> int:
    value = entry.get(key)
    if not (isinstance(value, int) and not isinstance(value, bool) and 0 <= value < scene.robots):
        raise GoalError(f"{label}: {key} must be a robot index in 0..{scene.robots - 1}, not {value!r}")
    return value


def _waypoints(entry: dict[str, Any], label: str) -> np.ndarray:
    pts = _rows(entry.get("waypoints"), "t, x, y", 2, f"{label} waypoints")
    if np.any(np.diff(pts[:, 0]) <= 0):
        raise GoalError(f"{label} waypoints must be [[t, x, y], ...] with increasing t, not {pts[:, 0].tolist()}")
    return pts


def scripted_position(waypoints: np.ndarray, t: float) -> np.ndarray:
    """Where a scripted robot should be at time t (straight segments, holding the ends)."""
    return np.array([np.interp(t, waypoints[:, 0], waypoints[:, 1]), np.interp(t, waypoints[:, 0], waypoints[:, 2])])


def _table(data: dict[str, Any], key: str, default: dict[str, Any]) -> dict[str, Any]:
    value = data.get(key, default)
    if not isinstance(value, dict):
        raise GoalError(f"{key} must be a table ([{key}] with key = value lines), not {value!r}")
    return dict(value)


def _tables(data: dict[str, Any], key: str, keys: tuple[str, ...] | None = None) -> list[dict[str, Any]]:
    """The [[key]] tables of a scene, each with only ``keys`` (None: checked by kind, later)."""
    value = data.get(key, [])
    if not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
        raise GoalError(f"{key} must be [[{key}]] tables, not {value!r}")
    for k, table in enumerate(value):
        if keys is not None:
            check_keys(table, keys, f"{key}[{k}]")
    return list(value)


def _converge_hold(end: dict[str, Any]) -> float:
    check_keys(end, ("converge_hold",), "[end]")
    hold = end.get("converge_hold", Scene.converge_hold)
    if not (is_number(hold) and hold >= 0):
        raise GoalError(f"[end] converge_hold must be a number of seconds >= 0, not {hold!r}")
    return float(hold)


def _noise(data: dict[str, Any]) -> Noise:
    check_keys(data, tuple(f.name for f in fields(Noise)), "[noise]")
    for key, level in data.items():
        if not (is_number(level) and level >= 0):
            raise GoalError(f"[noise] {key} must be a number >= 0, not {level!r}")
    return Noise(**{k: float(v) for k, v in data.items()})


def _polygon(obstacle: dict[str, Any], label: str) -> list[tuple[float, float]]:
    verts = obstacle.get("vertices")
    pts = [(float(x), float(y)) for x, y in _rows(verts, "x, y", 3, f"{label} vertices")]
    if fault := _polygon_fault(pts):  # the world would refuse it once the run has begun
        raise GoalError(f"{label} vertices must outline a simple polygon ({fault}), not {verts!r}")
    area2 = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1]))
    return pts if area2 > 0 else pts[::-1]  # counter-clockwise, as ORCA's obstacle lines expect


def _polygon_fault(pts: list[tuple[float, float]]) -> str | None:
    """What makes a vertex list no simple polygon (a repeated vertex, no area, crossing edges), or None."""
    from shapely import Polygon, is_valid_reason  # here only: scenes without obstacles need no shapely

    polygon = Polygon(pts)
    if len(set(pts)) < len(pts):
        return "a vertex repeats"
    if polygon.area <= 0:
        return "it has no area"
    return None if polygon.is_valid else is_valid_reason(polygon).split("[")[0].lower()
