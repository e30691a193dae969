"""manifest.json: what a run did - provenance, plugins, seeds, run keys, warnings, every
stage's record, how training went, the time it took - from the run's records alone."""

from __future__ import annotations

import json
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.outputs.outdir import MANIFEST
from vitaplace.engine.pipeline.provenance import provenance
from vitaplace.engine.pipeline.records import RunRecord


def manifest_of(run: RunRecord) -> dict[str, Any]:
    """The manifest of the run ``run`` records: provenance, seeds, datasets, warnings,
    stages, training, timing, and what the report reads besides
    (`vitaplace.engine.report.report.MANIFEST_KEYS`); ``features`` from the transform stage on."""
    simulated = run.simulate
    manifest: dict[str, Any] = {
        "scenario": run.scenario,
        **provenance(),
        "plugins": run.plugins,
        "seed": run.seed,
        "run_seeds": simulated.run_seeds,
        "datasets": simulated.datasets,
        "recorded": simulated.recorded,
        "runs": simulated.facts,
        "warnings": run.warnings,
        "stages": [record.__dict__ for record in run.stages],
        "training": run.fit.training if run.fit is not None else {},
        "training_world": run.training_world,
        "methods": run.methods,
        "seconds": run.seconds,
    }
    if simulated.dropout:
        manifest["dropout"] = simulated.dropout
    if run.transform is not None:
        manifest["features"] = run.transform.features
    return manifest


def write_manifest(run: RunRecord) -> None:
    """``OUT/manifest.json`` of the run ``run`` records (`manifest_of`)."""
    write_text_atomic(run.out / MANIFEST, json.dumps(manifest_of(run), indent=2))
