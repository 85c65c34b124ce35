"""Commands: the CLI, scene runs, sweeps, the Dask cluster, benchmarks, reports, progress bars, the cosseratbench plugin."""
