"""ViTa-SLAM's hand-crafted visuo-tactile front end as a vitaplace feature plugin.

Registered through the entry point ``handcrafted`` of the group ``vitaplace.features``.
"""

from __future__ import annotations

from collections.abc import Callable

from vitaplace.plugin import FeatureExtractor, hookimpl

from .extractor import HandcraftedExtractor, HandcraftedParams
from .pfh import pfh, pfh_batch
from .profile import template_distance, templates
from .sda import sda

__all__ = [
    "HandcraftedExtractor",
    "HandcraftedParams",
    "pfh",
    "pfh_batch",
    "sda",
    "template_distance",
    "templates",
    "vitaplace_register_features",
]


@hookimpl
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    register(HandcraftedExtractor)
