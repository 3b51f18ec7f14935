"""The compiled robot core (agent/core/*.pyx) and the simulated bodies' motion (sim/bodies/kinematics.pyx),
built by `pip install -e .` and so by `make run`.

Floating point stays as the source writes it: no fast-math, and no fused multiply-add contraction,
which would round a robot's arithmetic differently on different machines.
"""

import os
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
    "auto_pickle": False,  # nothing compiled is pickled: no __reduce__ code in each class
}

# Cython's own support code (memoryviews above all) in one module every other imports, not a copy in each
SHARED = "agent.core._cython"

modules = [
    Extension(path[:-4].replace("/", "."), [path], extra_compile_args=FLAGS)
    for path in sorted(glob("agent/core/*.pyx") + glob("sim/bodies/*.pyx"))
] + [Extension(SHARED, [SHARED.replace(".", "/") + ".c"], extra_compile_args=FLAGS)]
# One module translated and compiled per core at once: a fresh clone's set-up waits less for the core
JOBS = os.cpu_count() or 1
setup(
    ext_modules=cythonize(modules, compiler_directives=DIRECTIVES, shared_utility_qualified_name=SHARED, nthreads=JOBS),
    options={"build_ext": {"parallel": JOBS}},
)
