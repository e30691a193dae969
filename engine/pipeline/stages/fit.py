"""The fit stage: each method's extractor fitted on the training run and saved, with how its
training went, into its model folder in the cache."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from functools import partial
from pathlib import Path
from typing import Any

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Method, Scenario
from vitaplace.engine.extension.registry import announce_training_epoch
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.keys import fit_key
from vitaplace.engine.pipeline.output_checks import call_plugin
from vitaplace.engine.pipeline.records import FitRecord, ModelFile, RunFile, SimulateRecord
from vitaplace.engine.pipeline.store import Store


def fit(store: Store, scenario: Scenario, simulated: SimulateRecord) -> FitRecord:
    """Every method fitted on the training run (or found in the cache)."""
    train = simulated.runs["train"]
    models, training, histories = {}, {}, {}
    registry = store.registry
    for method in scenario.methods:
        params = plan.params_for(scenario, registry, method)
        key = fit_key(method.plugin, registry.version_of(method.plugin), registry.code_digest(method.plugin), params,
                      train)
        folder = outdir.model_dir(store.cache, method.name, key)
        folder.parent.mkdir(parents=True, exist_ok=True)
        done = store.stage("fit", method.name, key, folder, partial(_fit, store, method, params, train, folder),
                           [train.key])
        models[method.name] = ModelFile(method.name, method.plugin, folder, key, done.digest)
        record = training_record(folder)
        if record["summary"]:
            training[method.name] = record["summary"]
        if record["history"]:
            histories[method.name] = record["history"]
    return FitRecord(models, training, histories)


def _fit(store: Store, method: Method, params: dict[str, Any], train: RunFile, folder: Path) -> None:
    """Fit ``method`` on the training run and save it into ``folder`` (atomically), with how
    its training went beside it (`outdir.training_file`)."""
    extractor = store.registry.create(method.plugin, params)
    extractor.progress = store.progress
    extractor.on_epoch = partial(announce_training_epoch, store.registry, store.out, method.name)
    call_plugin(store.out, f"fit {method.name} (plugin '{method.plugin}')", extractor, "fit", store.run(train))
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        extractor.save(tmp)
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    store.keep_model(folder, extractor)
    record = {"history": extractor.training_history(), "summary": extractor.training_summary()}
    write_text_atomic(outdir.training_file(folder), json.dumps(record))


def training_record(folder: Path) -> dict[str, Any]:
    """``{"history": per-epoch curves, "summary": how training ended}`` the fit stage saved
    beside the model in ``folder``."""
    path = outdir.training_file(folder)
    return json.loads(path.read_text()) if path.exists() else {"history": {}, "summary": {}}
