"""The goal pipeline's defaults for `pixelswarm goals`'s command line, apart from the OpenCV pipeline."""

from __future__ import annotations

TOLERANCE = 1e-4  # stop when the cost of eq. 1 falls by less than this fraction in one iteration
MAX_ITER = 300
RELAX = 1.8  # initial over-relaxation of the Lloyd step (1 = plain Lloyd), see cvt.lloyd()
METHODS = ("cvt", "kmeans")
