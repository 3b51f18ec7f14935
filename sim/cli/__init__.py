"""The `pixelswarm` command line: its subcommands and their arguments. May import every other part of sim."""

import os

from agent import ONE_BLAS_THREAD

os.environ.setdefault(*ONE_BLAS_THREAD)  # before numpy loads, here and in every process a run starts
