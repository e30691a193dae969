"""A VLAD (dense SIFT aggregated on a k-means vocabulary) vision baseline as a vitaplace feature plugin.

Registered through the entry point ``vlad`` of the group ``vitaplace.features``; it needs the
extra ``vision`` (OpenCV).
"""

from __future__ import annotations

from collections.abc import Callable

from vitaplace.plugin import FeatureExtractor, hookimpl

from .extractor import VladExtractor, VladParams

__all__ = ["VladExtractor", "VladParams", "vitaplace_register_features"]


@hookimpl
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    register(VladExtractor)
