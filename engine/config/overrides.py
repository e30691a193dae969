"""``--set`` overrides: ``key.path=value`` assignments and ``key.path+=value`` appends applied
to a scenario's mapping before it is validated."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import yaml

from vitaplace.engine.config.scenario import ScenarioError, current_key


def apply_overrides(data: dict[str, Any], assignments: Sequence[str], source: str = "--set") -> dict[str, Any]:
    """Apply ``key.path=value`` assignments (value parsed as YAML; list items by index) and
    ``key.path+=value`` appends (to a list the scenario sets; anything else is an error)."""
    data = copy.deepcopy(data)
    for assignment in assignments:
        key, sep, raw = assignment.partition("=")
        append = key.endswith("+")
        key = key.removesuffix("+")
        if not sep or not key:
            raise ScenarioError(f"{source} '{assignment}': expected key.path=value or key.path+=value")
        first, dot, rest = key.partition(".")
        key = current_key(first, f"{source} '{assignment}'") + dot + rest
        try:
            value = yaml.safe_load(raw) if raw else ""
        except yaml.YAMLError as exc:
            problem = getattr(exc, "problem", None) or type(exc).__name__
            raise ScenarioError(f"{source} '{assignment}': the value is not YAML ({problem}); a text with YAML's "
                                "special characters needs quotes") from None
        node: Any = data
        parts = key.split(".")
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise ScenarioError(f"{source} '{assignment}': '{'.'.join(parts[:i])}' has no item {part}")
                index: Any = int(part)
            else:
                index = part
            if last and append:
                target = node[index] if isinstance(node, list) or index in node else None
                if not isinstance(target, list):
                    what = "not set in the scenario" if target is None else f"a {type(target).__name__}, not a list"
                    raise ScenarioError(f"{source} '{assignment}': '{key}' is {what}; += appends to a list")
                target.append(value)
            elif last:
                node[index] = value
            else:
                if not isinstance(node, list) and not isinstance(node.get(index), (dict, list)):
                    node[index] = {}
                node = node[index]
    return data
