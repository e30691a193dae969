"""The transform stage: each fitted method's features of every evaluation run, checked and
saved in the cache."""

from __future__ import annotations

from functools import partial
from pathlib import Path

from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.extension.features import feature_facts, load_features, save_features
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.keys import features_key
from vitaplace.engine.pipeline.output_checks import call_plugin, check_features
from vitaplace.engine.pipeline.records import (
    FeaturesFile,
    FitRecord,
    ModelFile,
    RunFile,
    SimulateRecord,
    TransformRecord,
)
from vitaplace.engine.pipeline.store import Store


def transform(store: Store, scenario: Scenario, simulated: SimulateRecord, fitted: FitRecord) -> TransformRecord:
    """Every method's features of every evaluation run (or found in the cache)."""
    runs = [run for label, run in simulated.runs.items() if label != "train"]
    files: dict[str, dict[str, FeaturesFile]] = {}
    for method in scenario.methods:
        model = fitted.models[method.name]
        files[method.name] = {}
        for run in runs:
            key = features_key(model, run)
            path = outdir.features_file(store.cache, method.name, run.label, key)
            done = store.stage("transform", f"{method.name} {run.label}", key, path,
                               partial(_transform, store, model, run, path), [model.key, run.key])
            files[method.name][run.label] = FeaturesFile(path, key, done.digest)
    facts = {name: {label: feature_facts(load_features(f.path)) for label, f in by_run.items()}
             for name, by_run in files.items()}
    return TransformRecord(files, facts)


def _transform(store: Store, model: ModelFile, run: RunFile, path: Path) -> None:
    """The features of ``run`` by the fitted ``model``, checked, saved to ``path``."""
    opened = store.run(run)
    what = f"transform {model.method} (plugin '{model.plugin}') {run.label}"
    features = call_plugin(store.out, what, store.model(model), "transform", opened)
    save_features(path, check_features(features, len(opened), what))
