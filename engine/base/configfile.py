"""YAML configuration files shared by scenarios and environments.

* `load_yaml` reads a mapping, resolving ``extends: other.yaml`` (relative to the file,
  cycles detected; a name with no such file next to it is a shipped scenario or environment,
  `shipped_file`): mappings are deep-merged, anything else (lists too) is replaced.
* `format_validation_error` turns a pydantic error into lines ``FILE: key.path: message``,
  with the nearest valid key suggested for an unknown one.
* `NumbersNotBooleans`, the base of the configuration models, refuses a boolean where a number
  is expected (YAML's ``epochs: true`` would otherwise be read as 1).
"""

from __future__ import annotations

import copy
import functools
import logging
import re
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any

import pydantic
import pydantic_core
import yaml

from vitaplace.engine.base.errors import UserError, did_you_mean
from vitaplace.engine.base.shipped import shipped_file

log = logging.getLogger("vitaplace")


class ConfigError(UserError, ValueError):
    """A configuration file that cannot be used; the message names the file and key path."""


def _kinds(tp: Any) -> frozenset[str]:
    """What an annotation admits among ``bool``, ``int``, ``float`` and ``any`` (``Any``, ``object``),
    through unions, ``Annotated``, containers and ``Literal`` (a literal True or False is a bool)."""
    if tp is bool or tp is int or tp is float:
        return frozenset({tp.__name__})
    if tp is Any or tp is object:
        return frozenset({"any"})
    if typing.get_origin(tp) is typing.Literal:
        return frozenset({"bool"} if any(isinstance(a, bool) for a in typing.get_args(tp)) else ())
    return frozenset().union(*(_kinds(arg) for arg in typing.get_args(tp)))


def _first_boolean(value: Any, where: tuple[int, ...] = ()) -> tuple[int, ...] | None:
    """Where the first boolean in ``value`` is: () for ``value`` itself, a list or tuple's
    indices for one inside them (mappings are left to the models they validate as); None."""
    if isinstance(value, bool):
        return where
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            found = _first_boolean(item, (*where, i))
            if found is not None:
                return found
    return None


@functools.cache
def _number_wanted(model: type[pydantic.BaseModel], field: str) -> str | None:
    """``"a whole number"`` or ``"a number"`` when ``field`` of ``model`` takes integers or
    floats and never a boolean; None otherwise."""
    kinds = _kinds(model.model_fields[field].annotation)
    if kinds & {"bool", "any"} or not kinds & {"int", "float"}:
        return None
    return "a number" if "float" in kinds else "a whole number"


#: a heading in degrees, one turn either way at most: a start's yaw of 1e308 validated and then
#: made the simulation unstable, blamed on the robot
Degrees = Annotated[float, pydantic.Field(ge=-360.0, le=360.0, allow_inf_nan=False)]


class NumbersNotBooleans(pydantic.BaseModel):
    """A base of configuration models: a boolean given where a number is expected, alone or in
    a list, is refused at its key path, "expected a whole number, not a boolean" (pydantic would
    read YAML's ``true`` as 1). A field that takes a boolean (``bool``, ``Any``, a union with
    ``bool``) keeps taking it. A model-level check: pydantic allows no field validator on the
    tag of a discriminated union (a run's ``kind``)."""

    @pydantic.model_validator(mode="before")
    @classmethod
    def _numbers_not_booleans(cls, data: Any) -> Any:
        if not isinstance(data, Mapping):
            return data
        problems: list[Any] = []
        for key, value in data.items():
            wanted = _number_wanted(cls, key) if isinstance(key, str) and key in cls.model_fields else None
            where = None if wanted is None else _first_boolean(value)
            if where is not None:
                problems.append({"type": pydantic_core.PydanticCustomError(
                    "boolean_not_number", "expected {wanted}, not a boolean", {"wanted": wanted}),
                    "loc": (key, *where), "input": _inside(value, where)})
        if problems:
            raise pydantic_core.ValidationError.from_exception_data(cls.__name__, problems)
        return data


def _inside(value: Any, where: tuple[int, ...]) -> Any:
    """The item of nested lists ``value`` at indices ``where``."""
    for i in where:
        value = value[i]
    return value


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """``override`` over ``base``: mappings merge key by key, anything else (lists too) replaces."""
    merged = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


#: Limits on what a configuration file may expand to (alias "bombs", absurd nesting).
MAX_VALUES = 1_000_000
MAX_DEPTH = 100
MAX_QUOTE = 80


def _quote(value: Any) -> str:
    """``repr(value)``, capped: an error message never quotes a huge value whole."""
    text = repr(value)
    return text if len(text) <= MAX_QUOTE else text[: MAX_QUOTE - 3] + "..."


class _StrictLoader(yaml.SafeLoader):
    """Safe YAML that refuses duplicate keys (instead of keeping the last one silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)
            if isinstance(key, typing.Hashable) and key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {_quote(key)} (first at line {seen[key] + 1})", key_node.start_mark
                )
            if isinstance(key, typing.Hashable):
                seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


def _expanded_size(root: yaml.Node) -> int:
    """How many values the node graph expands to (aliases counted each time they are used),
    capped just above `MAX_VALUES`; raises ValueError past `MAX_DEPTH` levels of nesting."""
    memo: dict[int, int] = {}

    def size(node: yaml.Node, depth: int) -> int:
        if depth > MAX_DEPTH:
            raise ValueError(f"nested more than {MAX_DEPTH} levels deep")
        key = id(node)
        if key in memo:
            return memo[key]
        if isinstance(node, yaml.SequenceNode):
            total = 1 + sum(size(child, depth + 1) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            total = 1 + sum(size(k, depth + 1) + size(v, depth + 1) for k, v in node.value)
        else:
            total = 1
        memo[key] = total = min(total, MAX_VALUES + 1)
        return total

    return size(root, 0)


def read_yaml(path: Path, error: type[ConfigError] = ConfigError) -> dict[str, Any]:
    """The YAML mapping in ``path`` (an empty file is an empty mapping). Undecodable text,
    invalid YAML, duplicate keys, documents expanding to more than `MAX_VALUES` values and
    nesting deeper than `MAX_DEPTH` are errors naming the file."""
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}); is this a YAML file?") from None
    try:
        loader = _StrictLoader(text)
        try:
            node = loader.get_single_node()
            if node is None:
                return {}
            try:
                values = _expanded_size(node)
            except ValueError as exc:
                raise error(f"{path}: {exc}") from None
            if values > MAX_VALUES:
                raise error(f"{path}: expands to more than {MAX_VALUES:,} values (aliases used recursively?)")
            data = loader.construct_document(node)
        finally:
            loader.dispose()
    except RecursionError:
        raise error(f"{path}: nested more than {MAX_DEPTH} levels deep") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{path}: invalid YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return data


def load_yaml(
    path: Path,
    error: type[ConfigError] = ConfigError,
    localise: Callable[[dict[str, Any], Path], dict[str, Any]] | None = None,
    _chain: tuple[Path, ...] = (),
) -> dict[str, Any]:
    """Read ``path`` with its ``extends:`` chain merged in.

    ``localise(data, path)`` prepares one file's own data before merging (``path`` is that
    file): relative paths made absolute, so every path resolves against the file that names
    it, and renamed keys read under their new names.
    """
    path = path.resolve()
    if path in _chain:
        raise error(f"{_chain[0]}: 'extends' forms a cycle: {' -> '.join(str(p) for p in (*_chain, path))}")
    data = read_yaml(path, error)
    if localise is not None:
        data = localise(data, path)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise error(f"{path}: extends: expected a file name, got {parent!r}")
    found = local_or_shipped(path.parent, parent, f"{path.name}: extends")
    if not found.is_file():
        there = f"{found} is a folder" if found.is_dir() else f"no file {found}{'' if found.suffix else ' or .yaml'}"
        raise error(f"{path}: extends: {parent!r}: expected a YAML file; {there}, and vitaplace ships none "
                    "of that name")
    base = load_yaml(found, error, localise, (*_chain, path))
    base.pop("name", None)  # a name belongs to the file that states it
    return deep_merge(base, data)


def local_or_shipped(folder: Path, name: str, what: str = "") -> Path:
    """``folder / name`` (or ``name.yaml``) when that file exists, else the shipped file of that
    name (`shipped_file`), else ``folder / name`` (whose absence the caller reports)."""
    local = folder / name
    for candidate in (local, folder / f"{name}.yaml"):
        if candidate.is_file():
            return candidate
    shipped = shipped_file(name)
    if shipped is None:
        return local
    log.debug("%s: no file %s, using the shipped %s", what or name, local, shipped)
    return shipped


def _unwrap(tp: Any) -> list[Any]:
    """The alternatives of a type: Optional/Union members, Annotated stripped."""
    if typing.get_origin(tp) is typing.Annotated:
        return _unwrap(typing.get_args(tp)[0])
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return [m for arg in typing.get_args(tp) for m in _unwrap(arg) if m is not type(None)]
    return [tp]


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, pydantic.BaseModel)


def _tags(model: type[pydantic.BaseModel]) -> tuple[Any, ...]:
    """The values of a model's ``type`` or ``kind`` field (``Literal[...]``): its tags in a
    discriminated union (landmarks on ``type``, run settings on ``kind``)."""
    fields = (model.model_fields.get(name) for name in ("type", "kind"))
    return next((typing.get_args(f.annotation) for f in fields
                 if f and typing.get_origin(f.annotation) is typing.Literal), ())


def _resolve(tp: Any, loc: tuple[Any, ...]) -> tuple[type[pydantic.BaseModel] | None, list[Any] | None]:
    """Follow ``loc`` through the annotations of ``tp``. Returns the model reached (None for a
    non-model value) and the key path to show, without the tags of discriminated unions that
    pydantic puts in ``loc``; the path is None when ``loc`` does not fit ``tp``."""
    options = _unwrap(tp)
    if not loc:
        return next((o for o in options if _is_model(o)), None), []
    part, rest = loc[0], loc[1:]
    for option in options:
        origin, args = typing.get_origin(option), typing.get_args(option)
        if origin in (list, tuple) and isinstance(part, int) and args:
            inner = (args[0] if origin is list or len(args) == 2 and args[1] is Ellipsis
                     else args[min(part, len(args) - 1)])
            model, shown = _resolve(inner, rest)
        elif origin is dict and args:
            model, shown = _resolve(args[1], rest)
        elif _is_model(option) and part in option.model_fields:
            model, shown = _resolve(option.model_fields[part].annotation, rest)
        elif _is_model(option) and part in _tags(option):
            model, shown = _resolve(option, rest)  # a tag of a discriminated union: not shown
            if shown is not None:
                return model, shown
            continue
        else:
            continue
        if shown is not None:
            return model, [part, *shown]
    return None, None


def show_key(part: Any) -> str:
    """A key path part as text on one line (quoted when it holds control characters)."""
    text = str(part)
    return text if text.isprintable() else _quote(text)


def _tag_problem(key: str, err: Mapping[str, Any]) -> tuple[str, str]:
    """The key path and message of an unknown tag of a discriminated union (``run.kind:
    'teleport' ...``): the tags it takes and the nearest one, in place of pydantic's wording."""
    ctx = err.get("ctx", {})
    discriminator = str(ctx.get("discriminator", "")).strip("'")
    tags = re.findall(r"'([^']*)'", str(ctx.get("expected_tags", "")))
    tag = ctx.get("tag", "")
    key = f"{key}.{discriminator}" if discriminator and key != "(top level)" else discriminator or key
    return key, f"expected one of {', '.join(tags)}, got {_quote(tag)}{did_you_mean(tag, tags)}"


def format_validation_error(path: Path | str, exc: pydantic.ValidationError, model: type[pydantic.BaseModel]) -> str:
    """One line: ``FILE: key.path: message`` for the first problem (suggesting the nearest
    valid key), followed by the key paths of any others."""
    lines: list[str] = []
    keys: list[str] = []
    for err in exc.errors():
        loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and ("[" in p or p.startswith("function-"))))
        parent, shown = _resolve(model, loc[:-1])
        if shown is None:
            parent, shown = None, list(loc[:-1])
        key = ".".join(show_key(p) for p in (*shown, *loc[-1:])) or "(top level)"
        message = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            valid = sorted(parent.model_fields) if parent else []
            message = "unknown key" + did_you_mean(loc[-1], valid)
            if valid:
                message += f" (valid keys: {', '.join(valid)})"
        elif err["type"] == "missing":
            message = "required key is missing"
        elif err["type"] == "union_tag_invalid":  # e.g. run.kind: teleport
            key, message = _tag_problem(key, err)
        elif "input" in err and err["type"] not in ("value_error", "assertion_error"):
            message += f" (got {_quote(err['input'])})"
        if not loc and err["type"] == "value_error":
            lines.append(f"{path}: {message}")  # model-level checks name their key path themselves
        else:
            lines.append(f"{path}: {key}: {message}")
        keys.append(key)
    if len(lines) > 1:  # one line: the first problem, and where the others are
        others = ", ".join(dict.fromkeys(keys[1:]))
        return f"{lines[0]}; {len(lines) - 1} more problem(s) at {_quote(others)[1:-1]}"
    return lines[0]
