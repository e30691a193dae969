"""vitaplace engine: predictive-coding network, backends, simulation, datasets, evaluation, CLI."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vitaplace")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
