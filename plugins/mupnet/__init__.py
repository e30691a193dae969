"""Built-in plugin: learned MuPNet features (``mupnet``)."""

from vitaplace.plugin import hookimpl
from vitaplace.plugins.mupnet.extractor import MupnetExtractor


@hookimpl
def vitaplace_register_features(register) -> None:
    register(MupnetExtractor)
