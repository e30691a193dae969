"""vitaplace's Python API for notebooks and scripts (docs/API.md): a thin layer over the
functions the command line uses.

    import vitaplace

    scenario = vitaplace.load_scenario("quickstart", {"methods.0.params.epochs": 2})
    rows = vitaplace.run("quickstart", {"methods.0.params.epochs": 2}, out="runs/q", until="evaluate")
    rows = vitaplace.read_results("runs/q")
    run = vitaplace.simulate("e1", kind="route", n_samples=20, seed=1)
    h = vitaplace.fit_extractor("handcrafted", run)
    distances = h.distance(h.transform(run), h.transform(run))

Simulations run in spawned worker processes, which re-import the script that started them:
a script that calls `run` outside an ``if __name__ == "__main__":`` block would start them
again and again. `run` notices that case and simulates in its own process instead (one log
line says so); notebooks and guarded scripts keep the parallel workers.
"""

from __future__ import annotations

import ast
import functools
import inspect
import json
import logging
import numbers
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vitaplace.engine import __version__
from vitaplace.engine.base.errors import UserError, did_you_mean

if TYPE_CHECKING:
    from types import FrameType

    from vitaplace.engine.config.scenario import Scenario
    from vitaplace.engine.data.dataset import Run
    from vitaplace.engine.extension.features import FeatureExtractor

#: names imported on first use, so that ``import vitaplace`` (and every ``vitaplace.engine``
#: import, the command line's included) stays cheap
_LAZY = {
    "Run": "vitaplace.engine.data.dataset", "open_run": "vitaplace.engine.data.dataset",
    "FeatureExtractor": "vitaplace.engine.extension.features", "Features": "vitaplace.engine.extension.features",
    "Scenario": "vitaplace.engine.config.scenario", "STAGES": "vitaplace.engine.pipeline.keys",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'vitaplace' has no attribute {name!r}")

__all__ = [
    "__version__", "STAGES", "FeatureExtractor", "Features", "Run", "Scenario", "UserError", "extractors",
    "fit_extractor", "load_scenario", "open_run", "read_results", "run", "simulate", "unguarded_script",
]

#: ``{"key.path": value}`` (values as Python objects) or ``["key.path=YAML", ...]`` as ``--set`` takes them
Overrides = Mapping[str, Any] | Sequence[str] | None

log = logging.getLogger("vitaplace")


def _one_line_arguments(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function`` with its arguments bound before it runs, so that a misspelt keyword, a
    missing argument or one too many is a one-line `UserError` naming it (and the nearest
    parameter) instead of Python's TypeError."""
    signature = inspect.signature(function)
    names = list(signature.parameters)
    stars: dict[object, str] = {inspect.Parameter.VAR_POSITIONAL: "*", inspect.Parameter.VAR_KEYWORD: "**"}
    shown = ", ".join(stars.get(p.kind, "") + p.name for p in signature.parameters.values()) or "none"

    @functools.wraps(function)
    def checked(*args: Any, **kwargs: Any) -> Any:
        try:
            signature.bind(*args, **kwargs)
        except TypeError as exc:
            unknown = [key for key in kwargs if key not in signature.parameters]
            problem = (f"unknown argument {unknown[0]!r}{did_you_mean(unknown[0], names)}" if unknown
                       else str(exc).replace("\n", " "))
            raise UserError(f"vitaplace.{function.__name__}(): {problem} (its arguments: {shown})") from None
        return function(*args, **kwargs)

    return checked


def _flag(value: Any, name: str) -> bool:
    """``value`` if it is True or False (numpy's too), else UserError naming argument ``name``."""
    if type(value).__module__ == "numpy" and hasattr(value, "item"):
        value = value.item()
    if not isinstance(value, bool):
        raise UserError(f"{name}={value!r:.80}: expected True or False")
    return value


def _choice(value: Any, name: str, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices``, else UserError naming ``name`` and the nearest choice."""
    if not isinstance(value, str) or value not in choices:
        hint = did_you_mean(value, choices) if isinstance(value, str) else ""
        raise UserError(f"{name}={value!r:.80}: expected one of {', '.join(choices)}{hint}")
    return value


def _stages(force: Any) -> list[str]:
    """``force`` as a list of stage names (one name alone is a list of one), each one of `STAGES`."""
    from vitaplace.engine.pipeline.keys import STAGES

    names = [force] if isinstance(force, str) else force
    if not isinstance(names, Iterable) or isinstance(names, Mapping):
        raise UserError(f"force={force!r:.80}: expected stage names, a list of some of {', '.join(STAGES)}")
    names = list(names)
    for stage in names:
        if not isinstance(stage, str) or stage not in STAGES:
            hint = did_you_mean(stage, STAGES) if isinstance(stage, str) else ""
            raise UserError(f"force={force!r:.80}: {stage!r:.40} is not a stage; "
                            f"expected some of {', '.join(STAGES)}{hint}")
    return names


def _assignments(overrides: Overrides) -> list[str]:
    """``--set`` assignments from a mapping of key paths to values (JSON is YAML) or a list of
    them; anything else is a UserError."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        if not all(isinstance(key, str) for key in overrides):
            raise UserError(f"overrides: keys {list(overrides)!r:.80}: expected key paths as text, e.g. 'seed'")
        return [f"{key}={_yaml_value(key, value)}" for key, value in overrides.items()]
    if isinstance(overrides, str):
        return [overrides]
    if isinstance(overrides, (list, tuple)) and all(isinstance(item, str) for item in overrides):
        return list(overrides)
    raise UserError(f"overrides: {overrides!r:.80}: expected a mapping of key paths to values or a list of "
                    "'key.path=YAML' strings")


def _yaml_value(key: str, value: Any) -> str:
    """``value`` as JSON (which YAML reads): numpy numbers and arrays as numbers and lists, paths
    as text; anything else JSON cannot hold (a set, an object) is a UserError naming ``key``."""
    try:
        return json.dumps(value, default=_plain)
    except (TypeError, ValueError) as exc:
        raise UserError(f"overrides[{key!r}]: {exc}; expected numbers, text, booleans, None, and lists and "
                        "mappings of them") from None


def _plain(value: Any) -> Any:
    """A numpy number or array, or a path, as what JSON holds; TypeError for anything else."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} values have no YAML form")


def _path(value: Any, name: str) -> str | Path:
    """``value`` if it is a path (text or path-like), else UserError naming argument ``name``."""
    if isinstance(value, str):
        return value
    if isinstance(value, os.PathLike):
        return Path(value)
    raise UserError(f"{name}={value!r:.80}: expected a path or a name (text)")


def _whole(value: Any, name: str, low: int, high: int | None = None) -> int:
    """``value`` if it is a whole number >= ``low`` (and < ``high``; not a bool), else UserError
    naming ``name``."""
    whole = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not whole or not low <= int(value) < (high if high is not None else int(value) + 1):
        below = "" if high is None else f" and < {high}"
        raise UserError(f"{name}={value!r:.80}: expected a whole number >= {low}{below}")
    return int(value)


@_one_line_arguments
def load_scenario(scenario: str | Path, overrides: Overrides = None) -> Scenario:
    """The validated scenario ``scenario`` (a YAML file or a shipped scenario's name) with
    ``overrides`` applied, e.g. ``{"methods.0.params.epochs": 2, "seed": 3}``. Raises
    `UserError` (one line naming file, key path and problem) for anything invalid."""
    from vitaplace.engine.config.loading import load_scenario as load

    return load(_path(scenario, "scenario"), _assignments(overrides))[0]


@_one_line_arguments
def run(
    scenario: str | Path,
    overrides: Overrides = None,
    out: str | Path | None = None,
    until: str = "report",
    force: Iterable[str] = (),
    progress: bool = False,
    workers: int | None = None,
) -> list[dict[str, Any]]:
    """Run ``scenario`` (as `load_scenario` reads it) into ``out`` (default
    ``runs/<scenario name>``) up to and including stage ``until`` (one of `STAGES`), and on
    to a later stage whose output ``out`` holds, reusing every cached stage unless named in
    ``force``; returns the result rows (as in results.json; empty before the evaluate stage).
    ``workers``: processes that simulate runs in parallel (default: one per core; 1 in a
    script without a ``__main__`` guard). Stage messages go to the ``vitaplace`` logger
    (``logging.basicConfig(level="INFO")`` shows them)."""
    from vitaplace.engine.base.cpus import configure_blas_threads
    from vitaplace.engine.config.loading import load_scenario as load
    from vitaplace.engine.outputs.outdir import claimed
    from vitaplace.engine.pipeline.keys import STAGES
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store

    configure_blas_threads()
    until, force, progress = _choice(until, "until", STAGES), _stages(force), _flag(progress, "progress")
    late = [stage for stage in force if STAGES.index(stage) > STAGES.index(until)]
    if late:  # it would be ignored
        raise UserError(f"force={force!r:.80}: {', '.join(late)} comes after until={until!r}, which stops before it; "
                        "expected stages up to until")
    if workers is not None:
        workers = _whole(workers, "workers", 1)
    out = None if out is None else _path(out, "out")
    loaded, resolved = load(_path(scenario, "scenario"), _assignments(overrides))
    script = unguarded_script() if workers is None else None
    if script is not None:
        log.info("%s calls vitaplace.run outside `if __name__ == \"__main__\":`; simulating in this process "
                 "(guard the call for parallel simulation workers)", script)
        workers = 1
    with claimed(Path(out) if out is not None else Path("runs") / loaded.name, option="out") as folder:
        rows = run_stages(loaded, resolved, Store(folder, force=force, progress=progress, workers=workers), until,
                          option="out")
    return [row.dump() for row in rows]


@_one_line_arguments
def unguarded_script() -> str | None:
    """The path of the script being run when the call to this function comes from its top
    level outside an ``if __name__ == "__main__":`` block (spawned workers would run that
    code again); None in notebooks, the REPL, ``python -c`` and guarded scripts."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or not Path(path).is_file():
        return None
    frame: FrameType | None = sys._getframe(1)
    while frame is not None and frame.f_globals.get("__name__") != "__main__":
        frame = frame.f_back
    while frame is not None and frame.f_back is not None and frame.f_back.f_globals.get("__name__") == "__main__":
        frame = frame.f_back  # the outermost frame of the script: the statement at its top level
    if frame is None or frame.f_code.co_name != "<module>":
        return None
    line = frame.f_lineno
    try:
        tree = ast.parse(Path(path).read_text())
    except (OSError, SyntaxError, ValueError):
        return None
    for node in tree.body:
        if (isinstance(node, ast.If) and node.lineno <= line <= (node.end_lineno or node.lineno)
                and _is_main_guard(node.test)):
            return None
    return path


def _is_main_guard(test: ast.expr) -> bool:
    """Whether ``test`` is ``__name__ == "__main__"`` (either way round)."""
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    return any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides) and any(
        isinstance(s, ast.Constant) and s.value == "__main__" for s in sides)


@_one_line_arguments
def read_results(out: str | Path) -> list[dict[str, Any]]:
    """The result rows of the finished run in folder ``out`` (its results.json): one per
    environment x method x direction, with ``max_f1``, ``auc``, ``recall_at_k``, ...
    (docs/RESULTS.md). The folder must be complete as `vitaplace aggregate` requires
    (`vitaplace.engine.study.aggregate.validate_run_folder`: its completion record matching
    its files, every row well formed); else UserError, one line."""
    from vitaplace.engine.study.aggregate import validate_run_folder

    folder = Path(_path(out, "out"))
    if not (folder / "results.json").is_file():
        raise UserError(f"{folder / 'results.json'}: no results here; run the scenario up to the evaluate stage first")
    return [row.dump() for row in validate_run_folder(folder).rows]


@_one_line_arguments
def simulate(
    environment: str | Path, kind: str = "foraging", n_samples: int = 200, seed: int = 0, progress: bool = False,
    **run_settings: Any,
) -> Run:
    """Simulate one run of the WhiskEye in ``environment`` (a YAML file or a shipped name such
    as ``"e1"``) and return it in memory (``vitaplace.engine.data.dataset.write_run`` saves it).
    ``kind``: foraging, teleop, stations, route or orbit; ``run_settings``: any other run key
    of that kind (docs/SCENARIOS.md), e.g. ``lateral_noise=0.05`` or ``gains={"leave_time": 2.0}``.
    Runs in this process."""
    import pydantic

    from vitaplace.engine.base.configfile import format_validation_error
    from vitaplace.engine.base.cpus import configure_blas_threads
    from vitaplace.engine.sim.controllers import RUN_KINDS, RunSpec
    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import simulate_run
    from vitaplace.engine.study.grid import seed_range

    configure_blas_threads()

    class Settings(pydantic.BaseModel):  # errors then name run.KEY and the kind's valid keys
        run: RunSpec

    environment, seed = _path(environment, "environment"), _whole(seed, "seed", *seed_range())  # a scenario's
    kind, n_samples = _choice(kind, "kind", list(RUN_KINDS)), _whole(n_samples, "n_samples", 1)
    progress = _flag(progress, "progress")
    try:
        spec = Settings(run={"kind": kind, "n_samples": n_samples, **run_settings}).run
    except pydantic.ValidationError as exc:
        message = format_validation_error("simulate", exc, Settings)  # keys as the arguments' names
        raise UserError(message.replace("simulate: run.", "vitaplace.simulate(): ", 1)) from None
    return simulate_run(load_environment(environment), spec, seed=seed, progress=progress,
                        name=f"{Path(environment).stem}-{kind}")


@_one_line_arguments
def extractors() -> list[str]:
    """The names of the installed feature extractors (``vitaplace plugins`` lists them too)."""
    from vitaplace.engine.extension.registry import discover

    return discover().names()


@_one_line_arguments
def fit_extractor(
    plugin: str, train: Run, params: Mapping[str, Any] | None = None, progress: bool = False
) -> FeatureExtractor:
    """A new extractor of ``plugin`` (e.g. ``"handcrafted"``, ``"mupnet"``) with ``params``
    (the scenario's ``methods.N.params``), fitted on the run ``train``. Its ``transform(run)``
    gives features and ``distance(query, reference)`` the distance matrix."""
    from vitaplace.engine.base.cpus import configure_blas_threads
    from vitaplace.engine.data.dataset import Run
    from vitaplace.engine.extension.checks import check_methods
    from vitaplace.engine.extension.registry import discover

    configure_blas_threads()
    if not isinstance(plugin, str):
        raise UserError(f"plugin={plugin!r:.80}: expected the name of an extractor, one of {', '.join(extractors())}")
    if not isinstance(train, Run):
        raise UserError(f"train={train!r:.80}: expected a Run (vitaplace.open_run(path) reads a run file)")
    if len(train) == 0:
        raise UserError(f"train: run {train.name!r} has no samples; expected a run to fit on")
    if params is not None and not isinstance(params, Mapping):
        raise UserError(f"params={params!r:.80}: expected a mapping of parameter names to values, or None")
    extractor = discover().create(plugin, params)
    extractor.progress = _flag(progress, "progress")
    extractor.fit(train)
    return check_methods(extractor, plugin, train)
