"""The evaluate stage of a scenario's late fusions (``fusions:``): per fusion and direction the
touch weight chosen on the selection evaluation from the two methods' saved distances, then
every evaluation scored with it like a method (`vitaplace.engine.evaluation.fusion`).

A fusion's evaluation folder is a stage output like a method's, keyed by the fusion's
settings, the scoring settings and the digests of the two methods' evaluation folders it
reads: this evaluation's and the selection evaluation's (so a changed weight choice re-runs
every evaluation of the fusion)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Fusion, Scenario, training_world_evaluation
from vitaplace.engine.evaluation import pairfiles
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve
from vitaplace.engine.evaluation.fusion import choose_weight, fused_distance
from vitaplace.engine.evaluation.sequence import sequence_scores
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.keys import fusion_key
from vitaplace.engine.pipeline.output_checks import StageError
from vitaplace.engine.pipeline.records import EvaluateRecord, SimulateRecord
from vitaplace.engine.pipeline.scoring import result_row, score, sequence_for
from vitaplace.engine.pipeline.store import Store


def method_distances(out: Path, environment: str, method: str, direction: str) -> np.ndarray:
    """A method's own distances in one evaluation (before any sequence scoring), as its
    ``matrices.npz`` saved them (only pairs of at most `FULL_MATRIX_LIMIT` entries have one)."""
    path = outdir.evaluation_dir(out, environment, method, direction) / outdir.MATRICES
    if not path.is_file():
        raise StageError(f"{path}: missing; a late fusion reads each method's whole distances, saved only for "
                         f"pairs of at most {pairfiles.FULL_MATRIX_LIMIT:,} queries x references (FULL_MATRIX_LIMIT)")
    with np.load(path) as saved:
        return np.asarray(saved["distance" if "distance" in saved.files else "tme"], dtype=float)


def selection(scenario: Scenario, fusion: Fusion) -> str:
    """The evaluation ``fusion``'s weight is chosen on (validated to exist)."""
    chosen = fusion.select_on or training_world_evaluation(scenario)[0]
    assert chosen is not None  # the scenario's validation makes sure there is one
    return chosen


def chosen_weight(store: Store, scenario: Scenario, simulated: SimulateRecord, fusion: Fusion, direction: str,
                  query: str) -> dict[str, Any]:
    """The weight that maximises the fused max F1 on the selection evaluation in ``direction``
    (whose queries are its ``query`` side), scored as every evaluation is (ground truth,
    sequences), and the spreads."""
    settings, env = scenario.scoring, selection(scenario, fusion)
    reference = "reference" if query == "query" else "query"
    q, r = (store.run(simulated.runs[f"{env}/{side}"]) for side in (query, reference))
    gtm = ground_truth_matrix(q.poses, r.poses, settings.heading_tolerance_deg)
    sequence = sequence_for(scenario, q, r)

    def max_f1(fused: np.ndarray) -> float:
        scored = fused if sequence is None else sequence_scores(fused, **sequence, poses=(q.poses, r.poses))
        return pr_curve(scored, gtm, settings.tau).max_f1

    vision, touch = (method_distances(store.out, env, m, direction) for m in (fusion.vision, fusion.touch))
    weight, sigma_v, sigma_t, scores = choose_weight(vision, touch, fusion.weights, max_f1)
    return {"weight": weight, "sigma_vision": sigma_v, "sigma_touch": sigma_t, "selection_max_f1": scores[weight]}


def _evaluate(store: Store, scenario: Scenario, simulated: SimulateRecord, fusion: Fusion, choice: dict[str, Any],
              environment: str, direction: tuple[str, str, str], folder: Path) -> None:
    name, query, reference = direction
    folder.mkdir(parents=True, exist_ok=True)
    vision, touch = (method_distances(store.out, environment, m, name) for m in (fusion.vision, fusion.touch))
    fused = fused_distance(vision, touch, choice["sigma_vision"], choice["sigma_touch"], choice["weight"])
    q, r = (store.run(simulated.runs[f"{environment}/{side}"]) for side in (query, reference))
    summary = score(scenario, folder, fused, q, r)
    summary["fusion"] = choice
    write_text_atomic(folder / outdir.SUMMARY, json.dumps(summary, indent=2))


def fuse(store: Store, scenario: Scenario, simulated: SimulateRecord, evaluated: EvaluateRecord) -> EvaluateRecord:
    """``evaluated`` with every fusion's results rows after the methods' (each with ``fusion``:
    the weight, the spreads and the selection evaluation's max F1 at that weight), their
    folders' digests and the files they rest on."""
    rows, folders, files = list(evaluated.rows), dict(evaluated.folders), list(evaluated.files)
    for fusion in scenario.fusions:
        chosen_on = selection(scenario, fusion)
        for direction in plan.directions(scenario):
            name, query, _ = direction
            choice = chosen_weight(store, scenario, simulated, fusion, name, query)
            for e in scenario.evaluations:
                members = [(env, m, name) for env in (e.name, chosen_on) for m in (fusion.vision, fusion.touch)]
                key = fusion_key(fusion, chosen_on, scenario, [evaluated.folders[member] for member in members])
                folder = outdir.evaluation_dir(store.out, e.name, fusion.name, name)
                done = store.stage(
                    "evaluate", f"{e.name} {fusion.name} {name}", key, folder,
                    partial(_evaluate, store, scenario, simulated, fusion, choice, e.name, direction, folder),
                    [str(outdir.evaluation_dir(store.out, *member).relative_to(store.out)) for member in members])
                folders[(e.name, fusion.name, name)] = done.digest
                rows.append(result_row(e, fusion.name, name, folder, simulated.runs[f"{e.name}/query"]))
                files += [folder / outdir.SUMMARY, folder / outdir.PR_CURVE]
    return EvaluateRecord(rows, folders, files)
