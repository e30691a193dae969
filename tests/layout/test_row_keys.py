"""Lint: a results row is read by attribute (`ResultRow`), not by spelling its keys.

The rule, checked with `ast` over engine/, kernels/, plugins/, api/ and docs/results/*.py:
outside engine/outputs/ (the row's floor), no string constant that names a field of
`ResultRow` (``"max_f1"``, ``"environment"``, ...) is a subscript (``row["max_f1"]``) or the
first argument of ``.get``, ``.pop`` or ``.setdefault`` on an expression named ``row`` or
``first``, or on an element of ``rows`` (``rows[0]["tau"]``): the names the package gives a
results row. Other records that share a column name with a row (sensitivity.csv's rows,
sweep.csv's, complementarity.json's) are named otherwise and not results rows; they may
spell their own columns. `EXEMPT` lists the modules that still take results rows as
mappings, each with the reason (some are being rewritten or moved now); the list only shrinks.
"""

from __future__ import annotations

import ast
from pathlib import Path

from vitaplace.engine.outputs.rows import ResultRow

ROOT = Path(__file__).resolve().parents[2]
ROW_KEYS = frozenset(ResultRow.model_fields)
#: the names a results row goes by
ROW_NAMES = frozenset({"row", "first"})
#: modules that still read results rows as mappings, and why
EXEMPT = {
    "engine/study/summary.py": "the summary's input: each row's dump tagged with its seed",
    "engine/evaluation/resample.py": "the block bootstrap of one seed-tagged row of the summary",
    "engine/report/figures.py": "write_pr_bands: the summary's seed-tagged rows (also from study/grid.py)",
    "docs/results/benchmark.py": "the committed `vitaplace difficulty` rows (engine/cli/difficulty.py's)",
}


def _row_name(node: ast.expr) -> bool:
    """Whether ``node`` is how the package names a results row: ``row``, ``first``, ``rows[i]``."""
    if isinstance(node, ast.Name):
        return node.id in ROW_NAMES
    return isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and node.value.id == "rows"


def spelled_keys(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, key) of every row key spelled as a string on a results row in ``tree``."""
    found = []
    for node in ast.walk(tree):
        target, key = None, None
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            target, key = node.value, node.slice.value
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr in ("get", "pop", "setdefault") and node.args
              and isinstance(node.args[0], ast.Constant)):
            target, key = node.func.value, node.args[0].value
        if target is not None and key in ROW_KEYS and _row_name(target):
            found.append((node.lineno, key))
    return found


def scanned() -> list[Path]:
    folders = [ROOT / name for name in ("engine", "kernels", "plugins", "api")]
    files = [p for folder in folders for p in folder.rglob("*.py")] + sorted((ROOT / "docs" / "results").glob("*.py"))
    return [p for p in files if not p.is_relative_to(ROOT / "engine" / "outputs")]


def test_the_rule_finds_a_spelled_key_and_leaves_other_records_alone():
    tree = ast.parse('row["max_f1"]; rows[0].get("tau"); first.setdefault("method", 1); record["max_f1"]; '
                     'row.max_f1; row["seed"]; r["environment"]')
    assert spelled_keys(tree) == [(1, "max_f1"), (1, "tau"), (1, "method")]


def test_no_module_outside_the_rows_floor_spells_a_row_key():
    found = {}
    for path in scanned():
        name = path.relative_to(ROOT).as_posix()
        if name not in EXEMPT and (keys := spelled_keys(ast.parse(path.read_text(), str(path)))):
            found[name] = keys
    assert not found, f"results rows read by key, not by ResultRow's attributes: {found}"
