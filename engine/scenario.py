"""Scenario files: what to simulate, which methods to compare, how to evaluate (DESIGN §11).

A scenario is YAML validated by pydantic before anything runs. ``extends: other.yaml``
(relative to the file) deep-merges the file over another scenario. Errors name the file,
the key path and what was expected, and suggest the nearest valid key for a typo.

Example::

    name: quickstart
    seed: 0
    train:
      environment: environments/e1.yaml
      run: {kind: foraging, n_samples: 300}
    evaluations:
      - name: E1
        environment: environments/e1.yaml
        run: {kind: route, n_samples: 120}
    methods:
      - {name: L, plugin: mupnet, params: {epochs: 5}}
      - {name: H, plugin: handcrafted}
    evaluation: {tau: 0.3}
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import json
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pydantic
import yaml

from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.robot import RobotSpec
from vitaplace.engine.sim.simulate import RunSpec

BUILTIN_DIR = Path(__file__).resolve().parent.parent / "scenarios"


class ScenarioError(ValueError):
    """A scenario that cannot run; the message is one line naming file, key path and problem."""


class Strict(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")


class SimulatedRun(Strict):
    """One recorded run: an environment file and how the robot moves in it."""

    environment: Path
    run: RunSpec


class EvaluationRuns(SimulatedRun):
    """An evaluation environment: two noisy runs along the same route (query and reference)."""

    name: str = pydantic.Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")


class Method(Strict):
    """A feature extractor to compare: a label, the plugin's extractor name, its parameters."""

    name: str = pydantic.Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    plugin: str
    params: dict[str, Any] = {}


class EvaluationSettings(Strict):
    tau: float = pydantic.Field(0.3, ge=0, description="ground-truth revisit tolerance [m]")
    heading_weight: float = pydantic.Field(0.0, ge=0, description="GTM += weight * |yaw difference| [m/rad]")
    delta: float | None = pydantic.Field(None, description="fixed acceptance threshold for the F1 at delta")
    recall_k: list[pydantic.PositiveInt] = [1, 5, 10]
    direction: typing.Literal["query-to-reference", "reference-to-query", "both"] = "query-to-reference"


class Scenario(Strict):
    name: str = pydantic.Field(min_length=1)
    description: str = ""
    seed: int = 0
    robot: RobotSpec = RobotSpec()
    train: SimulatedRun
    evaluations: list[EvaluationRuns] = pydantic.Field(min_length=1)
    methods: list[Method] = pydantic.Field(min_length=1)
    evaluation: EvaluationSettings = EvaluationSettings()

    @pydantic.model_validator(mode="after")
    def _unique_names(self) -> Scenario:
        for what, items in (("methods", self.methods), ("evaluations", self.evaluations)):
            names = [item.name for item in items]
            if len(set(names)) != len(names):
                raise ValueError(f"{what}: names must be unique, got {names}")
        return self


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` over ``base``: mappings merge key by key, anything else (lists too) replaces."""
    merged = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def read_yaml(path: Path) -> dict[str, Any]:
    """A YAML mapping from ``path``; ScenarioError for a missing file, bad YAML or a non-mapping."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError(f"{path}: invalid YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return data


def _load_raw(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The scenario mapping with ``extends`` resolved and relative environment paths made absolute."""
    path = path.resolve()
    if path in seen:
        raise ScenarioError(f"{path}: 'extends' forms a cycle through {', '.join(str(p) for p in seen)}")
    data = _absolute_paths(read_yaml(path), path.parent)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ScenarioError(f"{path}: extends: expected a file name, got {type(parent).__name__}")
    return deep_merge(_load_raw(path.parent / parent, (*seen, path)), data)


def _absolute_paths(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """Environment paths are relative to the file that names them."""

    def fix(entry: Any) -> None:
        if isinstance(entry, dict) and isinstance(entry.get("environment"), str):
            entry["environment"] = str((folder / entry["environment"]).resolve())

    fix(data.get("train"))
    for entry in data.get("evaluations") or []:
        fix(entry)
    return data


def apply_overrides(data: dict[str, Any], assignments: Sequence[str], source: str = "--set") -> dict[str, Any]:
    """Apply ``key.path=value`` assignments (value parsed as YAML; list items by index)."""
    data = copy.deepcopy(data)
    for assignment in assignments:
        key, sep, raw = assignment.partition("=")
        if not sep or not key:
            raise ScenarioError(f"{source} '{assignment}': expected key.path=value")
        value = yaml.safe_load(raw) if raw else ""
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
            if last:
                node[index] = value
            else:
                if not isinstance(node, list) and not isinstance(node.get(index), (dict, list)):
                    node[index] = {}
                node = node[index]
    return data


def _model_at(model: Any, loc: Sequence[Any]) -> type[pydantic.BaseModel] | None:
    """The pydantic model class found by following ``loc`` through ``model``'s annotations."""
    current: Any = model
    for part in loc:
        while True:  # unwrap Optional / list / dict to the element type
            origin = typing.get_origin(current)
            if origin in (typing.Union, types.UnionType):
                args = [a for a in typing.get_args(current) if a is not type(None)]
                current = args[0] if args else None
            elif origin in (list, tuple) and isinstance(part, int):
                current = typing.get_args(current)[0]
                break
            elif origin is dict:
                current = typing.get_args(current)[1]
                break
            else:
                break
        if isinstance(part, int):
            continue
        if not (isinstance(current, type) and issubclass(current, pydantic.BaseModel)):
            return None
        field = current.model_fields.get(part)
        if field is None:
            return None
        current = field.annotation
    while typing.get_origin(current) in (typing.Union, types.UnionType):
        current = next((a for a in typing.get_args(current) if a is not type(None)), None)
    return current if isinstance(current, type) and issubclass(current, pydantic.BaseModel) else None


def format_validation_error(path: Path | str, exc: pydantic.ValidationError, model: type = Scenario) -> str:
    """One line per problem: ``FILE: key.path: message`` with a suggestion for unknown keys."""
    lines = []
    for err in exc.errors():
        loc = [p for p in err["loc"] if not (isinstance(p, str) and ("[" in p or p.startswith("function-")))]
        key = ".".join(str(p) for p in loc) or "(top level)"
        message = err["msg"]
        if err["type"] == "extra_forbidden":
            parent = _model_at(model, loc[:-1])
            valid = sorted(parent.model_fields) if parent else []
            close = difflib.get_close_matches(str(loc[-1]), valid, n=1)
            message = "unknown key" + (f"; did you mean '{close[0]}'?" if close else "")
            if valid:
                message += f" (valid keys: {', '.join(valid)})"
        elif err["type"] == "missing":
            message = "required key is missing"
        elif "input" in err and err["type"] not in ("value_error", "assertion_error"):
            message += f" (got {err['input']!r})"
        lines.append(f"{path}: {key}: {message}")
    return "\n".join(lines)


def resolve_path(name: str | Path) -> Path:
    """A scenario path as given, or the name of a built-in scenario (``quickstart``)."""
    path = Path(name)
    if path.exists():
        return path
    for candidate in (BUILTIN_DIR / path, BUILTIN_DIR / f"{path}.yaml"):
        if candidate.exists():
            return candidate
    raise ScenarioError(f"{name}: no such scenario file (built-in scenarios: {', '.join(builtin_names())})")


def builtin_names() -> list[str]:
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.yaml"))


def load_scenario(name: str | Path, overrides: Sequence[str] = ()) -> tuple[Scenario, dict[str, Any]]:
    """Read, merge, override and validate a scenario; also return the resolved raw mapping.

    Environment files and method plugins are checked too, so every error surfaces here.
    """
    path = resolve_path(name)
    raw = apply_overrides(_load_raw(path), overrides)
    try:
        scenario = Scenario.model_validate(raw)
    except pydantic.ValidationError as exc:
        raise ScenarioError(format_validation_error(path, exc)) from None
    for where, entry in [("train", scenario.train)] + [
        (f"evaluations.{i}", e) for i, e in enumerate(scenario.evaluations)
    ]:
        if not entry.environment.is_file():
            raise ScenarioError(f"{path}: {where}.environment: no such file {entry.environment}")
        load_environment(entry.environment)
    _check_methods(path, scenario)
    return scenario, raw


def _check_methods(path: Path, scenario: Scenario) -> None:
    from vitaplace.engine.features import ExtractorParamsError
    from vitaplace.engine.plugins import PluginError, discover

    registry = discover()
    for i, method in enumerate(scenario.methods):
        try:
            registry.get(method.plugin).validate_params(method.params)
        except PluginError as exc:
            raise ScenarioError(f"{path}: methods.{i}.plugin: {exc}") from None
        except ExtractorParamsError as exc:
            raise ScenarioError(f"{path}: methods.{i}.params: {exc}") from None


def environment_of(entry: SimulatedRun) -> EnvironmentSpec:
    return load_environment(entry.environment)


def content_hash(*parts: Any) -> str:
    """A short, stable hash of JSON-serialisable parts (the cache key of a stage)."""
    text = json.dumps(parts, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]
