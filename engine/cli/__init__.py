"""The command line (`vitaplace ...`) and the drivers of many runs it starts (sweeps, Slurm arrays)."""
