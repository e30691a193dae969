"""Built-in plugin: learned MuPNet features (``mupnet``)."""

from collections.abc import Callable

from vitaplace.plugin import FeatureExtractor, hookimpl
from vitaplace.plugins.mupnet.extractor import MupnetExtractor


@hookimpl
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    register(MupnetExtractor)
