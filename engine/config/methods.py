"""The scenario's methods checked against the installed plugins: each names a registered
feature extractor and gives parameters that extractor accepts, and handles missing
modalities when an evaluation has a query drop-out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vitaplace.engine.config.scenario import Scenario, ScenarioError
from vitaplace.engine.extension.features import ExtractorParamsError
from vitaplace.engine.extension.registry import PluginError, discover


def check_methods(path: Path, scenario: Scenario) -> list[tuple[Any, Any]]:
    """Each method's extractor class and validated parameters (errors name the method)."""
    registry = discover()
    checked = []
    for i, method in enumerate(scenario.methods):
        try:
            extractor = registry.get(method.plugin)
            checked.append((extractor, extractor.validate_params(method.params)))
        except PluginError as exc:
            raise ScenarioError(f"{path}: methods.{i}.plugin: {exc}") from None
        except ExtractorParamsError as exc:
            raise ScenarioError(f"{path}: methods.{i}.params: {exc}") from None
    dropouts = [i for i, e in enumerate(scenario.evaluations) if e.query_dropout is not None]
    for method, (extractor, _) in zip(scenario.methods, checked):
        if dropouts and not getattr(extractor, "handles_missing", False):
            raise ScenarioError(
                f"{path}: evaluations.{dropouts[0]}.query_dropout: method {method.name}'s extractor "
                f"'{method.plugin}' does not handle missing modalities (its handles_missing is false; "
                "docs/plugins.md): leave it out of this scenario or drop query_dropout"
            )
    return checked
