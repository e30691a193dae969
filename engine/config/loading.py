"""Loading a scenario: find the file (a path, or a shipped scenario's name), merge what it
``extends``, make the paths it names absolute, apply ``--set`` overrides, validate the schema,
then check its runs, methods and memory needs, so that every error surfaces here."""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pydantic

from vitaplace.engine.base.configfile import format_validation_error, load_yaml, local_or_shipped
from vitaplace.engine.base.shipped import SCENARIOS_DIR, shipped_file, shipped_names_hint
from vitaplace.engine.config.inputs import check_runs
from vitaplace.engine.config.memory import check_memory, physical_memory
from vitaplace.engine.config.methods import check_methods
from vitaplace.engine.config.overrides import apply_overrides
from vitaplace.engine.config.scenario import Scenario, ScenarioError, rename_legacy_keys

log = logging.getLogger("vitaplace")


def resolve_path(name: str | Path) -> Path:
    """A scenario path as given, or the name of a built-in scenario (``quickstart``)."""
    path = Path(name)
    if path.exists():
        return path
    shipped = shipped_file(path, (SCENARIOS_DIR,))
    if shipped is None:
        raise ScenarioError(f"{name}: no such scenario file ({shipped_names_hint(name, 'scenarios')})")
    return shipped


def load_scenario(name: str | Path, overrides: Sequence[str] = ()) -> tuple[Scenario, dict[str, Any]]:
    """Read, merge, override and validate a scenario; also return the resolved raw mapping.

    Environment files and method plugins are checked too, so every error surfaces here.
    """
    path = resolve_path(name)
    log.debug("scenario %s: file %s, %d override(s)", name, path.resolve(), len(overrides))
    raw = load_raw(path)
    if overrides:  # an override's environment or run-file path: from the working folder, or a shipped name
        raw = _absolute_paths(apply_overrides(raw, overrides), Path.cwd())
    try:
        scenario = Scenario.model_validate(raw)
    except pydantic.ValidationError as exc:
        raise ScenarioError(format_validation_error(path, exc, Scenario)) from None
    train_samples = check_runs(path, scenario)
    params = check_methods(path, scenario)
    check_memory(path, scenario, params, physical_memory(), train_samples)
    return scenario, raw


def load_raw(path: Path) -> dict[str, Any]:
    """The scenario mapping with ``extends`` merged, renamed keys under their new names and
    environment paths made absolute."""
    return load_yaml(path, ScenarioError, _prepared)


def _prepared(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """One scenario file's own mapping with renamed keys under their new names and its paths
    absolute."""
    return _absolute_paths(rename_legacy_keys(data, str(path)), path.parent)


def _map_paths(data: dict[str, Any], change: Callable[[str, str], str]) -> dict[str, Any]:
    """``data`` with each environment and run-file path of its runs replaced by
    ``change(key, path)`` (key: ``environment``, ``dataset``, ``query`` or ``reference``)."""

    def fix(entry: Any, keys: tuple[str, ...] = ("environment", "dataset")) -> None:
        for key in keys if isinstance(entry, dict) else ():
            if isinstance(entry.get(key), str):
                entry[key] = change(key, entry[key])
        if isinstance(entry, dict) and "datasets" in keys:
            fix(entry.get("datasets"), ("query", "reference"))

    fix(data.get("train"))
    evaluations = data.get("evaluations")
    for entry in evaluations if isinstance(evaluations, list) else []:  # anything else: the schema says why
        fix(entry, ("environment", "datasets"))
    return data


def _absolute_paths(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """Environment and run-file paths are relative to the file that names them."""

    def absolute(key: str, path: str) -> str:
        # an environment: a shipped name (e1) when no such file is next to the scenario
        return str(_resolved(local_or_shipped(folder, path, key) if key == "environment" else folder / path))

    return _map_paths(data, absolute)


def relative_paths(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """A copy of the resolved scenario mapping ``data`` with each environment and run-file path
    inside ``folder`` relative to it; the others as they are. A scenario file in ``folder``
    reads its paths from there (`load_scenario`), so it names the same files, wherever the
    folder is moved."""
    base = _resolved(Path(folder))

    def relative(key: str, path: str) -> str:
        where = _resolved(Path(path))
        return where.relative_to(base).as_posix() if where.is_relative_to(base) else path

    return _map_paths(copy.deepcopy(data), relative)


def _resolved(path: Path) -> Path:
    """``path`` absolute with its links followed; a link loop stays as it is (the file check
    then reports it as missing instead of Python raising)."""
    try:
        return path.resolve()
    except (RuntimeError, OSError):
        return path.absolute()
