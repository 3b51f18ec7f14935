"""`pixelswarm goals`: the command, its goals.json and preview, and one-line errors with exit code 2."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from coordinator import shapes
from coordinator.goals_cli import add_goals_parser
from tests.support import shape_truth

REPO = Path(__file__).resolve().parents[2]
HELPER = (
    "import argparse,sys; from coordinator.goals_cli import add_goals_parser; "
    "p=argparse.ArgumentParser(prog='pixelswarm'); s=p.add_subparsers(); add_goals_parser(s); "
    "a=p.parse_args(sys.argv[1:]); sys.exit(a.func(a))"
)


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="pixelswarm")
    add_goals_parser(parser.add_subparsers())
    return parser.parse_args(["goals", *map(str, argv)])


def _image(path: Path, name: str = "disk_and_line", size: int = 128) -> Path:
    cv2.imwrite(str(path), cv2.cvtColor(shapes.draw(name, size), cv2.COLOR_RGB2BGR))
    return path


def test_goals_command_writes_goals_and_preview(tmp_path, capsys):
    img = _image(tmp_path / "in.png")
    out, preview = tmp_path / "goals.json", tmp_path / "preview.png"
    args = _parse(
        img,
        "-n",
        14,
        "--arena",
        2.0,
        "--method",
        "kmeans",
        "--seed",
        3,
        "-o",
        out,
        "--preview",
        preview,
        "--region-counts",
        "0=10,1=4",
    )
    assert args.func(args) == 0
    data = json.loads(out.read_text())
    assert len(data["goals"]) == len(data["colors"]) == len(data["regions"]) == 14
    assert np.bincount(data["regions"]).tolist() == [10, 4]
    assert np.abs(np.array(data["goals"])).max() <= 1.0
    assert all(0 <= c <= 255 for rgb in data["colors"] for c in rgb)
    assert data["cost_history"] and data["params"]["method"] == "kmeans" and data["params"]["seed"] == 3
    assert data["params"]["arena"] == 2.0
    shown = cv2.imread(str(preview))
    assert shown is not None and shown.shape[0] > 200
    assert "14 goals" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["goals.json", "in.png", "preview.png"]


def _bad_inputs(tmp_path: Path) -> dict[str, list]:
    good = _image(tmp_path / "good.png")
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((64, 64, 3), 255, np.uint8))
    (tmp_path / "text.png").write_text("hello")
    return {
        "missing file": [tmp_path / "nope.png", "-n", 10],
        "unreadable file": [tmp_path / "text.png", "-n", 10],
        "no foreground": [blank, "-n", 10],
        "N too small": [good, "-n", 0],
        "more robots than a display has ids": [good, "-n", 2**16 + 1],
        "N too large for the arena": [good, "-n", 400, "--arena", 1.0],
        "bad background": [good, "-n", 10, "--background", "mauve-ish"],
        "bad region counts": [good, "-n", 10, "--region-counts", "0=20"],
    }


def test_bad_inputs_give_one_line_and_exit_2(tmp_path, capsys):
    for what, argv in _bad_inputs(tmp_path).items():
        out = tmp_path / "out.json"
        args = _parse(*argv, "-o", out, "--preview", tmp_path / "p.png")
        assert args.func(args) == 2, what
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("pixelswarm goals: error: "), (what, err)
        assert not out.exists() and not (tmp_path / "p.png").exists(), what
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_command_in_a_subprocess(tmp_path):
    img = _image(tmp_path / "in.png", "T")
    run = lambda *argv: subprocess.run(
        [sys.executable, "-c", HELPER, "goals", *map(str, argv)], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    ok = run(img, "-n", 12, "-o", tmp_path / "g.json")
    assert ok.returncode == 0, ok.stderr
    assert len(json.loads((tmp_path / "g.json").read_text())["goals"]) == 12
    bad = run(tmp_path / "missing.png", "-n", 12, "-o", tmp_path / "h.json")
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.splitlines() == [f"pixelswarm goals: error: no such file: {tmp_path / 'missing.png'}"]
    assert not (tmp_path / "h.json").exists()


def test_the_command_line_of_every_command_loads_no_image_pipeline_nor_scipy():
    """`pixelswarm`'s command line holds this command's parser (its defaults from coordinator.goals.defaults):
    building it, as every command does first (a run, a refused one, the agents, the router), loads
    neither the image pipeline nor SciPy."""
    code = (
        "import sys; from sim.cli.main import build_parser; build_parser(); "
        "print([m for m in ('scipy', 'coordinator.goals.pipeline', 'coordinator.goals.cvt') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_notes_go_to_stderr_without_failing(tmp_path, capsys):
    img, _ = shape_truth.photo_like(128, seed=2)
    path = tmp_path / "photo.jpg"
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    args = _parse(path, "-n", 30, "-o", tmp_path / "g.json")
    assert args.func(args) == 0
    lines = capsys.readouterr().err.splitlines()
    assert lines and all(line.startswith("pixelswarm goals: note: ") for line in lines)


def test_a_preview_named_as_the_goals_file_is_refused_and_overwrites_nothing(tmp_path, capsys):
    """-o X --preview X (however X is spelt) wrote the preview over the goals: refused, X kept."""
    img = _image(tmp_path / "in.png")
    goals = tmp_path / "g.json"
    goals.write_text("the goals of yesterday")
    for preview in (goals, tmp_path / "." / "g.json"):
        args = _parse(img, "-n", 10, "-o", goals, "--preview", preview)
        assert args.func(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("pixelswarm goals: error: --preview "), err
        assert "is the goals file" in err
        assert goals.read_text() == "the goals of yesterday"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.json", "in.png"]
