"""The scenario's methods checked against the installed plugins: each names a registered
feature extractor and gives parameters that extractor accepts, and handles missing
modalities when an evaluation has a query drop-out; the ``vision`` and ``touch`` roles of
fusions and complementarity pairs given a vision-only and a touch-only method (as far as
their plugins declare their senses); and which of them pair as vision-only and touch-only
(`complementarity_pairs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vitaplace.engine.config.scenario import ComplementarityPair, Fusion, Scenario, ScenarioError
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
    _check_roles(path, scenario, {m.name: extractor.modalities(params)
                                  for m, (extractor, params) in zip(scenario.methods, checked, strict=True)})
    return checked


#: the one sense a method in each role of a fusion or complementarity pair uses
ROLE_SENSES = {"vision": VISUAL, "touch": TACTILE}


def _check_roles(path: Path, scenario: Scenario, senses: dict[str, frozenset[str] | None]) -> None:
    """Each fusion's and complementarity pair's ``vision`` method uses vision alone and its
    ``touch`` method touch alone, as their plugins declare (`FeatureExtractor.modalities`):
    a touch-only method as the vision half would report touch rescuing touch, and a method
    with both senses would make "vision code + w touch code" a joint code. A method whose
    plugin declares nothing (None) cannot be checked and is accepted."""
    roles: list[tuple[str, ComplementarityPair | Fusion]] = [
        (f"scoring.complementarity.{i}", pair) for i, pair in enumerate(scenario.scoring.complementarity)]
    roles += [(f"fusions.{i}", fusion) for i, fusion in enumerate(scenario.fusions)]
    plugins = {m.name: m.plugin for m in scenario.methods}
    for where, entry in roles:
        for role, sense in ROLE_SENSES.items():
            method = getattr(entry, role)
            declared = senses[method]
            if declared is not None and declared != {sense}:
                said = " and ".join(sorted(declared, key=lambda s: (s != VISUAL, s))) or "no sense"
                raise ScenarioError(
                    f"{path}: {where}.{role}: method {method} uses {said} (as its plugin '{plugins[method]}' declares "
                    f"it); the {role} method needs {sense} alone (a {role}-only method)")


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
