"""The conventions of docs/conventions.md that a user relies on: one robot default, read alike by every
package, and no package reaching into another module's private names."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

from agent.core.params import EPUCK, RobotParams
from coordinator.goals import generate_goals
from coordinator.keyframes import keyframe_goals
from coordinator.scene import scene_from_dict
from sim.bodies.world import Body, World
from tests.conftest import REPO
from transport import epuck

PACKAGES = ("agent", "coordinator", "transport", "sim", "hardware", "bench")


def private_imports(source: str) -> list[str]:
    """``from <one of ours> import _name`` in this source: the private names it takes from another module."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ImportFrom):
            continue
        ours = node.level > 0 or (node.module or "").split(".")[0] in PACKAGES
        found += [a.name for a in node.names if ours and a.name.startswith("_") and not a.name.startswith("__")]
    return found


def test_the_private_import_check_finds_one():
    assert private_imports("from .shapes import RED, _disk\nfrom numpy import _core\n") == ["_disk"]


def test_no_package_imports_a_private_name_of_another_module():
    offenders = {
        str(path.relative_to(REPO)): names
        for package in PACKAGES
        for path in sorted((REPO / package).rglob("*.py"))
        if (names := private_imports(path.read_text()))
    }
    assert offenders == {}


def test_every_package_assumes_the_same_robot_body():
    scene = scene_from_dict({"robots": 3, "goals": {"kind": "antipodal"}})
    assert scene.radius == EPUCK.radius == RobotParams().radius == epuck.RADIUS
    assert (EPUCK.v_max, EPUCK.omega_max, EPUCK.wheel_base) == (epuck.V_MAX, epuck.OMEGA_MAX, epuck.WHEEL_BASE)
    for goals in (generate_goals, keyframe_goals):
        assert inspect.signature(goals).parameters["options"].default.robot_radius == EPUCK.radius
    body = Body(EPUCK.kinematics, EPUCK.radius, EPUCK.v_max)
    assert body == Body.from_params(EPUCK)
    assert inspect.signature(World).parameters["noise"].default.period == EPUCK.dt


def test_the_goals_command_defaults_to_the_same_radius(tmp_path: Path):
    from sim.cli.main import build_parser

    args = build_parser().parse_args(["goals", str(tmp_path / "picture.png"), "-n", "5"])
    assert args.robot_radius == EPUCK.radius
