"""Optional experiment tracking: log each finished scenario run to MLflow.

Inert unless the environment variable ``VITAPLACE_MLFLOW`` names an MLflow experiment; then
every finished pipeline (`vitaplace run`, each seed of a sweep, `vitaplace.run`) becomes one
MLflow run in that experiment, at MLflow's own tracking URI (``MLFLOW_TRACKING_URI``; by
default MLflow's local store in the working folder). Install the client with
``pip install "vitaplace[mlflow]"``. Logged (docs/plugins.md, "Experiment tracking"):

* params: the scenario's name and seed, its evaluation settings (``scoring.tau``, ...)
  and every method's plugin and the parameters the scenario sets
  (``methods.L.plugin``, ``methods.L.epochs``, ...);
* metrics: per results row ``ENVIRONMENT/METHOD/DIRECTION/METRIC`` for `METRICS`;
* tags: vitaplace's version, git commit and dirty flag (from manifest.json), the last stage;
* artifacts: report.md, results.json, results.csv, manifest.json, scenario.resolved.yaml
  and the figures/ folder, those of them the run wrote.

The module imports MLflow only when it logs, so it costs nothing when tracking is off.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vitaplace.plugin import hookimpl

#: the environment variable that turns tracking on: the MLflow experiment's name
EXPERIMENT_ENV = "VITAPLACE_MLFLOW"
#: the per-row numbers logged as metrics
METRICS = ("max_f1", "auc", "precision_at_max_f1", "recall_at_max_f1", "recall_at_100_precision")
ARTIFACTS = ("report.md", "results.json", "results.csv", "manifest.json", "scenario.resolved.yaml")

log = logging.getLogger("vitaplace")


def _flat(prefix: str, values: Mapping[str, Any]) -> dict[str, str]:
    """``{prefix.key: value}`` with values as JSON text (MLflow params are strings)."""
    return {f"{prefix}.{key}": value if isinstance(value, str) else json.dumps(value) for key, value in values.items()}


def run_params(scenario: Any) -> dict[str, str]:
    """The MLflow params of a scenario: name, seed, evaluation settings, methods."""
    params = {"scenario": scenario.name, "seed": str(scenario.seed)}
    params.update(_flat("scoring", scenario.scoring.model_dump(mode="json")))
    for method in scenario.methods:
        params[f"methods.{method.name}.plugin"] = method.plugin
        params.update(_flat(f"methods.{method.name}", method.params))
    return params


def run_metrics(rows: list[dict[str, Any]]) -> dict[str, float]:
    """``ENVIRONMENT/METHOD/DIRECTION/METRIC`` -> value for every number of `METRICS` in ``rows``."""
    return {
        f"{row['environment']}/{row['method']}/{row['direction']}/{name}": float(row[name])
        for row in rows for name in METRICS if isinstance(row.get(name), (int, float))
    }


@hookimpl
def vitaplace_run_finished(out: Path, scenario: Any, rows: list[dict[str, Any]], stage: str) -> None:
    """Log the finished run to the MLflow experiment named by ``VITAPLACE_MLFLOW`` (if set)."""
    experiment = os.environ.get(EXPERIMENT_ENV)
    if not experiment:
        return
    try:
        import mlflow
    except ImportError:
        log.warning("%s=%s but MLflow is not installed (pip install \"vitaplace[mlflow]\"): run not logged",
                    EXPERIMENT_ENV, experiment)
        return
    out = Path(out)
    manifest_path = out / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    tags = {"vitaplace.version": str(manifest.get("vitaplace_version")), "vitaplace.stage": stage,
            "git.commit": str(manifest.get("git_commit")), "git.dirty": str(manifest.get("git_dirty")),
            "vitaplace.out": str(out.resolve())}
    mlflow.set_experiment(experiment)
    with mlflow.start_run(run_name=f"{scenario.name} seed {scenario.seed}", tags=tags) as active:
        mlflow.log_params(run_params(scenario))
        metrics = run_metrics(rows)
        if metrics:
            mlflow.log_metrics(metrics)
        for name in ARTIFACTS:
            if (out / name).is_file():
                mlflow.log_artifact(str(out / name))
        if (out / "figures").is_dir():
            mlflow.log_artifacts(str(out / "figures"), artifact_path="figures")
    log.info("logged to MLflow: experiment %s, run %s", experiment, active.info.run_id)
