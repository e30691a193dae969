"""One run's report: report.md and its figures, rendered from the output folder alone."""
