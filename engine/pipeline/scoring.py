"""Scoring one evaluation folder, for a method's distances and a fusion's alike: the
scenario's scoring settings applied to a distance matrix (`evaluate_pair`), and the results
row (`ResultRow`) read back from the folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.config.scenario import EvaluationPair, Scenario, ScenarioError
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.evaluation.pairfiles import evaluate_pair
from vitaplace.engine.evaluation.ranking import Rows
from vitaplace.engine.evaluation.sequence import travelled
from vitaplace.engine.extension.features import warn_once
from vitaplace.engine.outputs import outdir
from vitaplace.engine.outputs.rows import QueryDropoutShares, ResultRow, parse_row
from vitaplace.engine.pipeline.records import RunFile


def sequence_for(scenario: Scenario, query: Run, reference: Run) -> dict[str, Any] | None:
    """The scenario's sequence matching settings (None for single samples), checked against
    the ``query`` and ``reference`` runs (a recorded run's length is known only here): a
    sequence no longer than the queries, and sequences that fit the reference run (a line
    that leaves it is no candidate, `vitaplace.engine.evaluation.sequence`): each velocity
    times ``length - 1`` below its samples, ``metres`` below its travelled distance."""
    sequence = scenario.scoring.sequence
    if sequence.length == 1 or sequence.metres == 0:
        return None
    if sequence.metres is not None:
        drive = float(travelled(reference.poses)[-1]) if len(reference) else 0.0
        if sequence.metres >= drive:
            raise ScenarioError(f"scoring.sequence.metres: {sequence.metres:g} m is not below the {drive:.2f} m run "
                                f"{reference.name} travelled: no reference has a sequence behind it")
        return sequence.model_dump()
    if sequence.length > len(query):
        raise ScenarioError(f"scoring.sequence.length: {sequence.length} is longer than run {query.name} "
                            f"({len(query)} samples); expected at most that")
    fastest = sequence.velocities[1] * (sequence.length - 1)
    if fastest >= len(reference):
        raise ScenarioError(f"scoring.sequence.velocities: the fastest, {sequence.velocities[1]:g}, spans "
                            f"{fastest:g} references over a sequence of {sequence.length}, not below the "
                            f"{len(reference)} samples of run {reference.name}: no line at it fits the run")
    return sequence.model_dump()


def score(scenario: Scenario, folder: Path, tme: np.ndarray | Rows, query: Run, reference: Run) -> dict[str, Any]:
    """The distances ``tme`` (whole, or `Rows` read a block of queries at a time) from the
    ``query`` run's samples to the ``reference`` run's scored
    with the scenario's settings into ``folder`` (`evaluate_pair`); returns the summary."""
    settings = scenario.scoring
    return evaluate_pair(
        folder, tme, query.poses, reference.poses, settings.tau, query_touch=query.touch_mask(),
        reference_touch=reference.touch_mask(), delta=settings.delta,
        heading_tolerance_deg=settings.heading_tolerance_deg, ks=searchable_ks(settings.recall_k, reference),
        sequence=sequence_for(scenario, query, reference),
    )


def searchable_ks(ks: list[int], reference: Run) -> tuple[int, ...]:
    """The K of ``ks`` below the ``reference`` run's samples: at K >= them every query with a
    true match has it among its first K, and recall@K is 100 % for any method. `vitaplace
    validate` refuses such a K in a list the scenario sets; the default list (1, 5, 10) meets
    it in runs of a few samples, where that K is left out of the row (its cell blank) and a run
    warning says so."""
    kept = tuple(k for k in ks if k < len(reference))
    if len(kept) < len(ks):
        left_out = ", ".join(f"recall@{k}" for k in ks if k not in kept)
        warn_once(reference, "recall@K", f"{left_out}: not scored against run {reference.name!r}: K is not below "
                  f"its {len(reference)} samples, where every query with a true match counts as found")
    return kept


def result_row(evaluation: EvaluationPair, name: str, direction: str, folder: Path, query: RunFile) -> ResultRow:
    """The results row of evaluation folder ``folder`` (method or fusion ``name``): its summary
    and, for an evaluation with a ``query_dropout``, the shares of the ``query`` run's samples
    that lacked each sensor (as drawn: whole samples)."""
    summary = folder / outdir.SUMMARY
    row = parse_row(
        json.loads(summary.read_text()) | dict(environment=evaluation.name, method=name, direction=direction),
        str(summary))
    if evaluation.query_dropout is None:
        return row
    shares = {sensor: float(mask.mean()) if len(mask) else 0.0 for sensor, mask in query.missing.items()}
    return row.model_copy(update=dict(query_dropout=QueryDropoutShares(**shares)))
