"""Import path kept for plugins written against earlier docs: the feature-extractor interface lives in
`vitaplace.engine.extension.features`; plugins import what they need from `vitaplace.plugin`."""

from typing import Any

from vitaplace.engine.extension import features as _home


def __getattr__(name: str) -> Any:
    return getattr(_home, name)
