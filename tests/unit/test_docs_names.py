"""The code the pages name exists: every module, class, function or constant of ours that README.md,
BENCHMARKS.md or a page of docs/ names in backticks (`agent.core.params.RobotParams`), and every source
file it names by path (`sim/run/launcher.py`); so do those the packages' comments and docstrings name.
A rename that leaves a page or a comment behind fails here."""

from __future__ import annotations

import importlib
import io
import re
import tokenize
from pathlib import Path

import pytest

from tests.conftest import REPO

PAGES = [REPO / "README.md", REPO / "BENCHMARKS.md", *sorted((REPO / "docs").glob("*.md"))]
PACKAGES = ("agent", "coordinator", "transport", "sim", "hardware")
OURS = ("agent", "coordinator", "transport", "sim", "hardware", "bench", "tests")
FILE_KINDS = ("py", "pyx", "pxd", "md", "toml", "json", "png", "npz", "mcap", "mp4", "txt", "c", "sh")
DOTTED = re.compile(rf"(?<![\w./-])(?:{'|'.join(OURS)})(?:\.[A-Za-z_]\w*)+")
PATH = re.compile(rf"(?<![\w./-])(?:{'|'.join(OURS)})/[\w/.*-]+\.(?:{'|'.join(FILE_KINDS)})\b")


def named(text: str, spans: str = r"`([^`\n]+)`") -> tuple[list[str], list[str]]:
    """The dotted names of ours and the source paths in a page's backticked spans (``spans``); placeholders
    (NAME, DIR) and file names written as dotted names (`runtime.py`) are not names."""
    dotted, paths = [], []
    for span in re.findall(spans, text):
        paths += [p for p in PATH.findall(span) if not re.search(r"/[A-Z]+[./]", p)]
        dotted += [d for d in DOTTED.findall(span) if d.rsplit(".", 1)[1] not in FILE_KINDS]
    return dotted, paths


def resolves(dotted: str) -> bool:
    """The longest importable module prefix, then attributes for the rest."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_the_scan_finds_names_and_paths_and_tells_a_missing_one():
    dotted, paths = named("`agent.core.params.RobotParams` and `sim/run/launcher.py`; `agent.nowhere` `NAME.toml`")
    assert dotted == ["agent.core.params.RobotParams", "agent.nowhere"] and paths == ["sim/run/launcher.py"]
    assert resolves("agent.core.params.RobotParams") and not resolves("agent.nowhere")
    assert not resolves("agent.core.params.NoSuchThing")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_name_a_page_gives_exists(page: Path):
    dotted, paths = named(page.read_text())
    missing = [d for d in dotted if not resolves(d)]
    missing += [p for p in paths if not any(REPO.glob(p))]
    assert not missing, f"{page.relative_to(REPO)} names what the code does not have: {', '.join(missing)}"


def prose(path: Path) -> str:
    """A source file's comments and strings (docstrings among them), each on a line of its own."""
    text = path.read_text()
    if path.suffix != ".py":  # Cython and TOML: comments and triple-quoted strings
        return "\n".join(m.group(0) for m in re.finditer(r'#[^\n]*|"""[\s\S]*?"""', text))
    tokens = tokenize.generate_tokens(io.StringIO(text).readline)
    return "\n".join(t.string for t in tokens if t.type in (tokenize.COMMENT, tokenize.STRING))


@pytest.mark.parametrize("package", PACKAGES)
def test_every_name_a_comment_or_docstring_gives_exists(package: str):
    sources = [p for p in sorted((REPO / package).rglob("*")) if p.suffix in (".py", ".pyx", ".pxd", ".toml")]
    missing = []
    for path in sources:
        dotted, paths = named(prose(path), spans=r"([^\n]+)")
        missing += [f"{path.relative_to(REPO)}: {d}" for d in dotted if not resolves(d)]
        missing += [f"{path.relative_to(REPO)}: {p}" for p in paths if not any(REPO.glob(p))]
    assert sources and not missing, "comments name what the code does not have: " + ", ".join(missing)
