"""Pluggy hook specifications of the ``vitaplace`` namespace (documented in docs/plugins.md)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pluggy

from vitaplace.engine.extension.features import FeatureExtractor

PROJECT = "vitaplace"
#: Entry-point group through which packages (built-in ones included) contribute plugins.
ENTRY_POINT_GROUP = "vitaplace.features"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    """Contribute feature extractors: call ``register(ExtractorClass)`` once per extractor.

    One plugin module may register several extractors. Each class needs a unique ``name``.
    """


@hookspec
def vitaplace_run_started(out: Path, scenario: Any) -> None:
    """A scenario's pipeline is starting in ``out`` (its scenario.resolved.yaml written,
    nothing computed yet); ``scenario``: its validated Scenario. Then exactly one of
    `vitaplace_run_finished` and `vitaplace_run_failed` follows, in the same process. For
    trackers that show a run while it runs. An exception is logged as a warning naming the
    plugin and does not stop the run.
    """


@hookspec
def vitaplace_training_epoch(out: Path, method: str, epoch: int, numbers: dict[str, float]) -> None:
    """Method ``method`` of the pipeline in ``out`` finished training epoch ``epoch`` (from 1)
    with ``numbers`` (by name, as its plugin reports them: MuPNet's ``energy``,
    ``held_out_energy``, ``latent_change``, ...), called as each epoch ends, in the process
    that fits, between `vitaplace_run_started` and the run's end; never for a model found in
    the cache. For trackers that plot training live. An exception is logged as a warning
    naming the plugin and does not stop training.
    """


@hookspec
def vitaplace_run_failed(out: Path, scenario: Any, error: str) -> None:
    """A scenario's pipeline in ``out`` raised ``error`` (``Type: message``, one line); the
    exception goes on to the caller after the hooks (for a sweep's seed: the seed fails). An
    exception in a hook is logged as a warning naming the plugin.
    """


@hookspec
def vitaplace_run_finished(out: Path, scenario: Any, rows: list[dict[str, Any]], stage: str) -> None:
    """A scenario's pipeline finished (``scenario``: its validated
    `vitaplace.engine.config.scenario.Scenario`, a floor above this module): every stage up
    to ``stage`` is done and ``out`` holds
    its outputs (manifest.json, scenario.resolved.yaml; from the evaluate stage on
    results.json/.csv with ``rows``, their rows; after the report stage report.md and
    figures/) and its completion record (completed.json): the run is finished before any hook
    is called. For trackers and notifications (e.g. `vitaplace.plugins.mlflow_tracking`).

    Called in the process that ran the pipeline (for a sweep: once per seed, in its worker).
    An exception is logged as a warning naming the plugin and does not fail the run.
    """


@hookspec
def vitaplace_sweep_started(out: Path, scenario: Any, seeds: list[int], grid: list[Any]) -> dict[str, str] | None:
    """A sweep (`vitaplace sweep`) is about to run ``seeds`` of ``scenario`` into ``out``
    (``grid``: on a grid, ``--grid``, its points, each a
    `vitaplace.engine.study.grid.GridPoint` with its folder name, its value per ``--grid``
    path and its scenario; else empty); called in the driver before any seed starts. Return
    the environment variables every seed's process needs (e.g. a tracker's parent run), or
    None. The driver sets them in its own environment while the seeds run, which its local
    workers and SLURM's tasks inherit, and gives them to each Ray task (its ``runtime_env``).
    An exception is logged as a warning naming the plugin and does not stop the sweep.
    """


@hookspec
def vitaplace_sweep_finished(out: Path, scenario: Any, seeds: list[int], failed: dict[int | str, str],
                             environment: dict[str, str]) -> None:
    """A sweep ended: ``out`` holds the summary of ``seeds`` (those that succeeded; sweep.json,
    sweep.csv, sweep-seeds.csv, sweep-diff.csv, sweep.md, sweep.tex and the pr-bands-*
    figures; a grid's, ``vitaplace sweep --grid``: grid.json, grid.csv and grid.md, and each
    point's summary in its folder ``out/<point>``); ``failed``: seed (on a grid:
    ``<point>/seed-<s>``) -> its one-line failure; ``environment``: the variables the
    `vitaplace_sweep_started` hooks asked for. Called in the driver; an exception is logged
    as a warning naming the plugin.
    """
