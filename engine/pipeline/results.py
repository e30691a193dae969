"""The result rows of a run: results.json (everything), results.csv (one row per
environment x method x direction) and complementarity.json (one record per environment x
direction x vision-only / touch-only pair)."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.outputs.outdir import COMPLEMENTARITY, RESULTS_CSV, RESULTS_JSON
from vitaplace.engine.outputs.rows import ResultRow, parse_row

RESULT_COLUMNS = (
    "environment", "method", "direction", "max_f1", "precision_at_max_f1", "recall_at_max_f1",
    "delta_at_max_f1", "auc", "recall_at_100_precision", "f1_at_e1_threshold", "e1_threshold", "delta", "precision",
    "recall", "f1", "n_queries", "n_references", "n_revisit", "tied_share",
)


def csv_row(row: ResultRow) -> ResultRow:
    """A results row for results.csv: without a fixed ``scoring.delta``, delta, precision,
    recall and F1 are those at the max-F1 threshold (instead of empty)."""
    if row.f1 is not None:
        return row
    return row.model_copy(update=dict(delta=row.delta_at_max_f1, precision=row.precision_at_max_f1,
                                      recall=row.recall_at_max_f1, f1=row.max_f1))


def write_results(out: Path, rows: Sequence[ResultRow | Mapping[str, Any]],
                  complementarity: list[dict[str, Any]]) -> None:
    """results.json (everything), results.csv (one row per environment x method x direction;
    `csv_row`: delta, precision, recall, F1 at the fixed delta, else at the max-F1 one) and
    complementarity.json (the records of `stages.compare.pair_complementarity`, a list, empty when no
    pair ran). ``rows``: `ResultRow`s, or mappings `parse_row` reads; results.json holds
    each row's `ResultRow.dump`."""
    parsed = [parse_row(row, f"results row {i}") for i, row in enumerate(rows)]
    write_text_atomic(out / RESULTS_JSON, json.dumps([row.dump() for row in parsed], indent=2))
    write_text_atomic(out / COMPLEMENTARITY, json.dumps(complementarity, indent=2))
    ks = sorted({k for row in parsed for k in row.recall_at_k or {}}, key=int)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*RESULT_COLUMNS, *(f"recall@{k}" for k in ks)])
    for row in parsed:
        filled, recalls = csv_row(row), row.recall_at_k or {}
        writer.writerow([getattr(filled, c) for c in RESULT_COLUMNS] + [recalls.get(k, "") for k in ks])
    write_text_atomic(out / RESULTS_CSV, buffer.getvalue())
