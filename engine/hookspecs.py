"""Import path kept for plugins written against earlier docs: the plugin hooks lives in
`vitaplace.engine.extension.hookspecs`; plugins import what they need from `vitaplace.plugin`."""

from typing import Any

from vitaplace.engine.extension import hookspecs as _home


def __getattr__(name: str) -> Any:
    return getattr(_home, name)
