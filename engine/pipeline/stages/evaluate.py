"""The evaluate stage: per evaluation, method and direction, the method's distances from the
query side's samples to the reference side's, scored into the evaluation's folder
(`vitaplace.engine.pipeline.scoring`), and its results row.

The distances are asked of the method a chunk of queries at a time (`distance_rows`), so a
pair above `FULL_MATRIX_LIMIT` entries is scored in memory linear in its samples; a pair at
or below it is asked for in one call, as it is held whole for ``matrices.npz``."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.evaluation.ranking import Rows
from vitaplace.engine.extension.features import FeatureExtractor, Features, load_features
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.keys import evaluate_key
from vitaplace.engine.pipeline.output_checks import call_plugin, check_distance
from vitaplace.engine.pipeline.records import (
    EvaluateRecord,
    FeaturesFile,
    FitRecord,
    ModelFile,
    RunFile,
    SimulateRecord,
    TransformRecord,
)
from vitaplace.engine.pipeline.scoring import result_row, score
from vitaplace.engine.pipeline.store import Store


def evaluate(store: Store, scenario: Scenario, simulated: SimulateRecord, fitted: FitRecord,
             transformed: TransformRecord) -> EvaluateRecord:
    """Every method scored in every evaluation and direction (or found scored)."""
    rows, folders, files = [], {}, []
    for e in scenario.evaluations:
        for method in scenario.methods:
            model, features = fitted.models[method.name], transformed.files[method.name]
            for direction, q, r in plan.directions(scenario):
                query = features[f"{e.name}/{q}"], simulated.runs[f"{e.name}/{q}"]
                reference = features[f"{e.name}/{r}"], simulated.runs[f"{e.name}/{r}"]
                key = evaluate_key(model, query, reference, scenario)
                folder = outdir.evaluation_dir(store.out, e.name, method.name, direction)
                done = store.stage("evaluate", f"{e.name} {method.name} {direction}", key, folder,
                                   partial(_evaluate, store, scenario, model, query, reference, folder),
                                   [query[0].path.stem, reference[0].path.stem])
                folders[(e.name, method.name, direction)] = done.digest
                rows.append(result_row(e, method.name, direction, folder, simulated.runs[f"{e.name}/query"]))
                files += [folder / outdir.SUMMARY, folder / outdir.PR_CURVE]
    return EvaluateRecord(rows, folders, files)


def distance_rows(extractor: FeatureExtractor, query: Features, reference: Features, shape: tuple[int, int],
                  what: str, out: Path) -> Rows:
    """``extractor``'s distances from the ``query`` features to the ``reference`` ones, a block
    of queries at a time (a query's row depends on that query alone: the plugin contract's
    `check_distance_rows`), each block checked (`check_distance`)."""
    n_references = shape[1]

    def read(start: int, stop: int) -> np.ndarray:
        block = {name: values[start:stop] for name, values in query.items()}
        tme = call_plugin(out, what, extractor, "distance", block, reference)
        return check_distance(tme, (stop - start, n_references), what)

    return Rows(shape, read)


def _evaluate(store: Store, scenario: Scenario, model: ModelFile, query: tuple[FeaturesFile, RunFile],
              reference: tuple[FeaturesFile, RunFile], folder: Path) -> None:
    """Score ``model``'s distances from the ``query`` run's samples to the ``reference`` run's
    into ``folder`` (summary, curves, matrices)."""
    folder.mkdir(parents=True, exist_ok=True)
    q, r = store.run(query[1]), store.run(reference[1])
    tme = distance_rows(store.model(model), load_features(query[0].path), load_features(reference[0].path),
                        (len(q), len(r)),
                        f"evaluate {query[1].label.split('/')[0]} {model.method} (plugin '{model.plugin}')", store.out)
    write_text_atomic(folder / outdir.SUMMARY, json.dumps(score(scenario, folder, tme, q, r), indent=2))
