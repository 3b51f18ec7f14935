"""A robot's decisions. The per-robot arithmetic is compiled when the project is installed
(agent/core/*.pyx, setup.py); a clone that was never installed stops here with how to build it."""

from importlib.machinery import PathFinder  # loaded with the interpreter, unlike importlib.util

_COMPILED = ("_cython", "bidding", "control", "crew", "grid")  # agent/core/*.pyx and Cython's shared support
if any(PathFinder.find_spec(f"{__name__}.{name}", __path__) is None for name in _COMPILED):
    raise SystemExit(
        "pixelswarm: the compiled robot core (agent/core/*.pyx) is not built: run `make run` or `pip install -e .`"
    )
