"""Evaluation: place-recognition metrics, statistics over seeds, figures, report.md, aggregation of run folders."""
