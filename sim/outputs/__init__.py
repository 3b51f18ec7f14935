"""The run's outputs: recorder, metrics, run directory, video, plots, MCAP, live view. May import sim.bodies."""
