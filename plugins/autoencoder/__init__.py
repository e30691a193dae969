"""Built-in plugin: the backprop control of MuPNet (``autoencoder``)."""

from collections.abc import Callable

from vitaplace.plugin import FeatureExtractor, hookimpl
from vitaplace.plugins.autoencoder.extractor import AutoencoderExtractor


@hookimpl
def vitaplace_register_features(register: Callable[[type[FeatureExtractor]], None]) -> None:
    register(AutoencoderExtractor)
