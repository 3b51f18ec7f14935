"""The goal pipeline's defaults that `pixelswarm goals` offers on its command line, in a module of their
own: every `pixelswarm` command builds that command line, and the pipeline's modules load OpenCV and
SciPy, which most commands never use."""

from __future__ import annotations

TOLERANCE = 1e-4  # stop when the cost of eq. 1 falls by less than this fraction in one iteration
MAX_ITER = 300
RELAX = 1.8  # initial over-relaxation of the Lloyd step (1 = plain Lloyd), see cvt.lloyd()
METHODS = ("cvt", "kmeans")
