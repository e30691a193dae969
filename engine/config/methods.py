"""The scenario's methods checked against the installed plugins: each names a registered
feature extractor and gives parameters that extractor accepts, and handles missing
modalities when an evaluation has a query drop-out; and which of them pair as vision-only
and touch-only (`complementarity_pairs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vitaplace.engine.config.scenario import Scenario, ScenarioError
from vitaplace.engine.extension.features import TACTILE, VISUAL, ExtractorParamsError
from vitaplace.engine.extension.registry import PluginError, Registry, discover


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
    for method, (extractor, _) in zip(scenario.methods, checked, strict=True):
        if dropouts and not getattr(extractor, "handles_missing", False):
            raise ScenarioError(
                f"{path}: evaluations.{dropouts[0]}.query_dropout: method {method.name}'s extractor "
                f"'{method.plugin}' does not handle missing modalities (its handles_missing is false; "
                "docs/plugins.md): leave it out of this scenario or drop query_dropout"
            )
    return checked


def complementarity_pairs(scenario: Scenario, registry: Registry) -> list[tuple[str, str]]:
    """The (vision method, touch method) pairs whose complementarity is measured: every
    vision-only with every touch-only method of the same plugin, as the plugin declares its
    configurations' senses (`FeatureExtractor.modalities`; one that says nothing is never
    paired), in the order of ``methods``, then the pairs ``scoring.complementarity`` names;
    each pair once."""
    senses = {}
    for method in scenario.methods:
        extractor = registry.get(method.plugin)
        senses[method.name] = (method.plugin, extractor.modalities(extractor.validate_params(method.params)))
    found = [(v, t) for v, (v_plugin, v_senses) in senses.items() for t, (t_plugin, t_senses) in senses.items()
             if v_plugin == t_plugin and v_senses == frozenset({VISUAL}) and t_senses == frozenset({TACTILE})]
    found += [(pair.vision, pair.touch) for pair in scenario.scoring.complementarity]
    return list(dict.fromkeys(found))
