"""A HOG (histogram of oriented gradients) vision baseline as a vitaplace feature plugin.

Registered through the entry point ``hog`` of the group ``vitaplace.features``; it needs the
extra ``vision`` (scikit-image).
"""

from __future__ import annotations

from collections.abc import Callable

from vitaplace.plugin import FeatureExtractor, hookimpl

from .extractor import HogExtractor, HogParams

__all__ = ["HogExtractor", "HogParams", "vitaplace_register_features"]


@hookimpl
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    register(HogExtractor)
