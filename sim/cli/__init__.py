"""The `pixelswarm` command line: its subcommands and their arguments. May import every other part of sim."""

import os

# Set before numpy loads, here and in every process a run starts (they inherit it): our processes keep
# their cores busy with threads of their own, and OpenBLAS's threads would only spin beside them after
# each large product of goal generation. A user's own setting stands.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
