"""The compiled robot core (agent/core/*.pyx) and the simulated bodies' motion (sim/bodies/kinematics.pyx),
built by `pip install -e .` and so by `make run`.

Floating point stays as the source writes it: no fast-math, and no fused multiply-add contraction,
which would round a robot's arithmetic differently on different machines.
"""

from glob import glob

from Cython.Build import cythonize
from setuptools import Extension, setup

FLAGS = ["-O3", "-ffp-contract=off", "-fno-fast-math"]
DIRECTIVES = {
    "language_level": 3,
    "boundscheck": False,
    "wraparound": False,
    "cdivision": True,
    "initializedcheck": False,
}

modules = [
    Extension(path[:-4].replace("/", "."), [path], extra_compile_args=FLAGS)
    for path in sorted(glob("agent/core/*.pyx") + glob("sim/bodies/*.pyx"))
]
setup(ext_modules=cythonize(modules, compiler_directives=DIRECTIVES))
