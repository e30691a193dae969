"""What the evaluate stage reads across evaluations once every one is scored: each row's F1
at the threshold chosen on the training world's evaluation, the complementarity of each
vision-only / touch-only pair, and warnings about evaluations with too few revisits."""

from __future__ import annotations

from typing import Any

import numpy as np

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.config.methods import complementarity_pairs
from vitaplace.engine.config.scenario import Scenario, training_world_evaluation
from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation.complementarity import complementarity
from vitaplace.engine.evaluation.pairfiles import load_curve, load_decisions
from vitaplace.engine.extension.features import warn_once
from vitaplace.engine.outputs import outdir
from vitaplace.engine.outputs.rows import ResultRow
from vitaplace.engine.pipeline.records import EvaluateRecord, SimulateRecord
from vitaplace.engine.pipeline.store import Store

#: an evaluation with fewer queries that have a true match is warned about: below 10, one
#: query's decision moves recall by more than 10 points, too coarse to compare methods by
MIN_REVISITS = 10


def compare(store: Store, scenario: Scenario, simulated: SimulateRecord, evaluated: EvaluateRecord) -> EvaluateRecord:
    """``evaluated`` with `f1_at_training_threshold` in every row, the complementarity records,
    and the few-revisits warnings raised (`warn_few_revisits`)."""
    rows = f1_at_training_threshold(store, scenario, evaluated.rows)
    warn_few_revisits(store, simulated, rows)
    return EvaluateRecord(rows, evaluated.folders, evaluated.files, pair_complementarity(store, scenario))


def f1_at_training_threshold(store: Store, scenario: Scenario, rows: list[ResultRow]) -> list[ResultRow]:
    """The rows with ``f1_at_e1_threshold``: F1 at the threshold that maximised the same
    method's F1 (same direction) on the training world's evaluation
    (`training_world_evaluation`), applied unchanged, and that threshold, ``e1_threshold``
    (None when it is -inf: accept nothing); both None when there is no such evaluation, or
    when its direction has no query with a true match (its max F1 is undefined, 0 by
    convention: its threshold is no training world's choice)."""
    source, _ = training_world_evaluation(scenario)
    revisits = {(row.environment, row.method, row.direction): row.n_revisit for row in rows}
    completed = []
    for row in rows:
        f1, threshold = None, None
        if source is not None and revisits.get((source, row.method, row.direction)):
            curve = load_curve(outdir.evaluation_dir(store.out, source, row.method, row.direction) / outdir.PR_CURVE)
            decisions = load_decisions(outdir.evaluation_dir(store.out, row.environment, row.method, row.direction)
                                       / outdir.DECISIONS)
            f1 = ev.f1_at_threshold_from(curve, decisions)
            threshold = curve.delta_at_max_f1 if np.isfinite(curve.delta_at_max_f1) else None
        completed.append(row.model_copy(update=dict(f1_at_e1_threshold=f1, e1_threshold=threshold)))
    return completed


def warn_few_revisits(store: Store, simulated: SimulateRecord, rows: list[ResultRow]) -> None:
    """Warn (log, manifest.json, report.md; on the run whose samples are the queries) about
    every evaluation direction in which fewer than `MIN_REVISITS` queries have a true
    match: with none, its max F1 of 0 says nothing about a method."""
    for row in rows:
        n, queries = row.n_revisit, row.n_queries
        if n >= MIN_REVISITS:
            continue
        side = "query" if row.direction == "query-to-reference" else "reference"
        what = ("none of its {q} queries has" if n == 0 else "only {n} of its {q} queries have").format(n=n, q=queries)
        warn_once(store.run(simulated.runs[f"{row.environment}/{side}"]), f"revisits {row.direction}",
                  f"evaluation {row.environment} {row.direction}: {what} a true match within tau = "
                  f"{row.tau:g} m (n_revisit < {MIN_REVISITS}): its max F1 and recall rest on too few samples "
                  "to compare methods by")


def pair_complementarity(store: Store, scenario: Scenario) -> list[dict[str, Any]]:
    """Per evaluation, direction and (vision, touch) pair of `complementarity_pairs`: what the
    touch method gets right of the vision method's wrong best matches
    (`vitaplace.engine.evaluation.complementarity`), from the two evaluations' decisions."""
    pairs = complementarity_pairs(scenario, store.registry)
    records = []
    for e in scenario.evaluations:
        for direction, _, _ in plan.directions(scenario):
            for vision, touch in pairs:
                decisions = [load_decisions(outdir.evaluation_dir(store.out, e.name, m, direction) / outdir.DECISIONS)
                             for m in (vision, touch)]
                records.append({"environment": e.name, "direction": direction, "vision": vision, "touch": touch,
                                **complementarity(*decisions)})
    return records
