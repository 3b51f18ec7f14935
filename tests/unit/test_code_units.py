"""Units a reader can hold (docs/conventions.md): outside the compiled kernels, no function runs over
60 lines, and a class keeps at most 15 attributes unless its docstring says why it holds more.
ruff's PLR0913 (pyproject.toml) keeps every function to 8 parameters."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("agent", "coordinator", "transport", "sim", "hardware")
MOST_LINES = 60
MOST_ATTRIBUTES = 15

SOURCES = sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


def attributes(cls: ast.ClassDef) -> set[str]:
    """What an instance of ``cls`` holds: every ``self.name`` its methods assign, and its annotated fields
    (a ClassVar is the class's, not an instance's)."""
    fields = [
        s.target for s in cls.body if isinstance(s, ast.AnnAssign) and "ClassVar" not in ast.unparse(s.annotation)
    ]
    names = {target.id for target in fields if isinstance(target, ast.Name)}
    for node in ast.walk(cls):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            if isinstance(node.value, ast.Name) and node.value.id == "self":
                names.add(node.attr)
    return names


def where(path: Path, node: ast.AST) -> str:
    return f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"


def test_the_packages_have_sources() -> None:
    assert len(SOURCES) > 50  # the scan below reads the project, not an empty folder


@pytest.mark.parametrize("package", PACKAGES)
def test_no_function_runs_over_60_lines(package: str) -> None:
    long = []
    for path in (p for p in SOURCES if p.relative_to(ROOT).parts[0] == package):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                if lines > MOST_LINES:
                    long.append(f"{where(path, node)} {node.name}: {lines} lines")
    assert not long, "\n".join(long)


@pytest.mark.parametrize("package", PACKAGES)
def test_a_class_over_15_attributes_says_why(package: str) -> None:
    unexplained = []
    for path in (p for p in SOURCES if p.relative_to(ROOT).parts[0] == package):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and len(attributes(node)) > MOST_ATTRIBUTES:
                if "attribute" not in (ast.get_docstring(node) or ""):
                    unexplained.append(f"{where(path, node)} {node.name}: {len(attributes(node))} attributes")
    assert not unexplained, "\n".join(unexplained)


def test_the_scan_counts_what_a_class_assigns() -> None:
    """The scan itself: attributes assigned in any method, and dataclass fields, each once."""
    source = "class A:\n    x: int\n    K: ClassVar[int] = 1\n    def __init__(self):\n        self.y = self.x = 0\n    def f(self):\n        self.z = 1\n"
    (cls,) = [n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef)]
    assert attributes(cls) == {"x", "y", "z"}
