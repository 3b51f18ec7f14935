"""Every benchmark in bench/ imports as a user would run it (a module renamed elsewhere in the tree
breaks a benchmark only when someone next runs it, which may be months later) and says how to run it."""

from __future__ import annotations

import importlib

import pytest

from tests.conftest import REPO

MODULES = sorted(p.stem for p in (REPO / "bench").glob("*.py") if p.stem not in ("__init__", "common"))


@pytest.mark.parametrize("name", MODULES)
def test_a_benchmark_imports_and_says_how_to_run_it(name):
    module = importlib.import_module(f"bench.{name}")
    doc = module.__doc__ or ""
    assert f"python -m bench.{name}" in doc or f"bench/{name}.py" in doc, (
        f"bench/{name}.py: no command line in its docstring"
    )


def test_the_neighbour_timings_run_on_this_tree():
    """bench_world --neighbours runs its timings as a script, in a fresh process per tree: an API it calls that
    changed shows only when the script runs (``gather`` took a Sensed long before anyone noticed)."""
    from bench.bench_world import neighbour_timings

    figures = neighbour_timings(REPO, 1)
    assert len(figures) == 10 and all(ms > 0 for ms in figures.values()), figures
