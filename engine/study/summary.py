"""The summary of several seeds of one scenario, as a paper needs it.

Input: result rows (``results.json`` rows, each tagged with its ``seed``) and, where they
exist, the run folders whose ``evaluations/ENV/METHOD/DIRECTION/matrices.npz`` they came
from. Each numeric value of a row is one of two kinds (`kind`):

* a **metric** scores a method: max F1, precision and recall there, AUC,
  ``recall_at_100_precision``, recall@K (``recall_at_k: {"1": r}`` becomes ``recall@1``),
  F1/precision/recall at a fixed ``delta``, ``f1_at_e1_threshold``, and any numeric key not
  listed below. The metrics in `UNIT_METRICS` (and every ``recall@K``) are proportions in
  [0, 1]; their intervals are kept inside [0, 1] and those of their differences inside
  [-1, 1] (`bounds`); other metrics are unbounded;
* a **descriptor** says what a method was evaluated on or where it operated: the sample
  counts, the threshold ``delta_at_max_f1`` and the drive's ``difficulty.*`` measures
  (`DESCRIPTORS`). Descriptors are summarised per method (n, mean, std, min, max over
  seeds), never given intervals and never differenced between methods.

A row whose ``n_revisit`` is 0 (no query of its drive has a true match within ``tau``) has
no score to give: recall divides by the revisits, so F1, recall, AUC, recall@K and the rest
are conventions (0; precision 1 where nothing is accepted), not measurements
(`vitaplace.engine.evaluation.evaluate`). Its metrics are **left out** of every statistic
over seeds and of the paired differences (`left_out`); ``n`` counts the seeds that are left
and ``n_no_revisit`` those left out, which the tables show beside the mean
(``0.667 (1 of 2 seeds; 1 without revisits)``) and list by seed under "Seeds without
revisits". Its descriptors (sample counts, difficulty) are kept.

Nested mappings are flattened with dots (``difficulty: {"a": {"b": x}}`` becomes
``difficulty.a.b``); text, lists, booleans, nulls and non-finite numbers are skipped, so
``n`` counts the seeds that have a finite value. The identity columns and the evaluation's
settings (``tau``, ``delta``) are not values.

Per environment x method x direction x metric, over the seeds (`describe`):

* ``n``, ``mean``, ``std`` (sample, ``ddof=1``), ``min``, ``max``;
* ``t_low``/``t_high``: Student's t interval of the mean, ``mean ± t(0.975, n-1) std/√n``,
  cut to the metric's bounds;
* ``boot_low``/``boot_high``: the percentile bootstrap interval of the mean over seeds
  (`scipy.stats.bootstrap`, `SEED_RESAMPLES` resamples, generator seed `BOOT_SEED`),
  inside the range of the values and so inside the bounds;
* ``block_low``/``block_high``: the within-seed block bootstrap over contiguous query
  segments (`vitaplace.engine.evaluation.resample`): replicate r of the mean is the mean over seeds of
  each seed's replicate r; its 2.5 and 97.5 percentiles. With one seed it is that seed's
  interval. Only for metrics `evaluate` recomputes from the saved matrices and only where
  every seed's matrices are there (NaN otherwise).

Per pair of methods ``a - b`` (scenario order) x environment x direction x metric, over the
seeds both have (a paired comparison, `paired_differences`): the same statistics of the
per-seed differences (block replicates differenced replicate by replicate: both methods
draw the same query segments) and ``p_sign_flip``, the exact two-sided sign-flip
permutation p-value of the mean difference: all 2**n sign patterns of the n differences
(`scipy.stats.permutation_test`, ``permutation_type="samples"``), p = the share of patterns
whose mean is at least as far from 0 as the observed one.

With n = 1 the standard deviation, t and bootstrap intervals are NaN and the tables say
``n=1``. Files (written atomically): ``sweep-seeds.csv`` (long: one row per seed x
environment x method x direction x value, with its block interval), ``sweep.csv`` (the
summary, both kinds), ``sweep-diff.csv`` (paired differences of metrics), ``sweep.md`` and
``sweep.tex`` (the tables), ``sweep.json`` (all of it and the definitions, NaN as null).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.evaluation import resample
from vitaplace.engine.pipeline.processes import interrupts_to_this_process, stop_pool, worker_pool

#: columns naming what a result row is about, not values
IDENTITY = ("seed", "environment", "method", "direction")
#: settings of the evaluation copied into every row: inputs, not outcomes
SETTINGS = frozenset({"tau", "delta", "heading_tolerance_deg", "sequence"})
#: metrics that are proportions in [0, 1] (and every ``recall@K``)
UNIT_METRICS = frozenset({"max_f1", "precision_at_max_f1", "recall_at_max_f1", "auc", "recall_at_100_precision",
                          "precision", "recall", "f1", "f1_at_e1_threshold"})
#: values that describe the evaluation, not the method's score: sample counts and thresholds
DESCRIPTORS = frozenset({"n_queries", "n_references", "n_revisit", "n_accepted", "tp", "fp", "fn", "tn",
                         "delta_at_max_f1", "e1_threshold", "tied_share"})
#: nested objects whose every value is a descriptor (``difficulty.<measure>``, a fusion's chosen ``fusion.weight``)
DESCRIPTOR_GROUPS = ("difficulty", "fusion")
#: confidence level of the intervals
LEVEL = 0.95
#: resamples of the bootstrap over seeds, and the seed of its generator
SEED_RESAMPLES = 9999
BOOT_SEED = 0

SEED_COLUMNS = ("seed", "environment", "method", "direction", "metric", "kind", "value", "no_revisit", "block_low",
                "block_high", "block_length")
INTERVAL_COLUMNS = ("t_low", "t_high", "boot_low", "boot_high", "block_low", "block_high")
STAT_COLUMNS = ("n", "n_no_revisit", "mean", "std", "min", "max", *INTERVAL_COLUMNS)
SUMMARY_COLUMNS = ("environment", "method", "direction", "metric", "kind", *STAT_COLUMNS)
#: the files `write_summary` writes
SUMMARY_FILES = ("sweep-seeds.csv", "sweep.csv", "sweep-diff.csv", "sweep.md", "sweep.tex", "sweep.json")
DIFF_COLUMNS = ("environment", "direction", "metric", "method_a", "method_b", *STAT_COLUMNS, "p_sign_flip")

#: what sweep.json says about how its numbers were made
DEFINITIONS = {
    "level": LEVEL,
    "std": "sample standard deviation over seeds (ddof=1)",
    "t": "Student's t interval of the mean over seeds, cut to the metric's bounds",
    "boot": f"percentile bootstrap of the mean over seeds (scipy.stats.bootstrap, {SEED_RESAMPLES} resamples, "
            f"seed {BOOT_SEED})",
    "block": "percentile interval of the mean over seeds of a within-seed block bootstrap: ceil(n_queries / L) "
             "contiguous query segments of L = ceil(sqrt(n_queries)) queries drawn with replacement",
    "p_sign_flip": "exact two-sided sign-flip permutation p-value of the mean paired difference (all 2**n sign "
                   "patterns, scipy.stats.permutation_test)",
    "bounds": "metrics in [0, 1]: " + ", ".join(sorted(UNIT_METRICS)) + ", recall@K; their differences in [-1, 1]",
    "descriptors": "per method only, never differenced: " + ", ".join(sorted(DESCRIPTORS))
                   + ", " + ", ".join(f"{g}.*" for g in DESCRIPTOR_GROUPS),
    "n_no_revisit": "seeds whose drive has no revisit (n_revisit 0): their metrics are undefined (0 by convention) "
                    "and left out of n, the means, the intervals and the differences",
}

log = logging.getLogger("vitaplace")

#: ``{(seed, environment, method, direction): {metric: block-bootstrap replicates}}``
Replicates = dict[tuple, dict[str, np.ndarray]]


def _number(value: Any) -> float | None:
    """``value`` as a finite float, or None when it is not a finite number (bools are not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _flatten(name: str, value: Any) -> Iterator[tuple[str, float]]:
    if isinstance(value, Mapping):
        for sub, item in value.items():
            yield from _flatten(f"{name}.{sub}", item)
    elif (number := _number(value)) is not None:
        yield name, number


def row_values(row: Mapping[str, Any]) -> dict[str, float]:
    """The finite numeric values of one result row, nested mappings flattened with dots
    (``recall_at_k: {"1": r}`` becomes ``recall@1``)."""
    found: dict[str, float] = {}
    for key, value in row.items():
        if key in IDENTITY or key in SETTINGS:
            continue
        if key == "recall_at_k" and isinstance(value, Mapping):
            found.update(pair for sub, v in value.items() for pair in _flatten(f"recall@{sub}", v))
        else:
            found.update(_flatten(key, value))
    return found


def no_revisit(row: Mapping[str, Any]) -> bool:
    """Whether a result row's drive has no revisit (``n_revisit`` 0): its scores are undefined."""
    return row.get("n_revisit") == 0


def left_out(value: Mapping[str, Any]) -> bool:
    """Whether a `seed_rows` value is left out of the statistics: a metric of a drive without revisits."""
    return bool(value["no_revisit"]) and value["kind"] == "metric"


def kind(name: str) -> str:
    """``descriptor`` for sample counts, thresholds and ``difficulty.*``; else ``metric``."""
    if name in DESCRIPTORS or name.split(".", 1)[0] in DESCRIPTOR_GROUPS:
        return "descriptor"
    return "metric"


def bounds(metric: str) -> tuple[float, float]:
    """The range a metric's values lie in: [0, 1] for proportions, else unbounded."""
    return (0.0, 1.0) if metric in UNIT_METRICS or metric.startswith("recall@") else (-math.inf, math.inf)


def _clip(low: float, high: float, limits: tuple[float, float]) -> tuple[float, float]:
    return float(np.clip(low, *limits)), float(np.clip(high, *limits))


def percentile_interval(replicates: np.ndarray,
                        limits: tuple[float, float] = (-math.inf, math.inf)) -> tuple[float, float]:
    """The (1 - LEVEL)/2 and (1 + LEVEL)/2 quantiles of bootstrap replicates, inside ``limits``."""
    low, high = np.quantile(replicates, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return _clip(low, high, limits)


def difference_bounds(metric: str) -> tuple[float, float]:
    """The range of a difference of two values of ``metric``: [-1, 1] for proportions."""
    low, high = bounds(metric)
    return low - high, high - low


def spread(values: Sequence[float]) -> dict[str, float]:
    """n, mean, std (ddof=1; NaN for n < 2), min and max of ``values`` (NaN but n for none)."""
    x = np.asarray(values, dtype=float)
    n = len(x)
    if n == 0:
        return {"n": 0, "mean": math.nan, "std": math.nan, "min": math.nan, "max": math.nan}
    return {"n": n, "mean": float(x.mean()), "std": float(x.std(ddof=1)) if n >= 2 else math.nan,
            "min": float(x.min()), "max": float(x.max())}


def t_interval(values: Sequence[float], level: float = LEVEL,
               limits: tuple[float, float] = (-math.inf, math.inf)) -> tuple[float, float]:
    """Student's t ``level`` interval of the mean, ``mean ± t((1 + level) / 2, n - 1) std/√n``,
    inside ``limits``; NaN for n < 2 (the std is)."""
    s = spread(values)
    half = float(stats.t.ppf(0.5 + level / 2, s["n"] - 1)) * s["std"] / math.sqrt(s["n"])
    return _clip(s["mean"] - half, s["mean"] + half, limits)


def describe(values: Sequence[float], limits: tuple[float, float] = (-math.inf, math.inf),
             block: np.ndarray | None = None) -> dict[str, float]:
    """`spread`, then the Student-t (`t_interval`) and percentile-bootstrap intervals of the
    mean inside ``limits`` (NaN for n < 2) and the percentile interval of the block
    replicates of the mean ``block`` (NaN when None)."""
    out = {**spread(values), **dict.fromkeys(INTERVAL_COLUMNS, math.nan)}
    n, x = out["n"], np.asarray(values, dtype=float)
    if n >= 2:
        out["t_low"], out["t_high"] = t_interval(values, LEVEL, limits)
        boot = stats.bootstrap((x,), np.mean, n_resamples=SEED_RESAMPLES, confidence_level=LEVEL,
                               method="percentile", random_state=np.random.default_rng(BOOT_SEED))
        # every resample's mean lies within the values' range; its float sum may not (n equal
        # values gave a low bound one ulp above the high one)
        inside = (max(limits[0], float(x.min())), min(limits[1], float(x.max())))
        boot_low, boot_high = boot.confidence_interval
        out["boot_low"], out["boot_high"] = _clip(boot_low, boot_high, inside)
    if block is not None:
        out["block_low"], out["block_high"] = percentile_interval(block, limits)
    return out


def sign_flip_p(differences: Sequence[float]) -> float:
    """Exact two-sided sign-flip permutation p-value of the mean of paired differences: every
    one of the 2**n sign patterns is enumerated."""
    d = np.asarray(differences, dtype=float)
    if len(d) == 0:
        return math.nan
    if len(d) < 2:  # scipy needs two; with one, both signs are as extreme as the observed
        return 1.0
    test = stats.permutation_test((d,), np.mean, permutation_type="samples", n_resamples=np.inf,
                                  alternative="two-sided")
    return float(test.pvalue)


def block_replicates(rows: Sequence[Mapping[str, Any]], folders: Mapping[int, Path], workers: int = 1) -> Replicates:
    """``{(seed, environment, method, direction): {metric: replicates}}`` of the within-seed
    block bootstrap, for the rows whose run folder has the evaluation's saved matrices. With
    more than one of ``workers`` and seeds, one seed per task on that many worker processes: a
    row's replicates depend on its seed and its matrices alone, so the result is the same."""
    by_seed: dict[int, list[Mapping[str, Any]]] = {}
    for row in rows:
        if row["seed"] in folders:
            by_seed.setdefault(row["seed"], []).append(row)
    tasks = [(folders[seed], seed_rows) for seed, seed_rows in by_seed.items()]
    workers = min(workers, len(tasks))
    if workers <= 1:
        parts = [_seed_block_replicates(folder, seed_rows) for folder, seed_rows in tasks]
    else:
        pool = worker_pool(workers, blas_threads=1)
        try:
            with interrupts_to_this_process():
                futures = [pool.submit(_seed_block_replicates, folder, seed_rows) for folder, seed_rows in tasks]
            parts = [future.result() for future in futures]
        except KeyboardInterrupt:
            stop_pool(pool)
            raise
        finally:
            pool.shutdown(cancel_futures=True)
    return {identity: values for part in parts for identity, values in part.items()}


def _seed_block_replicates(folder: Path, rows: Sequence[Mapping[str, Any]]) -> Replicates:
    """`block_replicates` of the rows of one seed, whose run folder is ``folder``."""
    found: Replicates = {}
    for row in rows:
        replicates = resample.evaluation_replicates(folder, row)
        if replicates is None:
            continue
        values = [row_values(r) for r in replicates]
        found[tuple(row[k] for k in IDENTITY)] = {
            name: np.array([v[name] for v in values]) for name in values[0] if kind(name) == "metric"
        }
    return found


def seed_rows(rows: Sequence[Mapping[str, Any]], replicates: Replicates | None = None) -> list[dict[str, Any]]:
    """Long format: one row per seed x environment x method x direction x value, in seed
    order, then in the order of the result rows, with whether its drive has no revisit
    (`no_revisit`), the seed's block interval and the block length it used (NaN where the
    evaluation's matrices are not there, and for a value `left_out`)."""
    replicates = replicates or {}
    long = []
    for row in sorted(rows, key=lambda r: r["seed"]):
        identity = {k: row[k] for k in IDENTITY}
        for name, value in row_values(row).items():
            entry = {**identity, "metric": name, "kind": kind(name), "value": value, "no_revisit": no_revisit(row),
                     "block_low": math.nan, "block_high": math.nan, "block_length": math.nan}
            block = replicates.get(tuple(identity.values()), {}).get(name)
            if block is not None and not left_out(entry):
                entry["block_low"], entry["block_high"] = percentile_interval(block, bounds(name))
                entry["block_length"] = resample.block_length(row["n_queries"])
            long.append(entry)
    return long


def _grouped(long: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> dict[tuple, dict[int, float | None]]:
    """``{key values: {seed: value}}`` in order of first appearance; None for a value `left_out`."""
    groups: dict[tuple, dict[int, float | None]] = {}
    for row in long:
        groups.setdefault(tuple(row[k] for k in keys), {})[row["seed"]] = None if left_out(row) else row["value"]
    return groups


def _defined(by_seed: Mapping[int, float | None]) -> dict[int, float]:
    """``by_seed`` without the values left out."""
    return {s: v for s, v in by_seed.items() if v is not None}


def _mean_replicates(replicates: Replicates, cells: Sequence[tuple], metric: str) -> np.ndarray | None:
    """Replicate by replicate, the mean over ``cells`` (seed, environment, method, direction)
    of their block replicates of ``metric``; None unless every cell has them."""
    arrays = [replicates.get(cell, {}).get(metric) for cell in cells]
    found = [a for a in arrays if a is not None]
    return None if not arrays or len(found) < len(arrays) else np.mean(found, axis=0)


def summarise(long: Sequence[Mapping[str, Any]], replicates: Replicates | None = None) -> list[dict[str, Any]]:
    """Statistics over seeds per environment x method x direction x value (`describe`) of the
    values not `left_out` (``n_no_revisit``: how many were); descriptors get n, mean, std,
    min and max only."""
    replicates = replicates or {}
    keys = ("environment", "method", "direction", "metric")
    table = []
    for key, by_seed in _grouped(long, keys).items():
        env, method, direction, name = key
        defined = _defined(by_seed)
        if kind(name) == "metric":
            block = _mean_replicates(replicates, [(s, env, method, direction) for s in defined], name)
            described = describe(list(defined.values()), bounds(name), block)
        else:
            described = {**dict.fromkeys(STAT_COLUMNS, math.nan), **spread(list(defined.values()))}
        table.append({**dict(zip(keys, key, strict=True)), "kind": kind(name), **described,
                      "n_no_revisit": len(by_seed) - len(defined)})
    return table


def paired_differences(long: Sequence[Mapping[str, Any]], replicates: Replicates | None = None) -> list[dict[str, Any]]:
    """Statistics of ``a - b`` per seed for every pair of methods (a before b in the rows'
    order), per environment x direction x metric, over the seeds where both have the value
    and neither is `left_out` (``n_no_revisit``: the seeds where one was), with the exact
    sign-flip p-value (NaN without a seed). Descriptors are not compared."""
    replicates = replicates or {}
    long = [row for row in long if row["kind"] == "metric"]
    groups = _grouped(long, ("environment", "direction", "metric", "method"))
    methods = list(dict.fromkeys(row["method"] for row in long))
    cells = list(dict.fromkeys((row["environment"], row["direction"], row["metric"]) for row in long))
    table = []
    for env, direction, metric in cells:
        for i, a in enumerate(methods):
            for b in methods[i + 1 :]:
                va, vb = groups.get((env, direction, metric, a), {}), groups.get((env, direction, metric, b), {})
                both = {s: (va[s], vb[s]) for s in va if s in vb}
                if not both:
                    continue
                defined = {s: x - y for s, (x, y) in both.items() if x is not None and y is not None}
                seeds, diffs = list(defined), list(defined.values())
                ra = _mean_replicates(replicates, [(s, env, a, direction) for s in seeds], metric)
                rb = _mean_replicates(replicates, [(s, env, b, direction) for s in seeds], metric)
                block = ra - rb if ra is not None and rb is not None else None
                table.append({"environment": env, "direction": direction, "metric": metric, "method_a": a,
                              "method_b": b, **describe(diffs, difference_bounds(metric), block),
                              "n_no_revisit": len(both) - len(seeds), "p_sign_flip": sign_flip_p(diffs)})
    return table


def csv_text(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> str:
    """``rows`` as CSV text with a header of ``columns``."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def cell(row: Mapping[str, Any]) -> str:
    """``mean ± std``, or ``mean (n=1)`` where there is no spread; where seeds without
    revisits were left out (``n_no_revisit``), ``mean ± std (n of N seeds; k without revisits)``
    (``–`` for the mean of none)."""
    n, without = row["n"], row.get("n_no_revisit", 0)
    if not without:
        return f"{row['mean']:.3f} (n={n})" if n < 2 else f"{row['mean']:.3f} ± {row['std']:.3f}"
    mean = "–" if n == 0 else f"{row['mean']:.3f}" + (f" ± {row['std']:.3f}" if n >= 2 else "")
    return f"{mean} ({n} of {n + without} seeds; {without} without revisits)"


def interval(row: Mapping[str, Any], name: str) -> str:
    """``[low, high]`` of the interval ``name`` (t, boot, block), ``–`` where there is none."""
    low, high = row[f"{name}_low"], row[f"{name}_high"]
    return "–" if math.isnan(low) else f"[{low:.3f}, {high:.3f}]"


#: the header of `stat_cells`
STAT_HEADER = ("n", "mean ± std", "t 95 %", "bootstrap 95 %", "block 95 %")


def stat_cells(row: Mapping[str, Any]) -> list[str]:
    """A summary row's n, mean ± std and its three intervals, as table cells."""
    return [str(row["n"]), cell(row), interval(row, "t"), interval(row, "boot"), interval(row, "block")]


def without_revisits(long: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The drives without revisits: one entry per seed x environment x direction whose result
    rows have ``n_revisit`` 0 (`seed_rows`' ``no_revisit``), with those rows' methods, in
    the order of ``long``."""
    found: dict[tuple, list[str]] = {}
    for row in long:
        if row["no_revisit"]:
            methods = found.setdefault((row["seed"], row["environment"], row["direction"]), [])
            methods += [] if row["method"] in methods else [row["method"]]
    return [{"seed": seed, "environment": env, "direction": direction, "methods": methods}
            for (seed, env, direction), methods in found.items()]


def _tables(summary: Sequence[Mapping], diffs: Sequence[Mapping],
            missing: Sequence[Mapping] = ()) -> list[tuple[str, list[str], list[list[str]]]]:
    """(caption, header, body) of the metrics, the paired differences, the descriptors and the
    drives without revisits (``missing``, `without_revisits`) tables, as text cells."""
    metric_rows = [r for r in summary if r["kind"] == "metric"]
    descriptor_rows = [r for r in summary if r["kind"] == "descriptor"]
    return [
        ("Metrics over seeds",
         ["environment", "method", "direction", "metric", *STAT_HEADER],
         [[r["environment"], r["method"], r["direction"], r["metric"], *stat_cells(r)] for r in metric_rows]),
        ("Paired differences between methods (per seed, a - b)",
         ["environment", "direction", "metric", "difference", *STAT_HEADER, "p (sign flip)"],
         [[r["environment"], r["direction"], r["metric"], f"{r['method_a']} - {r['method_b']}", *stat_cells(r),
           f"{r['p_sign_flip']:.3g}"] for r in diffs]),
        ("Per method, not compared: sample counts, thresholds, drive difficulty",
         ["environment", "method", "direction", "value", "n", "mean", "min", "max"],
         [[r["environment"], r["method"], r["direction"], r["metric"], str(r["n"]),
           *(f"{r[k]:.4g}" for k in ("mean", "min", "max"))] for r in descriptor_rows]),
        ("Seeds without revisits: no query has a true match, so their scores are undefined (0 by convention) and "
         "left out above",
         ["seed", "environment", "direction", "methods"],
         [[str(m["seed"]), m["environment"], m["direction"], ", ".join(m["methods"])] for m in missing]),
    ]


LEGEND = (
    "Mean ± sample standard deviation over seeds; 95 % intervals of the mean: Student's t (cut to the metric's "
    "range), percentile bootstrap over seeds, and block bootstrap over contiguous query segments within each seed "
    "(the query drive's share of the uncertainty; the only interval a single seed has). Proportions (F1, precision, "
    "recall, AUC) stay in [0, 1], their differences in [-1, 1]. A seed whose drive has no revisit has no score and is "
    "left out: \"(1 of 2 seeds; 1 without revisits)\". p: exact two-sided sign-flip permutation test of "
    "the mean paired difference (all 2^n sign patterns of n seeds; its smallest value is 2/2^n). n=1: one seed; "
    "–: no such interval. Definitions: docs/SCALE.md, \"The summary\"."
)


def markdown(summary: Sequence[Mapping], diffs: Sequence[Mapping], title: str,
             missing: Sequence[Mapping] = ()) -> str:
    """sweep.md: the metrics, the paired differences between methods, the descriptors, the
    drives without revisits (``missing``, `without_revisits`)."""
    lines = [f"# {title}", "", LEGEND, ""]
    for caption, head, body in _tables(summary, diffs, missing):
        if body:
            lines += [f"## {caption}", "", "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
            lines += ["| " + " | ".join(row) + " |" for row in body] + [""]
    return "\n".join(lines)


_TEX = {c: "\\" + c for c in "&%$#_{}"} | {"\\": r"\textbackslash{}", "~": r"\textasciitilde{}", "^": r"\^{}",
                                          "±": r"$\pm$", "–": "--"}


def _tex(text: str) -> str:
    return "".join(_TEX.get(ch, ch) for ch in text)


def _tex_row(cells: Sequence[str]) -> str:
    return " & ".join(map(_tex, cells)) + r" \\"


def latex(summary: Sequence[Mapping], diffs: Sequence[Mapping], missing: Sequence[Mapping] = ()) -> str:
    """sweep.tex: the same tables as LaTeX tabulars (no package needed), each under its caption."""
    out = [f"% {_tex(LEGEND)}", ""]
    for caption, head, body in _tables(summary, diffs, missing):
        if body:
            out += [f"% {_tex(caption)}", rf"\begin{{tabular}}{{{'l' * len(head)}}}", r"\hline", _tex_row(head),
                    r"\hline", *map(_tex_row, body), r"\hline", r"\end{tabular}", ""]
    return "\n".join(out)


def json_safe(value: Any) -> Any:
    """NaN and infinities as null (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def write_summary(out: Path, rows: Sequence[Mapping[str, Any]], title: str, info: Mapping[str, Any],
                  folders: Mapping[int, Path] | None = None, workers: int = 1) -> dict[str, Any]:
    """Write the six summary files for ``rows`` (seed-tagged result rows) into ``out``;
    ``folders`` (seed -> run folder) give the saved matrices for the block bootstrap, computed
    on ``workers`` processes (`block_replicates`);
    ``info`` goes into sweep.json beside them. Each drive without revisits is also a warning
    on the console. Returns what sweep.json holds."""
    rows = sorted(rows, key=lambda r: r["seed"])
    replicates = block_replicates(rows, folders or {}, workers)
    long = seed_rows(rows, replicates)
    summary, diffs, missing = summarise(long, replicates), paired_differences(long, replicates), without_revisits(long)
    for m in missing:
        log.warning("%s: seed %s, %s %s: no revisit (no query has a true match within tau); its scores are "
                    "undefined and left out of the summary", title, m["seed"], m["environment"], m["direction"])
    write_text_atomic(out / "sweep-seeds.csv", csv_text(long, SEED_COLUMNS))
    write_text_atomic(out / "sweep.csv", csv_text(summary, SUMMARY_COLUMNS))
    write_text_atomic(out / "sweep-diff.csv", csv_text(diffs, DIFF_COLUMNS))
    write_text_atomic(out / "sweep.md", markdown(summary, diffs, title, missing))
    write_text_atomic(out / "sweep.tex", latex(summary, diffs, missing))
    definitions = {**DEFINITIONS, "block_resamples": resample.RESAMPLES}
    record = {**info, "statistics": definitions, "runs": list(rows), "values": long, "summary": summary,
              "differences": diffs, "without_revisits": missing}
    write_text_atomic(out / "sweep.json", json.dumps(json_safe(record), indent=2))
    return record
