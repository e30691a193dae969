"""Pluggy hook specifications of the ``vitaplace`` namespace (documented in docs/plugins.md)."""

from __future__ import annotations

from collections.abc import Callable

import pluggy

from vitaplace.engine.features import FeatureExtractor

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
