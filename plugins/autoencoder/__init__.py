"""Built-in plugin: the backprop control of MuPNet (``autoencoder``)."""

from vitaplace.plugin import hookimpl
from vitaplace.plugins.autoencoder.extractor import AutoencoderExtractor


@hookimpl
def vitaplace_register_features(register) -> None:
    register(AutoencoderExtractor)
