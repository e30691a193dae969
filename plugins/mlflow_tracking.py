"""Optional experiment tracking: log each finished scenario run, and each sweep, to MLflow.

Inert unless the environment variable ``VITAPLACE_MLFLOW`` names an MLflow experiment; then
every pipeline (`vitaplace run`, each seed of a sweep, `vitaplace.run`) becomes one
MLflow run in that experiment, at MLflow's own tracking URI (``MLFLOW_TRACKING_URI``; by
default MLflow's local store in the working folder: ``mlflow.db``, SQLite, for MLflow 3).
A sweep is one parent run with the seeds' runs nested under it. Install the client with
``pip install "vitaplace[mlflow]"`` (mlflow-skinny with SQLAlchemy and Alembic, which its
SQLite store needs). Logged (docs/plugins.md, "Experiment tracking"):

* params: the resolved scenario flattened (`run_params`: ``scenario``, ``seed``,
  ``train.run.n_samples``, ``evaluations.E1.run.kind``, ``scoring.tau``,
  ``methods.L.plugin``, ``methods.L.params.epochs``, ...; a value longer than MLflow takes is
  left out and named in the tag `SKIPPED_TAG`); a sweep's: the same but ``seeds``;
* metrics: per results row ``ENVIRONMENT/METHOD/DIRECTION/METRIC`` for `METRICS` and
  ``recall_at_K`` for each K of ``scoring.recall_k`` (recall@1/5/10); and while a method
  trains, after every epoch, ``training/METHOD/NAME`` at MLflow's step = the epoch for each
  number its plugin reports (`vitaplace_training_epoch`: MuPNet's ``energy``,
  ``held_out_energy``, ``latent_change``, ``energy.EDGE``; the autoencoder's ``loss``);
* tags: MLflow's source tags (`source_tags`: ``mlflow.source.name``, ``.type``; a finished
  run's ``.git.commit``), vitaplace's version, git commit and dirty flag (from manifest.json), the
  last stage, the output folder, and `KEY_TAG`, a digest of what was logged;
* artifacts: report.md, results.json, results.csv, manifest.json, scenario.resolved.yaml
  and the figures/ folder, those of them the run wrote; a sweep's parent: `SWEEP_FILES` and
  the pr-bands-* figures.

A run whose output folder, last stage, results and resolved scenario were logged already
(a rerun that found every stage cached) is not logged again; a rerun of the same sweep
(same folder, scenario and seeds) reuses its parent run. The module imports MLflow only
when it logs, so it costs nothing when tracking is off.

A run's MLflow run is opened when the pipeline starts (`vitaplace_run_started`: RUNNING,
with its params) and ended FAILED with the error as a tag (`ERROR_TAG`) when it raises, or
FINISHED with its metrics, tags and artifacts once its results and completion record are
written. A run opened for a rerun that turns out to have been logged already is deleted. A
grid's parent carries the grid's axes (`sweep_params`); its seeds are named by point
(`run_name`). The tracker never fails a run: its HTTP calls give up after MLflow's own settings
``MLFLOW_HTTP_REQUEST_TIMEOUT`` and ``MLFLOW_HTTP_REQUEST_MAX_RETRIES``, which it sets to
`HTTP_SETTINGS` (5 s, 1 retry) for its calls alone where the environment does not set them,
and a failure is one warning (`_tracking`). A sweep whose parent run cannot be opened is not
logged, nor are its seeds (one warning, not one per seed).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from vitaplace.engine import __version__
from vitaplace.engine.outputs.rows import ResultRow, parse_row
from vitaplace.plugin import hookimpl

#: the environment variable that turns tracking on: the MLflow experiment's name
EXPERIMENT_ENV = "VITAPLACE_MLFLOW"
#: set by a sweep's driver for its seeds: the MLflow run id of the sweep's parent run
PARENT_ENV = "VITAPLACE_MLFLOW_PARENT"
#: set by a sweep's driver for its seeds: the sweep's output folder (a grid seed's run is named by its point)
SWEEP_ENV = "VITAPLACE_MLFLOW_SWEEP"
#: the per-row numbers logged as metrics
METRICS = ("max_f1", "auc", "precision_at_max_f1", "recall_at_max_f1", "recall_at_100_precision")
ARTIFACTS = ("report.md", "results.json", "results.csv", "manifest.json", "scenario.resolved.yaml")
#: a sweep's summary files (on a grid, `vitaplace sweep --grid`: its table across points), logged to its parent run
SWEEP_FILES = ("sweep.json", "sweep.csv", "sweep-seeds.csv", "sweep-diff.csv", "sweep.md", "sweep.tex",
               "grid.json", "grid.csv", "grid.md")
#: the tag holding the digest of what a run logged (`run_key`, `sweep_key`); a later run with the same digest is skipped
KEY_TAG = "vitaplace.key"
#: the parent run's tag: the digest of the sweep.json it logged last
SUMMARY_TAG = "vitaplace.summary"
#: the tag naming the params left out for being longer than MLflow takes (`_log_params`)
SKIPPED_TAG = "vitaplace.params_skipped"
#: the tag of a failed run's MLflow run: the failure, ``Type: message``
ERROR_TAG = "vitaplace.error"
#: MLflow's tag that nests a run under its parent
PARENT_TAG = "mlflow.parentRunId"
#: MLflow's settings of its HTTP calls as the tracker's calls have them unless the environment sets them: a
#: tracking server that does not answer costs seconds, not MLflow's default 120 s x 7 retries with backoff
HTTP_SETTINGS = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "5", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "1"}
#: the longest reason a warning quotes
MAX_REASON = 300

log = logging.getLogger("vitaplace")


def _flat(prefix: str, value: Any) -> dict[str, str]:
    """``value`` flattened into ``{dotted.key: text}``: a mapping by its keys, a list of
    mappings that all have a "name" by those names, anything else as JSON text (a string as
    itself; MLflow params are strings)."""
    if isinstance(value, Mapping):
        items = list(value.items())
    elif (isinstance(value, list) and value and all(isinstance(v, Mapping) and isinstance(v.get("name"), str)
                                                    for v in value)):
        items = [(v["name"], {k: x for k, x in v.items() if k != "name"}) for v in value]
    else:
        return {prefix: value if isinstance(value, str) else json.dumps(value)}
    flat: dict[str, str] = {}
    for key, inner in items:
        flat.update(_flat(f"{prefix}.{key}" if prefix else str(key), inner))
    return flat


def run_params(scenario: Any) -> dict[str, str]:
    """The MLflow params of a scenario: the resolved scenario flattened (`_flat`: ``seed``,
    ``train.run.n_samples``, ``evaluations.E1.run.kind``, ``scoring.tau``,
    ``methods.L.plugin``, ``methods.L.params.epochs``, ...), its name as ``scenario``."""
    params = _flat("", scenario.model_dump(mode="json"))
    return {"scenario": params.pop("name"), **params}


def run_metrics(rows: Sequence[ResultRow | Mapping[str, Any]]) -> dict[str, float]:
    """``ENVIRONMENT/METHOD/DIRECTION/METRIC`` -> value for every number of `METRICS` in
    ``rows`` (results rows, or mappings `parse_row` reads), and ``.../recall_at_K`` for each
    K of the row's recall@K (``scoring.recall_k``)."""
    metrics = {}
    for i, row in enumerate(rows):
        parsed = parse_row(row, f"results row {i}")
        where = f"{parsed.environment}/{parsed.method}/{parsed.direction}"
        values = {name: getattr(parsed, name) for name in METRICS}
        values.update({f"recall_at_{k}": v for k, v in (parsed.recall_at_k or {}).items()})
        metrics.update({f"{where}/{name}": float(v) for name, v in values.items() if v is not None})
    return metrics


def _digest(parts: Iterable[str | bytes]) -> str:
    """SHA-256 of ``parts``, each length-prefixed (so no two lists of parts share a digest)."""
    sha = hashlib.sha256()
    for part in parts:
        data = part.encode() if isinstance(part, str) else part
        sha.update(f"{len(data)}:".encode() + data)
    return sha.hexdigest()


def run_key(out: Path, stage: str) -> str:
    """What identifies a logged run: its folder, last stage, and the bytes of its results.json
    and scenario.resolved.yaml (a rerun that recomputed nothing has the same key)."""
    files = [(out / name).read_bytes() if (out / name).is_file() else b""
             for name in ("results.json", "scenario.resolved.yaml")]
    return _digest([str(out.resolve()), stage, *files])


def sweep_key(out: Path, scenario: Any, seeds: list[int], grid: Sequence[Any] = ()) -> str:
    """What identifies a sweep's parent run: its folder, its resolved scenario, its seeds and
    (on a grid) its points' names."""
    points = [json.dumps(sorted(point.name for point in grid))] if grid else []
    return _digest([str(Path(out).resolve()), scenario.model_dump_json(), json.dumps(sorted(seeds)), *points])


def grid_axes(grid: Sequence[Any]) -> dict[str, list[Any]]:
    """``--grid`` path -> its values in the order of the points (`GridPoint.values`)."""
    axes: dict[str, list[Any]] = {}
    for point in grid:
        for path, value in point.values.items():
            if value not in axes.setdefault(path, []):
                axes[path].append(value)
    return axes


def sweep_params(scenario: Any, seeds: list[int], grid: Sequence[Any] = ()) -> dict[str, str]:
    """A sweep's parent run's params: the scenario's (`run_params`) but ``seed``, and
    ``seeds``; on a grid only those every point shares (the varied keys' base values are no
    point's) and per ``--grid`` path ``grid.PATH``: its values (`grid_axes`), as JSON."""
    params = run_params(scenario)
    for point in grid:
        theirs = run_params(point.scenario)
        params = {k: v for k, v in params.items() if theirs.get(k) == v}
    params.pop("seed", None)
    params.update({f"grid.{path}": json.dumps(values) for path, values in grid_axes(grid).items()})
    return {**params, "seeds": json.dumps(list(seeds))}


def run_name(out: Path, scenario: Any) -> str:
    """A run's name: ``<scenario> seed <s>``; a grid seed's ``<point>-seed<s>`` (its folder,
    ``SWEEP/<point>/seed-<s>``, under the sweep's in `SWEEP_ENV`)."""
    sweep = os.environ.get(SWEEP_ENV)
    if sweep and Path(out).resolve().parent.parent == Path(sweep).resolve():
        return f"{Path(out).resolve().parent.name}-seed{scenario.seed}"
    return f"{scenario.name} seed {scenario.seed}"


def _client() -> tuple[Any, Any] | None:
    """MLflow's module and a client at its tracking URI, or None (one warning) when MLflow is not installed."""
    try:
        import mlflow
        from mlflow.tracking import MlflowClient
    except ImportError:
        log.warning("%s=%s but MLflow is not installed (pip install \"vitaplace[mlflow]\"): not logged",
                    EXPERIMENT_ENV, os.environ.get(EXPERIMENT_ENV))
        return None
    return mlflow, MlflowClient()


@contextlib.contextmanager
def _tracking(what: str) -> Iterator[None]:
    """MLflow calls with `HTTP_SETTINGS` where the environment does not set them (as it was
    after); an exception among them is one warning that ``what`` was not logged, and stops
    there: the results it would have logged are written already."""
    unset = [name for name in HTTP_SETTINGS if name not in os.environ]
    os.environ.update({name: HTTP_SETTINGS[name] for name in unset})
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - a tracker that cannot log must not fail a finished run
        reason = " ".join(f"{type(exc).__name__}: {exc}".split())
        log.warning("MLflow: %s not logged (tracking URI %s): %s", what,
                    os.environ.get("MLFLOW_TRACKING_URI", "MLflow's default"),
                    reason if len(reason) <= MAX_REASON else reason[: MAX_REASON - 3] + "...")
    finally:
        for name in unset:
            os.environ.pop(name, None)


def _experiment_id(client: Any, name: str) -> str:
    """The id of experiment ``name``, created when missing (by whichever seed gets there first)."""
    found = client.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    try:
        return client.create_experiment(name)
    except Exception:  # noqa: BLE001 - another process created it meanwhile
        found = client.get_experiment_by_name(name)
        if found is None:
            raise
        return found.experiment_id


def _logged(client: Any, experiment_id: str, key: str) -> Any | None:
    """The run of ``experiment_id`` tagged with ``key`` (`KEY_TAG`), or None."""
    runs = client.search_runs([experiment_id], filter_string=f"tags.`{KEY_TAG}` = '{key}'", max_results=1)
    return runs[0] if runs else None


def _log_params(client: Any, run_id: str, params: Mapping[str, str]) -> None:
    """Log ``params``; one whose text is longer than MLflow takes (its ``MAX_PARAM_VAL_LENGTH``)
    is left out and named in the tag `SKIPPED_TAG` (scenario.resolved.yaml, an artifact, has it)."""
    from mlflow.entities import Param
    from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH

    items = [Param(k, v) for k, v in params.items() if len(v) <= MAX_PARAM_VAL_LENGTH]
    skipped = [k for k, v in params.items() if len(v) > MAX_PARAM_VAL_LENGTH]
    if skipped:
        client.set_tag(run_id, SKIPPED_TAG, " ".join(skipped))
    for start in range(0, len(items), 100):  # MLflow takes at most 100 params per batch
        client.log_batch(run_id, params=items[start:start + 100])


def source_tags() -> dict[str, str]:
    """MLflow's source tags (its UI's "Source" column): vitaplace, run locally (a finished
    run adds ``mlflow.source.git.commit``, `_manifest_tags`)."""
    return {"mlflow.source.name": "vitaplace", "mlflow.source.type": "LOCAL"}


def _manifest_tags(out: Path, stage: str) -> dict[str, str]:
    manifest_path = out / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    return {"vitaplace.version": str(manifest.get("vitaplace_version")), "vitaplace.stage": stage,
            "git.commit": str(manifest.get("git_commit")), "git.dirty": str(manifest.get("git_dirty")),
            "vitaplace.out": str(out.resolve()),
            **({"mlflow.source.git.commit": manifest["git_commit"]} if manifest.get("git_commit") else {})}


#: this process's runs in progress: output folder (resolved) -> the id of the MLflow run
#: `vitaplace_run_started` opened for it ("" when opening it failed: warned once, not tried again)
_open: dict[str, str] = {}


@hookimpl
def vitaplace_run_started(out: Path, scenario: Any) -> None:
    """Open the run's MLflow run (RUNNING, with its params) in the experiment named by
    ``VITAPLACE_MLFLOW`` (if set), nested under the sweep's parent run when `PARENT_ENV` is set."""
    experiment = os.environ.get(EXPERIMENT_ENV)
    if not experiment or (found := _client()) is None:
        return
    where = str(Path(out).resolve())
    _open[where] = ""
    with _tracking(f"the run in {out}"):
        _open[where] = _start_run(found[1], experiment, Path(out), scenario)


def _start_run(client: Any, experiment: str, out: Path, scenario: Any) -> str:
    """`vitaplace_run_started`'s MLflow calls; the run's id."""
    tags = {**source_tags(), "vitaplace.version": __version__, "vitaplace.out": str(out.resolve())}
    if os.environ.get(PARENT_ENV):
        tags[PARENT_TAG] = os.environ[PARENT_ENV]
    run_id = client.create_run(_experiment_id(client, experiment), run_name=run_name(out, scenario),
                               tags=tags).info.run_id
    _log_params(client, run_id, run_params(scenario))
    return str(run_id)


#: the runs whose per-epoch logging failed once (warned): not tried again for their other epochs
_epochs_off: set[str] = set()


@hookimpl
def vitaplace_training_epoch(out: Path, method: str, epoch: int, numbers: dict[str, float]) -> None:
    """Log one training epoch's ``numbers`` into the run's open MLflow run as it ends:
    ``training/METHOD/NAME`` at step ``epoch``."""
    where = str(Path(out).resolve())
    run_id = _open.get(where, "")
    if not run_id or where in _epochs_off or (found := _client()) is None:
        return
    _epochs_off.add(where)  # until this epoch is logged: a failure warns once, not once per epoch
    with _tracking(f"training epochs of {method} in {out}"):
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        found[1].log_batch(run_id, metrics=[Metric(f"training/{method}/{name}", float(value), now, epoch)
                                            for name, value in numbers.items()])
        _epochs_off.discard(where)


@hookimpl
def vitaplace_run_failed(out: Path, scenario: Any, error: str) -> None:
    """End the run's MLflow run FAILED, ``error`` in its tag `ERROR_TAG`."""
    run_id = _open.pop(str(Path(out).resolve()), "")
    if not run_id or (found := _client()) is None:
        return
    with _tracking(f"the failure of the run in {out}"):
        from mlflow.utils.validation import MAX_TAG_VAL_LENGTH

        found[1].set_tag(run_id, ERROR_TAG, error[:MAX_TAG_VAL_LENGTH])
        found[1].set_terminated(run_id, "FAILED")


@hookimpl
def vitaplace_run_finished(out: Path, scenario: Any, rows: Sequence[ResultRow | Mapping[str, Any]], stage: str) -> None:
    """Log the finished run into the MLflow run `vitaplace_run_started` opened and end it
    FINISHED; a run whose results are logged already (`run_key`) is deleted instead."""
    run_id = _open.pop(str(Path(out).resolve()), "")
    if not run_id or (found := _client()) is None:
        return
    with _tracking(f"the run in {out}"):
        _log_run(*found, run_id, Path(out), rows, stage)


def _log_run(mlflow: Any, client: Any, run_id: str, out: Path, rows: Sequence[ResultRow | Mapping[str, Any]],
             stage: str) -> None:
    """`vitaplace_run_finished`'s MLflow calls."""
    from mlflow.entities import Metric, RunTag

    try:
        key = run_key(out, stage)
        earlier = _logged(client, client.get_run(run_id).info.experiment_id, key)
        if earlier is not None:
            client.delete_run(run_id)
            log.info("MLflow: %s is logged already (run %s): not logged again", out, earlier.info.run_id)
            return
        tags = {**_manifest_tags(out, stage), KEY_TAG: key}
        client.log_batch(run_id, tags=[RunTag(k, v) for k, v in tags.items()])
        metrics = run_metrics(rows)
        if metrics:
            now = int(time.time() * 1000)
            client.log_batch(run_id, metrics=[Metric(k, v, now, 0) for k, v in metrics.items()])
        for name in ARTIFACTS:
            if (out / name).is_file():
                client.log_artifact(run_id, str(out / name))
        if (out / "figures").is_dir():
            client.log_artifacts(run_id, str(out / "figures"), artifact_path="figures")
    except BaseException:
        client.set_terminated(run_id, "FAILED")
        raise
    client.set_terminated(run_id, "FINISHED")
    log.info("logged to MLflow: run %s (%s)", run_id, mlflow.get_tracking_uri())


@hookimpl
def vitaplace_sweep_started(out: Path, scenario: Any, seeds: list[int], grid: list[Any]) -> dict[str, str] | None:
    """Open (or, for a rerun of the same sweep, find) the sweep's parent run; the variables
    every seed needs to log into it: the experiment, MLflow's settings (the tracking URI
    resolved here, so a Ray worker in another folder logs into the same store) and the parent."""
    experiment = os.environ.get(EXPERIMENT_ENV)
    if not experiment or (found := _client()) is None:
        return None
    mlflow, client = found
    env = {k: v for k, v in os.environ.items() if k.startswith("MLFLOW_")}  # the user's, not `_tracking`'s
    asked = {EXPERIMENT_ENV: ""}  # a store that failed here: the seeds do not try it, each for its own warning
    with _tracking(f"the sweep in {out} (nor its seeds)"):
        parent = _parent_run(client, experiment, out, scenario, seeds, grid)
        asked = {**env, "MLFLOW_TRACKING_URI": mlflow.get_tracking_uri(), EXPERIMENT_ENV: experiment,
                 PARENT_ENV: parent, SWEEP_ENV: str(Path(out).resolve())}
    return asked


def _parent_run(client: Any, experiment: str, out: Path, scenario: Any, seeds: list[int], grid: list[Any]) -> str:
    """The id of the sweep's parent run, opened unless a rerun of the same sweep finds it."""
    experiment_id, key = _experiment_id(client, experiment), sweep_key(out, scenario, seeds, grid)
    parent = _logged(client, experiment_id, key)
    if parent is None:
        tags = {**source_tags(), "vitaplace.version": __version__, "vitaplace.stage": "sweep",
                "vitaplace.out": str(Path(out).resolve()), KEY_TAG: key}
        name = f"{scenario.name} {'grid' if grid else 'sweep'}, seeds {' '.join(map(str, seeds))}"
        parent = client.create_run(experiment_id, run_name=name, tags=tags)
        _log_params(client, parent.info.run_id, sweep_params(scenario, seeds, grid))
    return str(parent.info.run_id)


@hookimpl
def vitaplace_sweep_finished(out: Path, scenario: Any, seeds: list[int], failed: dict[int | str, str],
                             environment: dict[str, str]) -> None:
    """Log the sweep's summary files and PR bands to its parent run (not again when its
    sweep.json, or a grid's grid.json, is the one logged last) and end the run: FAILED when a
    seed failed."""
    parent = environment.get(PARENT_ENV)
    if not parent or (found := _client()) is None:
        return
    with _tracking(f"the summary of the sweep in {out}"):
        _log_sweep(found[1], parent, Path(out), seeds, failed)


def _log_sweep(client: Any, parent: str, out: Path, seeds: list[int], failed: dict[int | str, str]) -> None:
    """`vitaplace_sweep_finished`'s MLflow calls."""
    summaries = [(out / name).read_bytes() for name in ("sweep.json", "grid.json") if (out / name).is_file()]
    summary = _digest(summaries) if summaries else ""
    client.set_terminated(parent, "FAILED" if failed else "FINISHED")
    if client.get_run(parent).data.tags.get(SUMMARY_TAG) == summary:
        log.info("MLflow: this sweep's summary is logged already (run %s): not logged again", parent)
        return
    for name in SWEEP_FILES:
        if (out / name).is_file():
            client.log_artifact(parent, str(out / name))
    for figure in sorted(out.glob("pr-bands-*")):
        client.log_artifact(parent, str(figure), artifact_path="pr-bands")
    client.set_tag(parent, SUMMARY_TAG, summary)
    log.info("logged the sweep to MLflow: run %s, %d seed(s)%s", parent, len(seeds),
             f", {len(failed)} failed" if failed else "")
