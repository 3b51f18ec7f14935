"""Studies: a spec's grid of runs, run here or on a Dask cluster, and its report. Runs are
`pixelswarm run` processes, so it imports no other part of sim."""
