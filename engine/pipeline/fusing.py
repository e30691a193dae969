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
from typing import Any, Protocol

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Fusion, Scenario, training_world_evaluation
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve
from vitaplace.engine.evaluation.fusion import choose_weight, fused_distance
from vitaplace.engine.evaluation.sequence import sequence_scores
from vitaplace.engine.outputs import outdir
from vitaplace.engine.outputs.keys import content_hash

#: the version of a fusion's evaluation (part of its key)
FUSION_VERSION = 1


class Evaluating(Protocol):
    """What the fusion stage uses of the runner."""

    out: Path
    scenario: Scenario

    def directions(self) -> list[tuple[str, str, str]]: ...
    def open(self, label: str) -> Run: ...
    def output_digest(self, path: Path) -> str: ...
    def stage(self, stage: str, item: str, key: str, output: Path, work: Any, inputs: Any = ()) -> Any: ...
    def sequence_for(self, query: str, n_queries: int) -> dict[str, Any] | None: ...
    def dropout_row(self, e: Any) -> dict[str, Any]: ...
    def score(self, folder: Path, tme: np.ndarray, query: str, reference: str) -> dict[str, Any]: ...


def method_distances(out: Path, environment: str, method: str, direction: str) -> np.ndarray:
    """A method's own distances in one evaluation (before any sequence scoring)."""
    with np.load(outdir.evaluation_dir(out, environment, method, direction) / outdir.MATRICES) as saved:
        return np.asarray(saved["distance" if "distance" in saved.files else "tme"], dtype=float)


def selection(runner: Evaluating, fusion: Fusion) -> str:
    """The evaluation ``fusion``'s weight is chosen on (validated to exist)."""
    chosen = fusion.select_on or training_world_evaluation(runner.scenario)[0]
    assert chosen is not None  # the scenario's validation makes sure there is one
    return chosen


def chosen_weight(runner: Evaluating, fusion: Fusion, direction: str, query: str, reference: str) -> dict[str, Any]:
    """The weight that maximises the fused max F1 on the selection evaluation in ``direction``,
    scored as every evaluation is (ground truth, sequences), and the spreads."""
    settings, env = runner.scenario.scoring, selection(runner, fusion)
    q, r = runner.open(f"{env}/{query}"), runner.open(f"{env}/{reference}")
    gtm = ground_truth_matrix(q.poses, r.poses, settings.heading_tolerance_deg)
    sequence = runner.sequence_for(f"{env}/{query}", len(q))

    def max_f1(fused: np.ndarray) -> float:
        return pr_curve(fused if sequence is None else sequence_scores(fused, **sequence), gtm, settings.tau).max_f1

    vision, touch = (method_distances(runner.out, env, m, direction) for m in (fusion.vision, fusion.touch))
    weight, sigma_v, sigma_t, scores = choose_weight(vision, touch, fusion.weights, max_f1)
    return {"weight": weight, "sigma_vision": sigma_v, "sigma_touch": sigma_t, "selection_max_f1": scores[weight]}


def _evaluate(runner: Evaluating, fusion: Fusion, choice: dict[str, Any], environment: str, direction: str,
              query: str, reference: str, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    vision, touch = (method_distances(runner.out, environment, m, direction) for m in (fusion.vision, fusion.touch))
    fused = fused_distance(vision, touch, choice["sigma_vision"], choice["sigma_touch"], choice["weight"])
    summary = runner.score(folder, fused, f"{environment}/{query}", f"{environment}/{reference}")
    summary["fusion"] = choice
    write_text_atomic(folder / outdir.SUMMARY, json.dumps(summary, indent=2))


def evaluate_fusions(runner: Evaluating) -> tuple[list[dict[str, Any]], list[Path]]:
    """Every fusion's results rows (each with ``fusion``: the weight, the spreads and the
    selection evaluation's max F1 at that weight) and the files they rest on."""
    rows: list[dict[str, Any]] = []
    files: list[Path] = []
    for fusion in runner.scenario.fusions:
        chosen_on = selection(runner, fusion)
        for direction, q, r in runner.directions():
            choice = chosen_weight(runner, fusion, direction, q, r)
            for e in runner.scenario.evaluations:
                members = [outdir.evaluation_dir(runner.out, env, m, direction)
                           for env in (e.name, chosen_on) for m in (fusion.vision, fusion.touch)]
                key = content_hash("evaluate-fusion", FUSION_VERSION, fusion.model_dump(), chosen_on,
                                   runner.scenario.scoring.model_dump(exclude={"complementarity"}),
                                   [runner.output_digest(folder) for folder in members])
                folder = outdir.evaluation_dir(runner.out, e.name, fusion.name, direction)
                runner.stage("evaluate", f"{e.name} {fusion.name} {direction}", key, folder,
                             partial(_evaluate, runner, fusion, choice, e.name, direction, q, r, folder),
                             [str(m.relative_to(runner.out)) for m in members])
                summary = json.loads((folder / outdir.SUMMARY).read_text())
                rows.append({"environment": e.name, "method": fusion.name, "direction": direction, **summary,
                             **runner.dropout_row(e)})
                files += [folder / outdir.SUMMARY, folder / outdir.PR_CURVE]
    return rows, files
