"""manifest.json: what a run did - provenance, plugins, seeds, run keys, warnings, every
stage's record, how training went, the time it took."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.config.scenario import training_world_evaluation
from vitaplace.engine.evaluation.report import feature_facts, run_facts
from vitaplace.engine.features import load_features
from vitaplace.engine.pipeline.outdir import MANIFEST
from vitaplace.engine.pipeline.provenance import provenance
from vitaplace.engine.pipeline.runner import STAGES, Pipeline
from vitaplace.engine.plugins import plugin_distributions


def write_manifest(pipeline: Pipeline, seconds: float, until: str) -> None:
    """``OUT/manifest.json`` of ``pipeline``'s run up to stage ``until``, which took ``seconds``:
    provenance, seeds, datasets, warnings, stages, training, timing, and what the report reads
    besides (`vitaplace.engine.evaluation.report.MANIFEST_KEYS`)."""
    scenario = pipeline.scenario
    manifest: dict[str, Any] = {
        "scenario": scenario.name,
        **provenance(),
        "plugins": plugin_distributions(pipeline.registry),
        "seed": scenario.seed,
        "run_seeds": {label: seed for label, (_, seed) in pipeline.runs().items() if label not in pipeline.recorded},
        "datasets": pipeline.state.datasets,
        "recorded": {label: str(path) for label, path in pipeline.recorded.items()},
        "runs": {label: run_facts(pipeline.open(label)) for label in pipeline.runs()},
        "warnings": {label: dict(run.warnings) for label, run in pipeline.opened.items() if run.warnings},
        "stages": [record.__dict__ for record in pipeline.state.records],
        "training": {m.name: s for m in scenario.methods if (s := pipeline.training_record(m)["summary"])},
        "training_world": training_world_evaluation(scenario)[1],
        "methods": pipeline.method_parameters(),
        "seconds": round(seconds, 3),
    }
    if STAGES.index(until) >= STAGES.index("transform"):
        manifest["features"] = {m.name: {label: feature_facts(load_features(pipeline.features_path(m, label)))
                                         for label in pipeline.runs() if label != "train"} for m in scenario.methods}
    write_text_atomic(Path(pipeline.out) / MANIFEST, json.dumps(manifest, indent=2))
