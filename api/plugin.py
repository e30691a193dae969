"""The plugin API in one import: everything a feature-extractor plugin needs (docs/plugins.md).

    from vitaplace.plugin import ExtractorParams, FeatureExtractor, Features, Run, hookimpl

This module is the stable home of these names: they stay importable from here whatever
module of the engine defines them, and the shipped plugins import them from here (the public
names are listed in docs/API.md, "Stable import paths").
`vitaplace.testing.check_extractor` checks a plugin against the interface's contract.
"""

from __future__ import annotations

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension.features import (
    TACTILE,
    VISUAL,
    ExtractorParams,
    ExtractorParamsError,
    FeatureExtractor,
    Features,
    warn_once,
)
from vitaplace.engine.extension.hookspecs import hookimpl
from vitaplace.engine.extension.registry import discover

__all__ = ["ExtractorParams", "ExtractorParamsError", "FeatureExtractor", "Features", "Run", "TACTILE", "VISUAL",
           "discover", "hookimpl", "warn_once"]
