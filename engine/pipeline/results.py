"""The result rows of a run: results.json (everything), results.csv (one row per
environment x method x direction) and complementarity.json (one record per environment x
direction x vision-only / touch-only pair)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.outputs.outdir import COMPLEMENTARITY, RESULTS_CSV, RESULTS_JSON


RESULT_COLUMNS = (
    "environment", "method", "direction", "max_f1", "precision_at_max_f1", "recall_at_max_f1",
    "delta_at_max_f1", "auc", "recall_at_100_precision", "f1_at_e1_threshold", "e1_threshold", "delta", "precision",
    "recall", "f1", "n_queries", "n_references", "n_revisit",
)


def csv_row(row: dict[str, Any]) -> dict[str, Any]:
    """A results row for results.csv: without a fixed ``scoring.delta``, delta, precision,
    recall and F1 are those at the max-F1 threshold (instead of empty)."""
    if row.get("f1") is not None:
        return row
    return {**row, "delta": row["delta_at_max_f1"], "precision": row["precision_at_max_f1"],
            "recall": row["recall_at_max_f1"], "f1": row["max_f1"]}


def write_results(out: Path, rows: list[dict[str, Any]], complementarity: list[dict[str, Any]]) -> None:
    """results.json (everything), results.csv (one row per environment x method x direction;
    `csv_row`: delta, precision, recall, F1 at the fixed delta, else at the max-F1 one) and
    complementarity.json (the records of `Pipeline.complementarity`, a list, empty when no
    pair ran)."""
    write_text_atomic(out / RESULTS_JSON, json.dumps(rows, indent=2))
    write_text_atomic(out / COMPLEMENTARITY, json.dumps(complementarity, indent=2))
    ks = sorted({k for row in rows for k in row.get("recall_at_k", {})}, key=int)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*RESULT_COLUMNS, *(f"recall@{k}" for k in ks)])
    for row in rows:
        filled = csv_row(row)
        writer.writerow([filled.get(c, "") for c in RESULT_COLUMNS] + [row["recall_at_k"].get(k, "") for k in ks])
    write_text_atomic(out / RESULTS_CSV, buffer.getvalue())
