"""Everything that runs a swarm on a machine, in sub-packages by role, each importing only those below it:

cli (the `pixelswarm` command) > study > run (one run's processes) > central (the engine) | node (the
body node) > outputs > bodies (the simulated world); emulators of real robots and a camera stand
apart. args and processes are small helpers any of them may use.
"""
