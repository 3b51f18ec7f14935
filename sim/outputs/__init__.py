"""What a run leaves behind and shows: the recorder, metrics, run directory, video and plots, MCAP,
the live view. May import sim.bodies."""
