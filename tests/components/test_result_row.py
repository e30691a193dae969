"""`ResultRow`, the schema of a results.json row: every committed results.json parses and dumps
back to its own bytes; each rule of the schema refuses a hand-made bad row in one line naming
the field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vitaplace.engine.outputs.rows import ResultRow, RowError, parse_row

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = sorted((ROOT / "docs" / "results").rglob("results.json"))

#: a row written by hand, every always-present field, the numbers chosen so that a wrong
#: field order, a float written as an int or a dropped null shows in the bytes
ROW = {
    "environment": "E1", "method": "L", "direction": "query-to-reference", "n_queries": 4, "n_references": 5,
    "n_revisit": 3, "tau": 0.3, "max_f1": 0.5, "precision_at_max_f1": 1.0, "recall_at_max_f1": 0.0,
    "delta_at_max_f1": None,
    "auc": 0.25, "auc_method": "average_precision_stepwise", "recall_at_100_precision": 0.0,
    "recall_at_k": {"1": 0.5, "5": 1.0}, "heading_tolerance_deg": None,
    "difficulty": {"nearest_ref_median_m": 0.0, "chance_r1": None},
    "f1_at_e1_threshold": None, "e1_threshold": 2.0,
}
TEXT = json.dumps([ROW], indent=2)


def test_every_committed_results_file_parses_and_dumps_to_its_own_bytes():
    assert len(COMMITTED) >= 40  # the studies' seeds, the benchmark's difficulty run
    kinds = set()
    for path in COMMITTED:
        text = path.read_text()
        rows = [parse_row(row, str(path)) for row in json.loads(text)]
        assert json.dumps([row.dump() for row in rows], indent=2) == text, path
        kinds |= {name for row in rows for name in ("sequence", "fusion", "query_dropout") if getattr(row, name)}
    assert kinds == {"sequence", "fusion", "query_dropout"}  # the optional parts are all among them


def test_a_row_keeps_the_fields_it_was_given_in_the_schemas_order():
    row = parse_row(ROW, "row")
    assert json.dumps([row.dump()], indent=2) == TEXT
    assert row.fusion is None and "fusion" not in row.dump() and row.difficulty.touch_both_share is None
    shuffled = parse_row(dict(reversed(ROW.items())), "row")  # the schema's order, not the input's
    assert list(shuffled.dump()) == list(ROW)
    assert parse_row(row, "row") is row
    assert parse_row({**ROW, "n_queries": 4.0}, "row").n_queries == 4  # a whole float is a count
    split = parse_row({**ROW, "tied_share": 0.5, "tp": 1.25, "fp": 2, "tn": 1}, "row").dump()
    assert (split["tied_share"], split["tp"], split["fp"]) == (0.5, 1.25, 2) and type(split["fp"]) is int


BAD = {
    "a metric as text": ({"auc": "high"}, "field 'auc' is 'high', expected a finite number"),
    "a proportion over 1": ({"max_f1": 1.5}, "field 'max_f1' is 1.5, expected a number in [0, 1]"),
    "a NaN metric": ({"recall_at_100_precision": float("nan")},
                     "field 'recall_at_100_precision' is nan, expected a finite number or null"),
    "a bool as a number": ({"tau": True}, "field 'tau' is True, expected a finite number"),
    "a fraction of a query": ({"n_queries": 2.5},
                              "field 'n_queries' is 2.5, expected a whole number of queries (>= 1)"),
    "no queries": ({"n_queries": 0}, "field 'n_queries' is 0, expected a whole number of queries (>= 1)"),
    "recall@0": ({"recall_at_k": {"0": 0.5}},
                 "field 'recall_at_k' is {'0': 0.5}, expected a mapping from K (1, 5, ...) to a recall, or null"),
    "recall@K as text": ({"recall_at_k": {"5": "x"}}, "field 'recall_at_k.5' is 'x', expected a finite number"),
    "an empty method": ({"method": ""}, "field 'method' is '', expected a non-empty name"),
    "a negative count": ({"tn": -1}, "field 'tn' is -1, expected a whole number (>= 0) or null"),
    "a negative expected count": ({"tp": -1}, "field 'tp' is -1, expected a count (>= 0; fractional where a tie "
                                              "splits it) or null"),
    "a fraction of a true negative": ({"tn": 0.5}, "field 'tn' is 0.5, expected a whole number (>= 0) or null"),
    "a share over 1": ({"difficulty": {"chance_r1": 2.0}},
                       "field 'difficulty.chance_r1' is 2.0, expected a number in [0, 1]"),
    "a fusion without a weight": ({"fusion": {"sigma_vision": 1.0, "sigma_touch": 1.0, "selection_max_f1": 0.5}},
                                  "field 'fusion.weight' is None, expected a finite number"),
    "an unknown field": ({"max_f2": 0.5}, "field 'max_f2' is 0.5, expected no such field (not one of a results row's)"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_row_is_refused_in_one_line_naming_the_field(case):
    change, message = BAD[case]
    with pytest.raises(RowError) as info:
        parse_row({**ROW, **change}, "results.json: row 0")
    assert str(info.value) == f"results.json: row 0: {message}"


def test_a_missing_field_reads_as_null_and_a_row_must_be_a_mapping():
    without = {k: v for k, v in ROW.items() if k != "max_f1"}
    with pytest.raises(RowError, match=r"^r: field 'max_f1' is None, expected a finite number$"):
        parse_row(without, "r")
    with pytest.raises(RowError, match=r"^r: a list, expected a result row \(a JSON object\)$"):
        parse_row([1, 2], "r")


def test_assignment_is_checked_and_kept():
    row = parse_row(ROW, "row")
    row.fusion = {"weight": 0.5, "sigma_vision": 2.0, "sigma_touch": 3.0, "selection_max_f1": 0.75}
    assert list(row.dump())[-3:] == ["fusion", "f1_at_e1_threshold", "e1_threshold"]
    with pytest.raises(ValueError, match="expected a number in"):
        row.max_f1 = -0.5
    assert ResultRow.model_fields["max_f1"].is_required() and not ResultRow.model_fields["fusion"].is_required()
