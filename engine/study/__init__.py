"""Across runs: aggregate over seeds, the sensitivity grid, the summary statistics."""
