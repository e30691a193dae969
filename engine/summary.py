"""The summary of several seeds of one scenario, as a paper needs it.

Input: result rows (``results.json`` rows, each tagged with its ``seed``). Every numeric
value of a row is a metric (``recall_at_k`` becomes ``recall@K``); the identity columns, the
evaluation's own settings (``tau``, ``delta``) and values that are missing or not finite (a
``delta_at_max_f1`` of ``None``) are left out, so ``n`` counts the seeds that have the value.

For each environment x method x direction x metric: ``n``, the mean, the sample standard
deviation (``ddof=1``) and the 95 % confidence interval of the mean from Student's t,
``mean ± t(0.975, n-1) * std / sqrt(n)``. For each pair of methods (in scenario order,
``a - b``) per environment x direction x metric: the same statistics of the per-seed
differences over the seeds both methods have (a paired comparison). With ``n = 1`` the
standard deviation and the interval are NaN, written ``n=1`` in the tables.

Files (written atomically): ``sweep-seeds.csv`` (long: one row per seed x environment x
method x direction x metric), ``sweep.csv`` (the summary), ``sweep-diff.csv`` (paired
differences), ``sweep.md`` and ``sweep.tex`` (tables of mean ± std [CI low, CI high]) and
``sweep.json`` (all of it, NaN as null).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from vitaplace.engine.atomic import write_text_atomic

#: columns naming what a result row is about, not metrics
IDENTITY = ("seed", "environment", "method", "direction")
#: settings of the evaluation copied into every row: inputs, not outcomes
SETTINGS = frozenset({"tau", "delta"})
#: confidence level of the intervals
LEVEL = 0.95

SEED_COLUMNS = ("seed", "environment", "method", "direction", "metric", "value")
STAT_COLUMNS = ("n", "mean", "std", "ci_low", "ci_high")
SUMMARY_COLUMNS = ("environment", "method", "direction", "metric", *STAT_COLUMNS)
DIFF_COLUMNS = ("environment", "direction", "metric", "method_a", "method_b", *STAT_COLUMNS)


def _number(value: Any) -> float | None:
    """``value`` as a finite float, or None when it is not a finite number (bools are not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def metrics(row: Mapping[str, Any]) -> dict[str, float]:
    """The finite numeric metrics of one result row, nested mappings flattened
    (``recall_at_k: {"1": r}`` becomes ``recall@1``, any other ``key: {sub: v}`` ``key.sub``)."""
    found: dict[str, float] = {}
    for key, value in row.items():
        if key in IDENTITY or key in SETTINGS:
            continue
        if isinstance(value, Mapping):
            stem = f"{key[: -len('_at_k')]}@" if key.endswith("_at_k") else f"{key}."
            items = [(f"{stem}{sub}", v) for sub, v in value.items()]
        else:
            items = [(key, value)]
        for name, item in items:
            number = _number(item)
            if number is not None:
                found[name] = number
    return found


def seed_rows(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Long format: one row per seed x environment x method x direction x metric, in seed
    order, then in the order of the result rows."""
    long = []
    for row in sorted(rows, key=lambda r: r["seed"]):
        for metric, value in metrics(row).items():
            long.append({**{k: row[k] for k in IDENTITY}, "metric": metric, "value": value})
    return long


def describe(values: Sequence[float]) -> dict[str, float]:
    """n, mean, sample std (ddof=1) and the Student-t 95 % interval of the mean (NaN for n < 2)."""
    x = np.asarray(values, dtype=float)
    n = len(x)
    mean = float(x.mean()) if n else math.nan
    if n < 2:
        return {"n": n, "mean": mean, "std": math.nan, "ci_low": math.nan, "ci_high": math.nan}
    std = float(x.std(ddof=1))
    half = float(stats.t.ppf(0.5 + LEVEL / 2, n - 1)) * std / math.sqrt(n)
    return {"n": n, "mean": mean, "std": std, "ci_low": mean - half, "ci_high": mean + half}


def _grouped(long: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> dict[tuple, dict[int, float]]:
    """``{key values: {seed: value}}`` in order of first appearance."""
    groups: dict[tuple, dict[int, float]] = {}
    for row in long:
        groups.setdefault(tuple(row[k] for k in keys), {})[row["seed"]] = row["value"]
    return groups


def summarise(long: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Statistics over seeds per environment x method x direction x metric."""
    keys = ("environment", "method", "direction", "metric")
    return [
        {**dict(zip(keys, key)), **describe(list(by_seed.values()))} for key, by_seed in _grouped(long, keys).items()
    ]


def paired_differences(long: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Statistics of ``a - b`` per seed for every pair of methods (a before b in the rows'
    order), per environment x direction x metric, over the seeds where both have the value."""
    groups = _grouped(long, ("environment", "direction", "metric", "method"))
    methods = list(dict.fromkeys(row["method"] for row in long))
    cells = list(dict.fromkeys((row["environment"], row["direction"], row["metric"]) for row in long))
    table = []
    for env, direction, metric in cells:
        for i, a in enumerate(methods):
            for b in methods[i + 1 :]:
                va, vb = groups.get((env, direction, metric, a), {}), groups.get((env, direction, metric, b), {})
                seeds = [s for s in va if s in vb]
                if seeds:
                    diffs = [va[s] - vb[s] for s in seeds]
                    table.append({"environment": env, "direction": direction, "metric": metric,
                                  "method_a": a, "method_b": b, **describe(diffs)})
    return table


def _csv(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def cell(row: Mapping[str, Any]) -> str:
    """``mean ± std [low, high]``, or ``mean (n=1)`` where there is no interval."""
    if row["n"] < 2:
        return f"{row['mean']:.3f} (n={row['n']})"
    return f"{row['mean']:.3f} ± {row['std']:.3f} [{row['ci_low']:.3f}, {row['ci_high']:.3f}]"


def _tables(summary: Sequence[Mapping], diffs: Sequence[Mapping]) -> list[tuple[list[str], list[list[str]]]]:
    """(header, body) of the summary table and of the paired-differences table, as text cells."""
    stat = ["n", "mean ± std [95 % CI]"]
    return [
        (["environment", "method", "direction", "metric", *stat],
         [[r["environment"], r["method"], r["direction"], r["metric"], str(r["n"]), cell(r)] for r in summary]),
        (["environment", "direction", "metric", "difference", *stat],
         [[r["environment"], r["direction"], r["metric"], f"{r['method_a']} - {r['method_b']}", str(r["n"]), cell(r)]
          for r in diffs]),
    ]


def markdown(summary: Sequence[Mapping], diffs: Sequence[Mapping], title: str) -> str:
    """sweep.md: the summary table, then the paired differences between methods."""
    lines = [f"# {title}", "", "Mean ± sample standard deviation over seeds [95 % confidence interval of the mean, "
             "Student's t]; n=1: one seed, no interval.", ""]
    for caption, (head, body) in zip(("", "## Paired differences between methods (per seed)"), _tables(summary, diffs)):
        if body:
            lines += [caption, ""] if caption else []
            lines += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
            lines += ["| " + " | ".join(row) + " |" for row in body] + [""]
    return "\n".join(lines)


_TEX = {c: "\\" + c for c in "&%$#_{}"} | {"\\": r"\textbackslash{}", "~": r"\textasciitilde{}", "^": r"\^{}",
                                          "±": r"$\pm$"}


def _tex_row(cells: Sequence[str]) -> str:
    return " & ".join("".join(_TEX.get(ch, ch) for ch in text) for text in cells) + r" \\"


def latex(summary: Sequence[Mapping], diffs: Sequence[Mapping]) -> str:
    """sweep.tex: the same tables as LaTeX tabulars (no package needed)."""
    out = []
    for head, body in _tables(summary, diffs):
        if body:
            out += [r"\begin{tabular}{llllrl}", r"\hline", _tex_row(head), r"\hline", *map(_tex_row, body),
                    r"\hline", r"\end{tabular}", ""]
    return "\n".join(out)


def _json_safe(value: Any) -> Any:
    """NaN and infinities as null (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def write_summary(out: Path, rows: Sequence[Mapping[str, Any]], title: str, info: Mapping[str, Any]) -> dict[str, Any]:
    """Write the six summary files for ``rows`` (seed-tagged result rows) into ``out``;
    ``info`` goes into sweep.json beside them. Returns what sweep.json holds."""
    rows = sorted(rows, key=lambda r: r["seed"])
    long = seed_rows(rows)
    summary, diffs = summarise(long), paired_differences(long)
    write_text_atomic(out / "sweep-seeds.csv", _csv(long, SEED_COLUMNS))
    write_text_atomic(out / "sweep.csv", _csv(summary, SUMMARY_COLUMNS))
    write_text_atomic(out / "sweep-diff.csv", _csv(diffs, DIFF_COLUMNS))
    write_text_atomic(out / "sweep.md", markdown(summary, diffs, title))
    write_text_atomic(out / "sweep.tex", latex(summary, diffs))
    record = {**info, "runs": list(rows), "summary": summary, "differences": diffs}
    write_text_atomic(out / "sweep.json", json.dumps(_json_safe(record), indent=2))
    return record
