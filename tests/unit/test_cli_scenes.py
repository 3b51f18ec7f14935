"""`pixelswarm scenes`: one line per shipped scene, its columns aligned whatever the names' lengths."""

from __future__ import annotations

from types import SimpleNamespace

from sim.cli import main as cli


def test_scene_list_columns_align_for_long_names(monkeypatch, capsys, tmp_path):
    names = ["swap", "paper-sequence-1000", "a-scene-with-a-much-longer-name-than-sixteen"]
    robots = {"swap": 14, "paper-sequence-1000": 1000, "a-scene-with-a-much-longer-name-than-sixteen": 7}
    for name in names:
        (tmp_path / f"{name}.toml").write_text(
            f'robots = {robots[name]}\ndescription = "shows {name}"\n[robot]\nkinematics = "holonomic"\n'
        )
    monkeypatch.setattr(cli, "shipped_scenes", lambda: names)
    monkeypatch.setattr(cli, "resolve_scene_path", lambda name: tmp_path / f"{name}.toml")
    assert cli.cmd_scenes(SimpleNamespace()) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == names
    for word in (" robots", "holonomic", "shows "):  # every column starts at the same place
        assert len({line.index(word) for line in lines}) == 1, (word, lines)
    assert all(line.split()[1] == str(robots[line.split()[0]]) for line in lines)


def test_the_shipped_scenes_are_listed_with_what_they_show(capsys):
    assert cli.cmd_scenes(SimpleNamespace()) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == cli.shipped_scenes()
    paper = next(line for line in lines if line.split()[0] == "paper-sequence")
    assert " 14 robots " in paper and "diffdrive" in paper and "Fig. 12" in paper
