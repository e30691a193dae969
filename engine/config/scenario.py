"""Scenario files: what to simulate, which methods to compare, how to evaluate.

A scenario is YAML validated by pydantic before anything runs. ``extends: other.yaml``
(relative to the file, or a shipped scenario's name) deep-merges the file over another
scenario; ``environment: e1`` names a shipped environment when no such file is next to the
scenario. Errors name the file,
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

A run can be a recorded run file instead (`vitaplace import`; docs/DATA.md): ``train:
{dataset: train.h5}`` and ``datasets: {query: q.h5, reference: r.h5}`` in an evaluation,
relative to the scenario file; the pipeline then reads the file instead of simulating.
"""

from __future__ import annotations

import copy
import hashlib
import math
import os
import json
import logging
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import pydantic
import yaml

from vitaplace.engine.config.configfile import ConfigError, format_validation_error, load_yaml, local_or_shipped
from vitaplace.engine.config.shipped import SCENARIOS_DIR, scenario_names, shipped_file
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.sim.plausibility import ImplausibleRun, check_run
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.robot import N_WHISKERS, RobotSpec
from vitaplace.engine.sim.controllers import RunSpec

log = logging.getLogger("vitaplace")


class ScenarioError(ConfigError):
    """A scenario that cannot run; the message is one line naming file, key path and problem."""


class Strict(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")


class _RunSource(Strict):
    """Where a run comes from: simulated (environment and run) or recorded (subclasses add the file keys)."""

    #: environment YAML, relative to the scenario file (or a shipped name); required for simulated runs
    environment: Path | None = None
    #: how the robot moves and how many samples are recorded (simulated runs only)
    run: RunSpec | None = None

    def _check_source(self, key: str, recorded: bool, environment_allowed: bool) -> None:
        """A run is simulated (``environment`` and ``run``) or recorded (``key``), never both."""
        if recorded:
            extra = [k for k in ("run",) + (() if environment_allowed else ("environment",)) if getattr(self, k) is not None]
            if extra:
                raise ValueError(
                    f"give either '{key}' (recorded runs) or 'environment' and 'run' (simulated), not both: remove "
                    f"{' and '.join(repr(k) for k in extra)} (or set to null what 'extends' brings)"
                )
            return
        missing = [k for k in ("environment", "run") if getattr(self, k) is None]
        if missing:
            raise ValueError(
                f"{' and '.join(repr(k) for k in missing)} missing: a run is simulated ('environment' and 'run') "
                f"or recorded ('{key}': a run file from `vitaplace import`)"
            )


class TrainingRun(_RunSource):
    """Simulated (an environment file and how the robot moves in it) or recorded (a run file)."""

    #: a recorded run file (HDF5, e.g. from `vitaplace import`), relative to the scenario file; instead of environment and run
    dataset: Path | None = None

    @pydantic.model_validator(mode="after")
    def _simulated_or_recorded(self) -> TrainingRun:
        self._check_source("dataset", self.dataset is not None, environment_allowed=False)
        return self


class RecordedRuns(Strict):
    """Run files (HDF5, e.g. from `vitaplace import`), relative to the scenario file."""

    #: the run whose samples query the reference run
    query: Path
    #: the run that is searched for each query
    reference: Path


def _not_only_dots(name: str) -> str:
    if set(name) == {"."}:
        raise ValueError(f"{name!r} is not a usable name: it would name a parent folder")
    return name


#: Names that become folder or file names: letters, digits, _ . - (not only dots), <= 64 long.
SafeName = Annotated[str, pydantic.StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$"), pydantic.AfterValidator(_not_only_dots)]
#: An evaluation run with fewer samples gives no meaningful precision-recall curve.
MIN_EVALUATION_SAMPLES = 5


class EvaluationRuns(_RunSource):
    """An evaluation: two simulated runs (in the shipped scenarios: independent teleoperated
    drives) or two recorded runs (query and reference)."""

    @pydantic.field_validator("run")
    @classmethod
    def _enough_samples(cls, run: RunSpec | None) -> RunSpec | None:
        if run is not None and run.n_samples < MIN_EVALUATION_SAMPLES:
            raise ValueError(f"an evaluation run needs at least {MIN_EVALUATION_SAMPLES} samples, got {run.n_samples}")
        return run

    #: label of the evaluation (E1, E2, ...), letters, digits, _ . -
    name: SafeName
    #: partial revisits: this fraction of the query run is driven off the route (the run's
    #: off_route_offset across it; route, orbit: the final part; teleop: detours spread along
    #: the run), so some queries have no true match
    query_off_route: float = pydantic.Field(0.0, ge=0, le=0.9, allow_inf_nan=False)
    #: recorded query and reference runs instead of simulated ones (no run key then; environment optional: it only draws the arena in the report and bounds tau)
    datasets: RecordedRuns | None = None

    @pydantic.model_validator(mode="after")
    def _simulated_or_recorded(self) -> EvaluationRuns:
        self._check_source("datasets", self.datasets is not None, environment_allowed=True)
        if self.query_off_route and (self.run is None or self.run.kind == "foraging"):
            raise ValueError(
                "query_off_route needs a simulated teleop, route or orbit run (not recorded runs, not foraging)"
            )
        return self

    def run_for(self, role: str) -> RunSpec:
        """The simulated run of ``role`` ("query" or "reference"): the query's carries the
        partial-revisit detour (``query_off_route``)."""
        assert self.run is not None  # validated: simulated
        if role == "query" and self.query_off_route:
            return self.run.model_copy(update={"off_route_fraction": self.query_off_route})
        return self.run

    def recorded(self) -> dict[str, Path]:
        """``{"query": file, "reference": file}`` for recorded runs, else empty."""
        return {} if self.datasets is None else {"query": self.datasets.query, "reference": self.datasets.reference}


class Method(Strict):
    """A feature extractor to compare: a label, the plugin's extractor name, its parameters."""

    #: label of the method in results and figures (L, H, ...)
    name: SafeName
    #: name of the registered feature extractor (`vitaplace plugins` lists them)
    plugin: str
    #: the extractor's parameters (validated by the extractor, see its section)
    params: dict[str, Any] = {}


class EvaluationSettings(Strict):
    tau: float = pydantic.Field(
        0.3, gt=0, allow_inf_nan=False, description="ground-truth revisit tolerance [m], below the arena's diagonal"
    )
    heading_tolerance_deg: float | None = pydantic.Field(
        30.0, ge=0, le=180, allow_inf_nan=False,
        description="a true match also faces within this many degrees of the query (wrapped yaw difference); "
        "null: position only",
    )
    delta: float | None = pydantic.Field(
        None, allow_inf_nan=False, description="fixed acceptance threshold for the F1 at delta"
    )
    #: K values of recall@K
    recall_k: list[pydantic.PositiveInt] = [1, 5, 10]
    #: which run queries which: query-to-reference, the reverse, or both
    direction: typing.Literal["query-to-reference", "reference-to-query", "both"] = "query-to-reference"


class Scenario(Strict):
    #: the scenario's name (reports, output folders): letters, digits, _ . -
    name: SafeName
    #: free text shown in the report
    description: str = ""
    #: master seed: every run's and method's seed derives from it
    seed: int = pydantic.Field(0, ge=0, lt=2**32)
    #: robot, sensors and physics for every run of the scenario
    robot: RobotSpec = RobotSpec()
    #: the run the methods are fitted on
    train: TrainingRun
    #: evaluation environments, each with a query and a reference run
    evaluations: list[EvaluationRuns] = pydantic.Field(min_length=1)
    #: the feature extractors compared
    methods: list[Method] = pydantic.Field(min_length=1)
    #: how features are scored
    evaluation: EvaluationSettings = EvaluationSettings()

    @pydantic.model_validator(mode="after")
    def _unique_names(self) -> Scenario:
        for what, items in (("methods", self.methods), ("evaluations", self.evaluations)):
            names = [item.name for item in items]
            if len(set(names)) != len(names):
                raise ValueError(f"{what}: names must be unique, got {names}")
        return self


def training_world_evaluation(scenario: Scenario) -> tuple[str | None, str]:
    """The evaluation in the training run's world, whose max-F1 threshold every evaluation is
    also scored at (``f1_at_e1_threshold``), and a sentence for the report saying which, or
    why there is none.

    It is the one evaluation whose environment is the training run's environment (the same
    environment specification once loaded, whatever the file and its name). None when the
    training run is a recorded file (no environment), when no evaluation is in that
    environment, or when several are (no single threshold to transfer).
    """
    if scenario.train.environment is None:
        return None, "none: the training run is a recorded file, in no known environment"
    world = load_environment(scenario.train.environment)

    def spec(env: EnvironmentSpec) -> dict[str, Any]:
        return env.model_dump(mode="json", exclude={"name"})

    same = [e.name for e in scenario.evaluations
            if e.environment is not None and spec(load_environment(e.environment)) == spec(world)]
    if len(same) == 1:
        return same[0], f"{same[0]}, the evaluation in the training run's environment {world.name}"
    if not same:
        return None, f"none: no evaluation is in the training run's environment {world.name}"
    return None, f"none: several evaluations are in the training run's environment {world.name}: {', '.join(same)}"


def _load_raw(path: Path) -> dict[str, Any]:
    """The scenario mapping with ``extends`` merged and environment paths made absolute."""
    return load_yaml(path, ScenarioError, _absolute_paths)


def _absolute_paths(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """Environment and run-file paths are relative to the file that names them."""

    def fix(entry: Any, keys: tuple[str, ...] = ("environment", "dataset")) -> None:
        for key in keys if isinstance(entry, dict) else ():
            if isinstance(entry.get(key), str):
                where = folder / entry[key]
                if key == "environment":  # a shipped name (e1) when no such file is next to the scenario
                    where = local_or_shipped(folder, entry[key], key)
                entry[key] = str(_resolved(where))
        if isinstance(entry, dict) and "datasets" in keys:
            fix(entry.get("datasets"), ("query", "reference"))

    fix(data.get("train"))
    evaluations = data.get("evaluations")
    for entry in evaluations if isinstance(evaluations, list) else []:  # anything else: the schema says why
        fix(entry, ("environment", "datasets"))
    return data


def _resolved(path: Path) -> Path:
    """``path`` absolute with its links followed; a link loop stays as it is (the file check
    then reports it as missing instead of Python raising)."""
    try:
        return path.resolve()
    except (RuntimeError, OSError):
        return path.absolute()


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


def resolve_path(name: str | Path) -> Path:
    """A scenario path as given, or the name of a built-in scenario (``quickstart``)."""
    path = Path(name)
    if path.exists():
        return path
    shipped = shipped_file(path, (SCENARIOS_DIR,))
    if shipped is None:
        raise ScenarioError(f"{name}: no such scenario file (built-in scenarios: {', '.join(scenario_names())})")
    return shipped


def load_scenario(name: str | Path, overrides: Sequence[str] = ()) -> tuple[Scenario, dict[str, Any]]:
    """Read, merge, override and validate a scenario; also return the resolved raw mapping.

    Environment files and method plugins are checked too, so every error surfaces here.
    """
    path = resolve_path(name)
    log.debug("scenario %s: file %s, %d override(s)", name, path.resolve(), len(overrides))
    raw = apply_overrides(_load_raw(path), overrides)
    try:
        scenario = Scenario.model_validate(raw)
    except pydantic.ValidationError as exc:
        raise ScenarioError(format_validation_error(path, exc, Scenario)) from None
    train_samples = scenario.train.run.n_samples if scenario.train.run else 0
    robot = scenario.robot
    # what every run must share with the training run: whiskers and image size
    train_shape = (N_WHISKERS, (robot.camera_height, robot.camera_width, 3))
    if scenario.train.dataset is not None:
        train = _recorded(path, "train.dataset", scenario.train.dataset, 1)
        train_samples, train_shape = len(train), (train.n_whiskers, train.image_shape)
    for i, e in enumerate(scenario.evaluations):
        for side, file in e.recorded().items():
            run = _recorded(path, f"evaluations.{i}.datasets.{side}", file, MIN_EVALUATION_SAMPLES)
            _check_like_training(path, f"evaluations.{i}.datasets.{side}", run, train_shape)
        if e.datasets is not None:
            _check_distinct(path, f"evaluations.{i}.datasets", e.datasets)
    for where, entry in [("train", scenario.train)] + [
        (f"evaluations.{i}", e) for i, e in enumerate(scenario.evaluations)
    ]:
        if entry.environment is None:
            continue
        if not entry.environment.is_file():
            raise ScenarioError(f"{path}: {where}.environment: no such file {str(entry.environment)!r}")
        env = load_environment(entry.environment)
        if entry.run is not None:
            runs = [entry.run_for(role) for role in ("query", "reference")] if where != "train" else [entry.run]
            for run in runs:
                try:
                    check_run(env, run, robot)
                except ImplausibleRun as exc:
                    raise ScenarioError(f"{path}: {where}.run.{exc.key}: {exc}") from None
        diagonal = 2 * math.hypot(env.arena.half_x, env.arena.half_y)
        if where != "train" and scenario.evaluation.tau >= diagonal:
            raise ScenarioError(
                f"{path}: evaluation.tau: {scenario.evaluation.tau} m is not below the {diagonal:.2f} m diagonal of "
                f"{env.name}: every pair of poses would count as a revisit"
            )
    params = _check_methods(path, scenario)
    _check_memory(path, scenario, params, physical_memory(), train_samples)
    return scenario, raw


def _recorded(path: Path, where: str, file: Path, minimum: int) -> Run:
    """The recorded run ``file``, opened (its attributes, fields, storage and shapes checked)
    and with at least ``minimum`` samples."""
    from vitaplace.engine.data.dataset import DatasetError, open_run

    if not file.is_file():
        raise ScenarioError(f"{path}: {where}: no such file {str(file)!r} (make one with `vitaplace import`)")
    try:
        run = open_run(file)
    except DatasetError as exc:
        raise ScenarioError(f"{path}: {where}: {exc}") from None
    if len(run) < minimum:
        role = "a training" if where.startswith("train") else "an evaluation"
        raise ScenarioError(f"{path}: {where}: {role} run needs at least {minimum} samples, {file} has {len(run)}")
    return run


def _check_like_training(path: Path, where: str, run: Run, train: tuple[int, tuple[int, ...]]) -> None:
    """An evaluation run has the training run's whiskers and image size (methods fitted on
    one cannot read the other)."""
    whiskers, image = train
    if run.n_whiskers != whiskers:
        raise ScenarioError(f"{path}: {where}: {run.path} has {run.n_whiskers} whiskers, the training run {whiskers}")
    if run.image_shape != tuple(image):
        shown = lambda shape: "x".join(map(str, shape))  # noqa: E731
        raise ScenarioError(
            f"{path}: {where}: {run.path} has {shown(run.image_shape)} images, the training run {shown(image)}"
        )


def _check_distinct(path: Path, where: str, datasets: RecordedRuns) -> None:
    """Query and reference are two recordings: the same file (or the same content) would
    match every query to itself and score 100 %."""
    from vitaplace.engine.pipeline.checksum import digest

    if digest(datasets.query) == digest(datasets.reference):
        raise ScenarioError(
            f"{path}: {where}: query {datasets.query} and reference {datasets.reference} are the same recording; "
            "an evaluation needs two separate runs"
        )


def physical_memory() -> int | None:
    """Bytes of RAM of this machine (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def run_bytes(run: RunSpec, robot: RobotSpec) -> int:
    """Memory a recorded run takes while it is simulated: frames, deflection series, sensors."""
    frame = robot.camera_height * robot.camera_width * 3
    series = robot.deflection_samples * 24 * 2 * 4
    return run.n_samples * (frame + series + 24 * 3 * 4 + 64)


def _check_memory(
    path: Path, scenario: Scenario, methods: list[tuple[Any, Any]], limit: int | None, train_samples: int
) -> None:
    """Refuse, before any compute, runs and networks that cannot fit in this machine's memory."""
    if limit is None:
        return
    runs = [("train.run", scenario.train.run)] + [(f"evaluations.{i}.run", e.run) for i, e in enumerate(scenario.evaluations)]
    for where, run in runs:
        if run is None:  # a recorded run: it fits, it was recorded
            continue
        need = run_bytes(run, scenario.robot)
        if need > limit:
            raise ScenarioError(
                f"{path}: {where}.n_samples: {run.n_samples} samples of {scenario.robot.camera_height}x"
                f"{scenario.robot.camera_width} frames need {need / 1e9:.3g} GB of memory; this machine has "
                f"{limit / 1e9:.3g} GB"
            )
    for i, (extractor, params) in enumerate(methods):
        need, key, what = extractor.memory_bytes(params, train_samples)
        if need > limit:
            raise ScenarioError(
                f"{path}: methods.{i}.params.{key}: {what} need {need / 1e9:.3g} GB of memory for the method; "
                f"this machine has {limit / 1e9:.3g} GB"
            )


def _check_methods(path: Path, scenario: Scenario) -> list[tuple[Any, Any]]:
    """Each method's extractor class and validated parameters (errors name the method)."""
    from vitaplace.engine.features import ExtractorParamsError
    from vitaplace.engine.plugins import PluginError, discover

    registry = discover()
    checked = []
    for i, method in enumerate(scenario.methods):
        try:
            extractor = registry.get(method.plugin)
            checked.append((extractor, extractor.validate_params(method.params)))
        except PluginError as exc:
            raise ScenarioError(f"{path}: methods.{i}.plugin: {exc}") from None
        except ExtractorParamsError as exc:
            raise ScenarioError(f"{path}: methods.{i}.params: {exc}") from None
    return checked


def content_hash(*parts: Any) -> str:
    """A short, stable hash of JSON-serialisable parts (the cache key of a stage)."""
    text = json.dumps(parts, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]
