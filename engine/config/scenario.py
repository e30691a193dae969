"""The scenario schema: what to simulate, which methods to compare, how to evaluate.

A scenario is YAML validated by pydantic before anything runs (`vitaplace.engine.config.loading`
reads, overrides and checks it). ``extends: other.yaml``
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
    scoring: {tau: 0.3}

A run can be a recorded run file instead (`vitaplace import`; docs/DATA.md): ``train:
{dataset: train.h5}`` and ``datasets: {query: q.h5, reference: r.h5}`` in an evaluation,
relative to the scenario file; the pipeline then reads the file instead of simulating.
"""

from __future__ import annotations

import logging
import math
import typing
from pathlib import Path
from typing import Annotated, Any

import pydantic

from vitaplace.engine.base.configfile import ConfigError, NumbersNotBooleans
from vitaplace.engine.sim.condition import Condition
from vitaplace.engine.sim.controllers import (
    RENAMED_RUN_KEYS,
    RunSpec,
    legacy_gain_paths,
    nest_legacy_gains,
    rename_legacy_run_keys,
)
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.robot import RobotSpec

log = logging.getLogger("vitaplace")


class ScenarioError(ConfigError):
    """A scenario that cannot run; the message is one line naming file, key path and problem."""


class Strict(NumbersNotBooleans):
    model_config = pydantic.ConfigDict(extra="forbid")


class _RunSource(Strict):
    """Where a run comes from: simulated (environment and run) or recorded (subclasses add the file keys)."""

    environment: Path | None = pydantic.Field(
        None,
        description="environment YAML, relative to the scenario file (or a shipped name); required for simulated runs",
    )
    run: RunSpec | None = pydantic.Field(
        None,
        description="how the robot moves and how many samples are recorded (simulated runs only)",
    )

    def _check_source(self, key: str, recorded: bool, environment_allowed: bool) -> None:
        """A run is simulated (``environment`` and ``run``) or recorded (``key``), never both."""
        if recorded:
            extra = [k for k in ("run",) + (() if environment_allowed else ("environment",))
                     if getattr(self, k) is not None]
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


class TrainingData(_RunSource):
    """Simulated (an environment file and how the robot moves in it) or recorded (a run file)."""

    dataset: Path | None = pydantic.Field(
        None,
        description="a recorded run file (HDF5, e.g. from `vitaplace import`), relative to the scenario file; "
        "instead of environment and run",
    )

    @pydantic.model_validator(mode="after")
    def _simulated_or_recorded(self) -> TrainingData:
        self._check_source("dataset", self.dataset is not None, environment_allowed=False)
        return self


class RecordedRuns(Strict):
    """Run files (HDF5, e.g. from `vitaplace import`), relative to the scenario file."""

    query: Path = pydantic.Field(description="the run whose samples query the reference run")
    reference: Path = pydantic.Field(description="the run that is searched for each query")


def _not_only_dots(name: str) -> str:
    if set(name) == {"."}:
        raise ValueError(f"{name!r} is not a usable name: it would name a parent folder")
    return name


#: Names that become folder or file names: letters, digits, _ . - (not only dots), <= 64 long.
SafeName = Annotated[str, pydantic.StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$"),
                     pydantic.AfterValidator(_not_only_dots)]
#: An evaluation run with fewer samples gives no meaningful precision-recall curve.
MIN_EVALUATION_SAMPLES = 5


class Gates(Strict):
    """What an evaluation must show for touch to be able to matter there (`vitaplace difficulty`
    prints each against its value, MISSED when it is not met); every gate is optional."""

    touch_correspondence_min: float | None = pydantic.Field(
        None, ge=0, le=1, allow_inf_nan=False,
        description="least share of the touched queries with a true match whose nearest true match is touched "
        "(difficulty.touch_correspondence)",
    )
    rescue_min: float | None = pydantic.Field(
        None, ge=0, le=1, allow_inf_nan=False,
        description="least share of H-V's recall@1 failures that H-T gets right (complementarity rescue)",
    )
    hv_max_f1_max: float | None = pydantic.Field(
        None, ge=0, le=1, allow_inf_nan=False, description="most max F1 of H-V (vision alone must not solve it)",
    )
    headroom_min: float | None = pydantic.Field(
        None, ge=0, le=1, allow_inf_nan=False,
        description="least headroom: the recall@1 of an oracle taking H-V's or H-T's best match, whichever is "
        "right, minus the better of H-V's and H-T's (complementarity oracle_r1; what any fusion could add at most)",
    )
class QueryDropout(Strict):
    """Sensors lost at query time: shares of the query run's samples without the camera or
    without the whiskers (disjoint: a sample loses at most one)."""

    camera: float = pydantic.Field(0.0, ge=0, le=1, allow_inf_nan=False,
                                   description="share of the query samples without a camera frame")
    whiskers: float = pydantic.Field(0.0, ge=0, le=1, allow_inf_nan=False,
                                     description="share of the query samples without whisker signals and contacts")

    @pydantic.model_validator(mode="after")
    def _at_most_all(self) -> QueryDropout:
        if self.camera + self.whiskers > 1:
            raise ValueError(f"camera + whiskers is {self.camera + self.whiskers:g}: a sample loses at most one "
                             "sensor, so the shares sum to at most 1")
        return self


class EvaluationPair(_RunSource):
    """An evaluation: two simulated runs (in the shipped scenarios: independent teleoperated
    drives) or two recorded runs (query and reference)."""

    @pydantic.field_validator("run")
    @classmethod
    def _enough_samples(cls, run: RunSpec | None) -> RunSpec | None:
        if run is not None and run.n_samples < MIN_EVALUATION_SAMPLES:
            raise ValueError(f"an evaluation run needs at least {MIN_EVALUATION_SAMPLES} samples, got {run.n_samples}")
        return run

    name: SafeName = pydantic.Field(description="label of the evaluation (E1, E2, ...), letters, digits, _ . -")
    query_off_route: float = pydantic.Field(
        0.0, ge=0, le=0.9, allow_inf_nan=False,
        description="partial revisits: this fraction of the query run is driven off the route (the run's "
        "off_route_offset across it; route, orbit: the final part; teleop: detours spread along the "
        "run), so some queries have no true match",
    )
    query_condition: Condition | None = pydantic.Field(
        None,
        description="the lighting and camera state the query run is recorded under, instead of the run's "
        "`condition` (docs/SIMULATION.md, Conditions): a revisit in another season, at night, with a dirty lens",
    )
    reference_condition: Condition | None = pydantic.Field(
        None, description="the same for the reference run",
    )
    query_dropout: QueryDropout | None = pydantic.Field(
        None,
        description="sensor drop-out at query time: these shares of the query samples, drawn from the scenario "
        "seed, lack the camera or the whiskers, and each method describes them by the sensor left "
        "(docs/plugins.md, Missing modalities); give the evaluation a name of its own",
    )
    datasets: RecordedRuns | None = pydantic.Field(
        None,
        description="recorded query and reference runs instead of simulated ones (no run key then; environment "
        "optional: it only draws the arena in the report and bounds tau)",
    )
    gates: Gates = pydantic.Field(
        Gates(), description="the values `vitaplace difficulty` checks this evaluation against (scores no method)",
    )

    @pydantic.model_validator(mode="after")
    def _simulated_or_recorded(self) -> EvaluationPair:
        self._check_source("datasets", self.datasets is not None, environment_allowed=True)
        if self.query_off_route and (self.run is None or self.run.kind in ("foraging", "visits")):
            raise ValueError(
                "query_off_route needs a simulated teleop, stations, route or orbit run "
                "(not recorded runs, not foraging or visits)"
            )
        conditions = [k for k in ("query_condition", "reference_condition") if getattr(self, k) is not None]
        if conditions and self.run is None:
            raise ValueError(f"{conditions[0]} needs simulated runs ('environment' and 'run'), not recorded ones")
        return self

    def run_for(self, role: str) -> RunSpec:
        """The simulated run of ``role`` ("query" or "reference"): the query's carries the
        partial-revisit detour (``query_off_route``); each carries its role's condition
        (``query_condition``, ``reference_condition``) when one is given."""
        assert self.run is not None  # validated: simulated
        update: dict[str, Any] = {}
        if role == "query" and self.query_off_route:
            update["off_route_fraction"] = self.query_off_route
        condition = self.query_condition if role == "query" else self.reference_condition
        if condition is not None:
            update["condition"] = condition
        return self.run.model_copy(update=update) if update else self.run

    def recorded(self) -> dict[str, Path]:
        """``{"query": file, "reference": file}`` for recorded runs, else empty."""
        return {} if self.datasets is None else {"query": self.datasets.query, "reference": self.datasets.reference}


class Method(Strict):
    """A feature extractor to compare: a label, the plugin's extractor name, its parameters."""

    name: SafeName = pydantic.Field(description="label of the method in results and figures (L, H, ...)")
    plugin: str = pydantic.Field(
        description="name of the registered feature extractor (`vitaplace plugins` lists them)",
    )
    params: dict[str, Any] = pydantic.Field(
        {},
        description="the extractor's parameters (validated by the extractor, see its section)",
    )


#: the largest touch weight of a fusion: a float64 sum keeps 52 bits, so at w = 1e12 the vision
#: term (normalised to the touch term's scale) still moves it by 1e-12 of its size, about 4500 ulp
MAX_FUSION_WEIGHT = 1e12


class Fusion(Strict):
    """A late fusion of a vision-only and a touch-only method: d_V / σ_V + w · d_T / σ_T, w chosen
    on one evaluation (`vitaplace.engine.evaluation.fusion`)."""

    name: SafeName = pydantic.Field(description="label of the fused method in results and figures (H-F, L-F, ...)")
    vision: str = pydantic.Field(description="the vision-only method (a name under methods; validate refuses one "
                                 "whose plugin declares it uses touch or no vision)")
    touch: str = pydantic.Field(description="the touch-only method (a name under methods; validate refuses one "
                                "whose plugin declares it uses vision or no touch)")
    weights: list[pydantic.NonNegativeFloat] = pydantic.Field(
        [0.0, 0.03, 0.1, 0.3, 1.0, 3.0], min_length=1,
        description="the grid the touch weight w is chosen from (max F1 on select_on, ties to the smallest); each "
        f"at most {MAX_FUSION_WEIGHT:g} (beyond, the vision term is lost in the rounding of the sum, and the sum "
        "can overflow)",
    )
    select_on: str | None = pydantic.Field(
        None, description="the evaluation w is chosen on, in each direction (default: the training world's)"
    )

    @pydantic.field_validator("weights")
    @classmethod
    def _finite_distinct(cls, weights: list[float]) -> list[float]:
        if not all(math.isfinite(w) for w in weights) or len(set(weights)) != len(weights):
            raise ValueError(f"expected distinct finite weights >= 0, got {weights}")
        if max(weights) > MAX_FUSION_WEIGHT:
            raise ValueError(f"weight {max(weights):g}: expected at most {MAX_FUSION_WEIGHT:g} (beyond, the vision "
                             "term is lost in the rounding of the fused sum, and the sum can overflow)")
        return weights


#: Top-level scenario keys renamed since scenario files were first written: old name -> new.
#: Files (and ``--set`` paths) that use an old name are read under the new one, with a warning.
RENAMED_KEYS = {"evaluation": "scoring"}


def current_key(name: str, where: str) -> str:
    """The current name of the top-level key ``name`` (`RENAMED_KEYS`); an old name is logged
    as a warning naming ``where``."""
    new = RENAMED_KEYS.get(name, name)
    if new != name:
        log.warning("%s: '%s' is now called '%s'; read as '%s' (rename it there)", where, name, new, new)
    return new


def rename_legacy_keys(data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data`` with its `RENAMED_KEYS` under their new names (`current_key`); both names at
    once is a ScenarioError naming ``where``."""
    for old, new in RENAMED_KEYS.items():
        if old in data:
            if new in data:
                raise ScenarioError(
                    f"{where}: both '{old}' and '{new}' are set; '{old}' is the old name of '{new}', keep only '{new}'"
                )
            data[current_key(old, where)] = data.pop(old)
    return current_run_settings(data, where)


def current_run_settings(data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data`` with each ``run:``'s settings of an old name under the new one
    (`RENAMED_RUN_KEYS`) and the foraging gains given at its top level (the form before
    ``run.gains``) moved under ``gains``, each with one warning naming ``where`` and the key
    paths; a setting given in both forms is a ScenarioError."""
    runs: dict[str, Any] = {"train.run": data.get("train")}
    evaluations = data.get("evaluations")
    for i, entry in enumerate(evaluations if isinstance(evaluations, list) else []):
        runs[f"evaluations.{i}.run"] = entry
    paths, renamed = [], []
    for prefix, entry in runs.items():
        run = entry.get("run") if isinstance(entry, dict) else None
        if not isinstance(run, dict):
            continue
        try:
            run, old = rename_legacy_run_keys(run)
            gains = legacy_gain_paths(run)
            entry["run"] = nest_legacy_gains(run)
        except ValueError as exc:
            raise ScenarioError(f"{where}: {prefix}: {exc}") from None
        renamed += [f"{prefix}.{key}" for key in old]
        paths += [f"{prefix}.{key}" for key in gains]
    if paths:
        log.warning("%s: the foraging gains %s are now under 'run.gains'; read from there (move them)", where,
                    ", ".join(paths))
    for path in renamed:
        new = RENAMED_RUN_KEYS[path.rsplit(".", 1)[1]]
        log.warning("%s: '%s' is now called '%s'; read as '%s' (rename it there)", where, path, new, new)
    return data


class ComplementarityPair(Strict):
    """A vision-only and a touch-only method whose complementarity is measured (by name)."""

    vision: str = pydantic.Field(description="the vision-only method (a name under methods; validate refuses one "
                                 "whose plugin declares it uses touch or no vision)")
    touch: str = pydantic.Field(description="the touch-only method (a name under methods; validate refuses one "
                                "whose plugin declares it uses vision or no touch)")


class SequenceSettings(Strict):
    """SeqSLAM-style sequence matching of the distances (`vitaplace.engine.evaluation.sequence`)."""

    length: pydantic.PositiveInt = pydantic.Field(
        1, description="queries per sequence (the query and the length - 1 before it), or with metres the points "
        "over those metres; 1: single-sample matching (window, metres and the velocities are then kept, not read, so "
        "that a grid over length or metres shares them, as the shipped studies' do)"
    )
    metres: float | None = pydantic.Field(
        None, ge=0, allow_inf_nan=False,
        description="match over this much travelled distance [m] of each run's poses (SeqSLAM with odometry: length "
        "points evenly spaced back from the sample, each the nearest sample) instead of length samples; velocities "
        "do not apply; 0: single-sample matching; null: length samples",
    )
    velocities: tuple[pydantic.PositiveFloat, pydantic.PositiveFloat] = pydantic.Field(
        (0.8, 1.25), description="[slowest, fastest] relative velocity searched (references per query)"
    )
    velocity_steps: pydantic.PositiveInt = pydantic.Field(
        5, le=1000, description="velocities tried, evenly spaced over velocities (1: the slowest only), at most 1000"
    )
    window: pydantic.PositiveInt = pydantic.Field(
        10, description="local contrast: references on either side whose mean and spread normalise an entry"
    )

    @pydantic.model_serializer(mode="wrap")
    def _metres_when_set(self, handler: pydantic.SerializerFunctionWrapHandler) -> dict[str, Any]:
        """The settings without ``metres`` when it is null: a scenario without it dumps, and so
        keys its evaluations, as before the option existed."""
        data: dict[str, Any] = handler(self)
        if self.metres is None:
            data.pop("metres", None)
        return data

    @pydantic.model_validator(mode="after")
    def _ordered(self) -> SequenceSettings:
        fields = type(self).model_fields
        if self.metres is not None and (self.velocities, self.velocity_steps) != (
                fields["velocities"].default, fields["velocity_steps"].default):
            raise ValueError("velocities: searched only by a sequence of length samples; with metres the sequence "
                             "follows the odometry (leave velocities and velocity_steps at their defaults)")
        low, high = self.velocities
        if not (math.isfinite(low) and math.isfinite(high)) or low > high:
            raise ValueError(f"velocities: expected [slowest, fastest] with 0 < slowest <= fastest, both finite, "
                             f"got [{low:g}, {high:g}]")
        if self.velocity_steps > 1 and low == high:
            raise ValueError(f"velocities: an empty range [{low:g}, {high:g}] "
                             f"with velocity_steps {self.velocity_steps}; "
                             "expected slowest < fastest, or velocity_steps 1")
        return self


class ScoringSettings(Strict):
    tau: float = pydantic.Field(
        0.3, gt=0, allow_inf_nan=False, description="ground-truth revisit tolerance [m], below the arena's diagonal"
    )
    heading_tolerance_deg: float | None = pydantic.Field(
        30.0, ge=0, le=180, allow_inf_nan=False,
        description="a true match also faces within this many degrees of the query (wrapped yaw difference); "
        "null: position only",
    )
    delta: float | None = pydantic.Field(
        None, ge=0, allow_inf_nan=False,
        description="fixed acceptance threshold for the F1 at delta: a query's best match is accepted when the "
        "method's distance to it (>= 0) is at most delta; null: no fixed threshold",
    )
    recall_k: list[pydantic.PositiveInt] = pydantic.Field(
        [1, 5, 10], description="K values of recall@K, distinct; each below every evaluation's reference samples "
        "(`vitaplace validate` checks it against the runs; of the default list, a K not below a run's samples is "
        "left out of its row, with a warning)",
    )
    direction: typing.Literal["query-to-reference", "reference-to-query", "both"] = pydantic.Field(
        "query-to-reference",
        description="which run queries which: query-to-reference, the reverse, or both",
    )
    sequence: SequenceSettings = pydantic.Field(
        SequenceSettings(),
        description="sequence matching (SeqSLAM): each query scored by the best straight line of length queries "
        "through the locally normalised distances, or with metres by length points over that travelled distance; "
        "length 1 (the default) matches single samples",
    )
    @pydantic.field_validator("recall_k")
    @classmethod
    def _distinct_ks(cls, ks: list[int]) -> list[int]:
        repeated = [k for i, k in enumerate(ks) if k in ks[:i]]
        if repeated:
            raise ValueError(f"K {repeated[0]} is given more than once in {ks}; expected distinct K values")
        return ks

    complementarity: list[ComplementarityPair] = pydantic.Field(
        [],
        description="vision-only and touch-only methods to measure the complementarity of, besides the pairs "
        "found by themselves (one plugin's vision-only and touch-only configurations; complementarity.json)",
    )


class ReportSettings(Strict):
    """Read from the run's scenario.resolved.yaml, so `vitaplace report OUT` draws the same."""

    figures: typing.Literal["all", "summary", "none"] = pydantic.Field(
        "all",
        description="all: every figure; summary: each evaluation's PR curves and each method's training energy, "
        "no per-method matrices or trajectories; none: report.md alone. A sweep's seeds default to summary",
    )
    pdf: bool = pydantic.Field(False, description="each figure as a PDF besides its PNG (needs figures)")

    @pydantic.model_validator(mode="after")
    def _figures_for_pdf(self) -> ReportSettings:
        if self.pdf and self.figures == "none":
            raise ValueError("pdf true draws each figure as a PDF too, and figures none draws none; set figures to "
                             "all or summary, or leave pdf out")
        return self


class Scenario(Strict):
    name: SafeName = pydantic.Field(description="the scenario's name (reports, output folders): letters, digits, _ . -")
    description: str = pydantic.Field("", description="free text shown in the report")
    seed: int = pydantic.Field(
        0, ge=0, lt=2**32,
        description="master seed: every run's and method's seed derives from it",
    )
    robot: RobotSpec = pydantic.Field(
        RobotSpec(),
        description="robot, sensors and physics for every run of the scenario",
    )
    train: TrainingData = pydantic.Field(description="the run the methods are fitted on")
    evaluations: list[EvaluationPair] = pydantic.Field(
        min_length=1,
        description="evaluation environments, each with a query and a reference run",
    )
    methods: list[Method] = pydantic.Field(min_length=1, description="the feature extractors compared")
    scoring: ScoringSettings = pydantic.Field(
        ScoringSettings(),
        description="how features are scored (an older file's `evaluation:` is read as this, with a warning)",
    )
    fusions: list[Fusion] = pydantic.Field(
        [], description="late fusions of two of the methods, scored like a method (docs/DESIGN.md, Late fusion)"
    )
    report: ReportSettings = pydantic.Field(ReportSettings(), description="which figures the report draws")

    @pydantic.model_validator(mode="after")
    def _unique_names(self) -> Scenario:
        for what, items in (("methods", self.methods), ("evaluations", self.evaluations)):
            names = [item.name for item in items]
            if len(set(names)) != len(names):
                raise ValueError(f"{what}: names must be unique, got {names}")
        methods = [m.name for m in self.methods]
        for i, pair in enumerate(self.scoring.complementarity):
            for role in ("vision", "touch"):
                if getattr(pair, role) not in methods:
                    raise ValueError(f"scoring.complementarity.{i}.{role}: no method '{getattr(pair, role)}' "
                                     f"(methods: {', '.join(methods)})")
            if pair.vision == pair.touch:
                raise ValueError(f"scoring.complementarity.{i}: vision and touch are the same method '{pair.vision}'; "
                                 "expected two different methods")
        return self

    @pydantic.model_validator(mode="after")
    def _fusions_name_methods(self) -> Scenario:
        methods, evaluations = [m.name for m in self.methods], [e.name for e in self.evaluations]
        fused = [f.name for f in self.fusions]
        for i, f in enumerate(self.fusions):
            if f.name in methods or f.name in fused[:i]:
                raise ValueError(f"fusions.{i}.name: '{f.name}' is already a method's or another fusion's name; "
                                 "expected a name of its own")
            for role in ("vision", "touch"):
                if getattr(f, role) not in methods:
                    raise ValueError(
                        f"fusions.{i}.{role}: no method '{getattr(f, role)}' (methods: {', '.join(methods)})")
            if f.vision == f.touch:
                raise ValueError(f"fusions.{i}: vision and touch are the same method '{f.vision}'; expected two "
                                 "different methods")
            if f.select_on is not None and f.select_on not in evaluations:
                raise ValueError(f"fusions.{i}.select_on: no evaluation '{f.select_on}' "
                                 f"(evaluations: {', '.join(evaluations)})")
            if f.select_on is None and training_world_evaluation(self)[0] is None:
                raise ValueError(f"fusions.{i}.select_on: no evaluation in the training world to choose the weight "
                                 f"on ({training_world_evaluation(self)[1]}); name one")
        return self

    @pydantic.model_validator(mode="after")
    def _sequences_fit(self) -> Scenario:
        """A sequence no longer than any simulated run it is matched on (a recorded run is
        checked when it is scored)."""
        length = self.scoring.sequence.length
        if self.scoring.sequence.metres is not None:  # points of the odometry, not samples
            return self
        for i, e in enumerate(self.evaluations):
            if e.run is not None and length > e.run.n_samples:
                raise ValueError(f"scoring.sequence.length: {length} is longer than evaluation {e.name}'s runs "
                                 f"(evaluations.{i}.run.n_samples {e.run.n_samples}); expected at most that")
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
