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
def vitaplace_run_finished(out: Path, scenario: Any, rows: list[dict[str, Any]], stage: str) -> None:
    """A scenario's pipeline finished (``scenario``: its validated
    `vitaplace.engine.config.scenario.Scenario`, a floor above this module): every stage up
    to ``stage`` is done and ``out`` holds
    its outputs (manifest.json, scenario.resolved.yaml; from the evaluate stage on
    results.json/.csv with ``rows``, their rows; after the report stage report.md and
    figures/). For trackers and notifications (e.g. `vitaplace.plugins.mlflow_tracking`).

    Called in the process that ran the pipeline (for a sweep: once per seed, in its worker).
    An exception is logged as a warning naming the plugin and does not fail the run.
    """
