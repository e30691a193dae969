"""Discovery of feature-extractor plugins through pluggy and the ``vitaplace.features`` entry points.

Every package (the built-in ``handcrafted`` and ``mupnet`` included) exposes a module with a
`vitaplace_register_features` hook implementation under the entry-point group
``vitaplace.features``. A plugin that fails to import or to register is reported by name
and skipped; two extractors with the same name are an error naming both packages. The
environment variable ``VITAPLACE_PLUGINS`` (comma-separated entry-point names) restricts
which plugins load.

`Registry.code_digest` is a SHA-256 over a plugin's code: the source files of its entry-point
module (every ``.py`` file of its package folder) and of the extractor's own module, plus the
files its distribution installed (bytecode and ``.dist-info`` records left out). It is part
of the cache key of the stages that run the plugin, so an edited plugin is never served
from the cache, whether or not its version changed.
"""

from __future__ import annotations

import hashlib
import inspect
import logging
import os
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import Distribution, EntryPoint, entry_points
from pathlib import Path
from types import ModuleType
from typing import Any

import pluggy

from vitaplace.engine.base.errors import UserError, did_you_mean
from vitaplace.engine.extension import hookspecs
from vitaplace.engine.extension.features import FeatureExtractor

ONLY_ENV = "VITAPLACE_PLUGINS"


class PluginError(UserError, ValueError):
    """A plugin problem the user must fix (duplicate name, unknown extractor, bad class)."""


@dataclass
class Registry:
    """Feature extractors by name, with the package that contributed each and the plugins skipped."""

    manager: pluggy.PluginManager
    extractors: dict[str, type[FeatureExtractor]] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    #: "distribution==version" of each plugin source (part of the cache keys of its stages)
    distributions: dict[str, str] = field(default_factory=dict)
    #: the loaded entry-point module and the distribution of each plugin source (for `code_digest`)
    modules: dict[str, object] = field(default_factory=dict)
    dists: dict[str, Distribution | None] = field(default_factory=dict)
    _digests: dict[str, str] = field(default_factory=dict)

    def names(self) -> list[str]:
        return sorted(self.extractors)

    def version_of(self, name: str) -> str:
        """The distribution and version that provide extractor ``name`` ("unknown" if not installed as one)."""
        return self.distributions.get(self.sources.get(name, ""), "unknown")

    def code_digest(self, name: str) -> str:
        """SHA-256 of the code behind extractor ``name`` (see the module docstring), computed once."""
        if name not in self._digests:
            source = self.sources.get(name, "")
            files = _module_files(self.modules.get(source)) | _module_files(sys.modules.get(self.get(name).__module__))
            files |= _installed_files(self.dists.get(source))
            # file names and contents, not where they are installed: the same code has one
            # digest on every machine (sweep jobs share one cache)
            entries = sorted(f"{file.name}:{hashlib.sha256(file.read_bytes()).hexdigest()}" for file in files)
            self._digests[name] = hashlib.sha256("\n".join(entries).encode()).hexdigest()
        return self._digests[name]

    def get(self, name: str) -> type[FeatureExtractor]:
        try:
            return self.extractors[name]
        except KeyError:
            valid = ", ".join(self.names()) or "none installed"
            raise PluginError(
                f"unknown feature extractor {name!r}; available: {valid}{did_you_mean(name, self.names())}") from None

    def create(self, name: str, params: Mapping[str, Any] | None = None) -> FeatureExtractor:
        return self.get(name)(params)

    def add_plugin(self, plugin: object, source: str) -> None:
        """Register one plugin object (module or instance) and collect the extractors it contributes."""
        for other, registered in self.manager.list_name_plugin():
            if registered is plugin:
                raise PluginError(
                    f"plugins '{other}' and '{source}' are the same module {getattr(plugin, '__name__', plugin)!r}; "
                    f"remove one of the two entry points or restrict plugins with {ONLY_ENV}"
                )
        self.manager.register(plugin, name=source)
        self.modules[source] = plugin
        hook_impls = [i for i in self.manager.hook.vitaplace_register_features.get_hookimpls() if i.plugin is plugin]
        for impl in hook_impls:
            try:
                impl.function(register=lambda cls, _source=source: self._register(cls, _source))
            except PluginError:
                raise
            except (KeyboardInterrupt, GeneratorExit):
                raise
            except BaseException as exc:  # noqa: BLE001 - a broken plugin (even one calling sys.exit) must not stop the others
                # A skipped plugin contributes nothing, not even what it registered before failing.
                for name in [n for n, s in self.sources.items() if s == source]:
                    del self.extractors[name], self.sources[name]
                self.manager.unregister(plugin)
                self._skip(source, f"its registration hook raised {type(exc).__name__}: {exc}")
                return

    def _register(self, cls: type[FeatureExtractor], source: str) -> None:
        if not (isinstance(cls, type) and issubclass(cls, FeatureExtractor)):
            raise PluginError(f"plugin '{source}' registered {cls!r}, which is not a FeatureExtractor subclass")
        if inspect.isabstract(cls):
            missing = ", ".join(sorted(cls.__abstractmethods__))
            raise PluginError(f"plugin '{source}' registered {cls.__name__}, which does not implement {missing}")
        name = getattr(cls, "name", None)
        if not isinstance(name, str) or not name:
            raise PluginError(f"plugin '{source}' registered {cls.__name__} without a 'name'")
        if name in self.extractors:
            raise PluginError(
                f"feature extractor name '{name}' is provided by two plugins: '{self.sources[name]}' and '{source}'; "
                f"uninstall one or restrict plugins with {ONLY_ENV}"
            )
        self.extractors[name] = cls
        self.sources[name] = source

    def _skip(self, source: str, why: str) -> None:
        self.failed[source] = why
        print(f"vitaplace: skipping plugin '{source}': {why}", file=sys.stderr)


def _module_files(module: object) -> set[Path]:
    """The source files of ``module``: every ``.py`` file of a package's folders, a module's file."""
    if not isinstance(module, ModuleType):
        return set()
    folders = [Path(p) for p in getattr(module, "__path__", [])]
    if folders:
        return {f.resolve() for folder in folders for f in folder.rglob("*.py")}
    file = getattr(module, "__file__", None)
    return {Path(file).resolve()} if file and Path(file).is_file() else set()


def _installed_files(dist: Distribution | None) -> set[Path]:
    """What ``dist`` installed, without bytecode and its own ``.dist-info`` records."""
    found: set[Path] = set()
    if dist is None:
        return found
    for item in dist.files or []:
        if item.suffix == ".pyc" or any(part.endswith(".dist-info") for part in item.parts):
            continue
        path = Path(str(dist.locate_file(item)))  # typed as a SimplePath, which Path() does not take
        if path.is_file():
            found.add(path.resolve())
    return found


def _source_label(ep: EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    package = dist.name if dist is not None else ep.value.split(":")[0]
    return f"{ep.name} ({package})"


def discover(eps: Iterable[EntryPoint] | None = None, only: str | None = None) -> Registry:
    """Load every plugin of the ``vitaplace.features`` entry-point group into a new `Registry`.

    ``only`` (default: the ``VITAPLACE_PLUGINS`` environment variable) is a comma-separated
    list of entry-point names to load; the rest are ignored.
    """
    manager = pluggy.PluginManager(hookspecs.PROJECT)
    manager.add_hookspecs(hookspecs)
    registry = Registry(manager)
    only = os.environ.get(ONLY_ENV) if only is None else only
    wanted = {name.strip() for name in only.split(",") if name.strip()} if only else None
    available = list(entry_points(group=hookspecs.ENTRY_POINT_GROUP) if eps is None else eps)
    unknown = sorted((wanted or set()) - {ep.name for ep in available})
    if unknown:
        print(
            f"vitaplace: {ONLY_ENV} names unknown plugin(s) {', '.join(unknown)}; "
            f"installed: {', '.join(sorted(ep.name for ep in available))}",
            file=sys.stderr,
        )
    for ep in available:
        if wanted is not None and ep.name not in wanted:
            continue
        source = _source_label(ep)
        dist = getattr(ep, "dist", None)
        registry.distributions[source] = f"{dist.name}=={dist.version}" if dist is not None else "unknown"
        registry.dists[source] = dist
        try:
            plugin = ep.load()
        except (KeyboardInterrupt, GeneratorExit):
            raise
        except BaseException as exc:  # noqa: BLE001 - a plugin that fails to import (even by sys.exit) is skipped
            registry._skip(source, f"import failed with {type(exc).__name__}: {exc}")
            continue
        registry.add_plugin(plugin, source)
    return registry


def plugin_distributions(registry: Registry) -> dict[str, dict[str, str]]:
    """Per extractor: the plugin (entry point) that provides it and that plugin's distribution
    name and version ("unknown" when not installed as a distribution), for manifests and reports."""
    out = {}
    for name in registry.names():
        source = registry.sources[name]
        distribution, _, installed = registry.distributions.get(source, "unknown").partition("==")
        out[name] = {"plugin": source, "distribution": distribution, "version": installed or "unknown"}
    return out


def _call_each(registry: Registry, hook: str, what: str, **kwargs: Any) -> list[Any]:
    """Call every plugin's ``hook``; one that raises is reported as a warning naming it and
    ``what`` it is ("run-finished hook"), and the others still run. Each gets the arguments
    it names (pluggy's rule: a hook written before an argument was added still works).
    Returns their results."""
    log = logging.getLogger("vitaplace")
    results = []
    for impl in getattr(registry.manager.hook, hook).get_hookimpls():
        try:
            results.append(impl.function(**{name: kwargs[name] for name in impl.argnames}))
        except Exception as exc:  # noqa: BLE001 - a tracker's failure must not fail a finished run
            log.warning("plugin '%s': its %s raised %s: %s", impl.plugin_name, what, type(exc).__name__,
                        str(exc).splitlines()[0] if str(exc) else "")
    return results


def announce_run_started(registry: Registry, out: Path, scenario: Any) -> None:
    """Call every plugin's `vitaplace_run_started` hook (one that raises: a warning)."""
    _call_each(registry, "vitaplace_run_started", "run-started hook", out=out, scenario=scenario)


def announce_training_epoch(registry: Registry, out: Path, method: str, epoch: int, numbers: dict[str, float]) -> None:
    """Call every plugin's `vitaplace_training_epoch` hook (one that raises: a warning)."""
    _call_each(registry, "vitaplace_training_epoch", "training-epoch hook", out=out, method=method, epoch=epoch,
               numbers=numbers)


def announce_run_failed(registry: Registry, out: Path, scenario: Any, error: str) -> None:
    """Call every plugin's `vitaplace_run_failed` hook (one that raises: a warning)."""
    _call_each(registry, "vitaplace_run_failed", "run-failed hook", out=out, scenario=scenario, error=error)


def announce_run_finished(registry: Registry, out: Path, scenario: Any, rows: list[dict[str, Any]], stage: str) -> None:
    """Call every plugin's `vitaplace_run_finished` hook; one that raises is reported as a
    warning naming it (the run's outputs are written already) and the others still run."""
    _call_each(registry, "vitaplace_run_finished", "run-finished hook", out=out, scenario=scenario, rows=rows,
               stage=stage)


def announce_sweep_started(registry: Registry, out: Path, scenario: Any, seeds: list[int],
                           grid: list[Any] | None = None) -> dict[str, str]:
    """Call every plugin's `vitaplace_sweep_started` hook (``grid``: the grid's points, if
    any); the environment variables they ask the seeds' processes to have, merged (text only)."""
    environment: dict[str, str] = {}
    for asked in _call_each(registry, "vitaplace_sweep_started", "sweep-started hook", out=out, scenario=scenario,
                            seeds=seeds, grid=list(grid or [])):
        environment.update({str(k): str(v) for k, v in (asked or {}).items()})
    return environment


def announce_sweep_finished(registry: Registry, out: Path, scenario: Any, seeds: list[int],
                            failed: dict[int | str, str], environment: dict[str, str]) -> None:
    """Call every plugin's `vitaplace_sweep_finished` hook (one that raises: a warning)."""
    _call_each(registry, "vitaplace_sweep_finished", "sweep-finished hook", out=out, scenario=scenario, seeds=seeds,
               failed=failed, environment=environment)
