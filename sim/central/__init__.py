"""The central engine: every robot in one process through the robot policy, over an in-process link.

The reference a decentralised run is studied against (with or without impairment), and the RVO2-shaped
engine of the ORCA benchmarks. May import sim.outputs and sim.bodies."""
