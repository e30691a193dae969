"""Import path kept for plugins written against earlier docs: the plugin registry lives in
`vitaplace.engine.extension.registry`; plugins import what they need from `vitaplace.plugin`."""

from typing import Any

from vitaplace.engine.extension import registry as _home


def __getattr__(name: str) -> Any:
    return getattr(_home, name)
