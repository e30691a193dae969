"""The plugin API in one import: everything a feature-extractor plugin needs (docs/plugins.md).

    from vitaplace.plugin import ExtractorParams, FeatureExtractor, Features, Run, hookimpl

This module is the stable home of these names: they stay importable from here whatever
module of the engine defines them. The engine paths that docs/plugins.md's example uses
(``vitaplace.engine.data.dataset.Run``, ``vitaplace.engine.features.FeatureExtractor``, ...) keep
working too and name the same objects. `vitaplace.testing.check_extractor` checks a plugin
against the interface's contract.
"""

from __future__ import annotations

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.features import ExtractorParams, ExtractorParamsError, FeatureExtractor, Features, warn_once
from vitaplace.engine.hookspecs import hookimpl

__all__ = ["ExtractorParams", "ExtractorParamsError", "FeatureExtractor", "Features", "Run", "hookimpl", "warn_once"]
