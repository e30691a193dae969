"""manifest.json: what a run did - provenance, plugins, seeds, run keys, warnings, every
stage's record, how training went, the time it took."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.pipeline.outdir import MANIFEST
from vitaplace.engine.pipeline.provenance import provenance
from vitaplace.engine.pipeline.runner import Pipeline
from vitaplace.engine.plugins import plugin_distributions


def write_manifest(pipeline: Pipeline, seconds: float) -> None:
    """``OUT/manifest.json`` of ``pipeline``'s run, which took ``seconds``."""
    scenario = pipeline.scenario
    manifest: dict[str, Any] = {
        "scenario": scenario.name,
        **provenance(),
        "plugins": plugin_distributions(pipeline.registry),
        "seed": scenario.seed,
        "run_seeds": {label: seed for label, (_, seed) in pipeline.runs().items() if label not in pipeline.recorded},
        "datasets": pipeline.state.datasets,
        "recorded": {label: str(path) for label, path in pipeline.recorded.items()},
        "warnings": {label: dict(run.warnings) for label, run in pipeline.opened.items() if run.warnings},
        "stages": [record.__dict__ for record in pipeline.state.records],
        "training": {m.name: s for m in scenario.methods if (s := pipeline.training_record(m)["summary"])},
        "seconds": round(seconds, 3),
    }
    write_text_atomic(Path(pipeline.out) / MANIFEST, json.dumps(manifest, indent=2))
