"""Studies: a spec's grid of runs, run here or on a Dask cluster, and its report. Runs are
`pixelswarm run` processes, so of sim it imports only sim.outputs (atomic writes) and what every layer may."""
