"""Checks of a validated scenario's runs against what they name: recorded run files (there,
readable, long enough, shaped like the training run, query and reference distinct, the
training run no evaluation's query run and warned about when it is a reference run) and
environments (there, and the runs plausible in them; ``scoring.tau`` below each arena's
diagonal); a stations run's approach jitter within the ground truth's tolerances."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vitaplace.engine.base.shipped import shipped_names_hint
from vitaplace.engine.config.scenario import (
    MIN_EVALUATION_SAMPLES,
    EvaluationPair,
    RecordedRuns,
    Scenario,
    ScenarioError,
    ScoringSettings,
)
from vitaplace.engine.data.dataset import DatasetError, Run, open_run, recorded_tactile_model, shape_problem
from vitaplace.engine.outputs.checksum import digest
from vitaplace.engine.sim.controllers import RunSpec
from vitaplace.engine.sim.environment import load_environment
from vitaplace.engine.sim.plausibility import ImplausibleRun, check_run

log = logging.getLogger("vitaplace")


def check_runs(path: Path, scenario: Scenario) -> int:
    """Check every run of ``scenario`` (read from ``path``, which errors name); return the
    number of samples of the training run."""
    (train_samples, lengths), robot = _check_recorded_runs(path, scenario), scenario.robot
    for where, entry in [("train", scenario.train)] + [
        (f"evaluations.{i}", e) for i, e in enumerate(scenario.evaluations)
    ]:
        if entry.environment is None:
            continue
        if not entry.environment.is_file():
            raise ScenarioError(f"{path}: {where}.environment: {_not_a_file(entry.environment)} "
                                f"({shipped_names_hint(entry.environment)})")
        env = load_environment(entry.environment)
        if entry.run is not None and where != "train":
            _check_station_jitter(path, where, entry.run, scenario)
        if entry.run is not None:
            runs = ([entry.run_for(role) for role in ("query", "reference")] if isinstance(entry, EvaluationPair)
                    else [entry.run])
            for run in runs:
                try:
                    check_run(env, run, robot)
                except ImplausibleRun as exc:
                    raise ScenarioError(f"{path}: {where}.run.{exc.key}: {exc}") from None
        problem = tau_problem(scenario.scoring.tau, env.arena.half_x, env.arena.half_y, env.name)
        if where != "train" and problem:
            raise ScenarioError(f"{path}: scoring.tau: {problem}")
    _check_recall_k(path, scenario, lengths)
    return train_samples


#: the side of an evaluation whose samples are searched, by ``scoring.direction``
REFERENCE_SIDES = {"query-to-reference": ("reference",), "reference-to-query": ("query",),
                   "both": ("reference", "query")}


def _check_recall_k(path: Path, scenario: Scenario, lengths: dict[Path, int]) -> None:
    """Every K of ``scoring.recall_k`` below the samples of every run searched (each
    evaluation's reference side in each direction): at K >= the references every query with a
    true match has it among its first K, so recall@K is 100 % for any method. The default list
    is not refused: in a run of a few samples scoring leaves such a K out, with a run warning
    (`vitaplace.engine.pipeline.scoring.searchable_ks`). ``lengths``: the
    samples of each recorded evaluation run (`_check_recorded_runs` read them)."""
    ks = scenario.scoring.recall_k
    if not ks or ks == ScoringSettings.model_fields["recall_k"].default:
        return
    k = max(ks)
    for i, e in enumerate(scenario.evaluations):
        for side in REFERENCE_SIDES[scenario.scoring.direction]:
            if e.datasets is not None:
                file = getattr(e.datasets, side)
                where, n = f"evaluations.{i}.datasets.{side} {file}", lengths[file]
            else:
                assert e.run is not None  # validated: simulated
                where, n = f"evaluations.{i}.run.n_samples", e.run.n_samples
            if k >= n:
                raise ScenarioError(
                    f"{path}: scoring.recall_k: K {k} is not below the {n} reference samples of evaluation {e.name} "
                    f"({where}): recall@K would count every query with a true match as found; expected each K "
                    f"< {n}")


def tau_problem(tau: float, half_x: float, half_y: float, environment: str) -> str | None:
    """Why ``tau`` cannot be the revisit tolerance of an evaluation in the arena of half extents
    ``half_x`` x ``half_y`` (of the environment named ``environment``), in words; None when it
    can. Not below the arena's diagonal, every pair of poses would count as a revisit. The
    one check of a tolerance, for a scenario (`check_runs`) and ``vitaplace sensitivity --tau``."""
    diagonal = 2 * math.hypot(half_x, half_y)
    if tau >= diagonal:
        return (f"{tau} m is not below the {diagonal:.2f} m diagonal of {environment}: every pair of poses would "
                "count as a revisit")
    return None


def _check_tau_on_poses(path: Path, tau: float, i: int, runs: list[Run]) -> None:
    """`tau_problem` for a recorded evaluation without an environment: the arena is the box
    around the positions its query and reference ``runs`` recorded."""
    xy = np.concatenate([np.asarray(run.poses, dtype=float)[:, :2] for run in runs])
    half_x, half_y = (xy.max(axis=0) - xy.min(axis=0)) / 2
    problem = tau_problem(tau, half_x, half_y, f"the box of the poses evaluations.{i}.datasets recorded")
    if problem:
        raise ScenarioError(f"{path}: scoring.tau: {problem}")


def _check_recorded_runs(path: Path, scenario: Scenario) -> tuple[int, dict[Path, int]]:
    """The recorded run files of ``scenario``: there, long enough, shaped like the training
    run, query and reference distinct, one tactile model with the simulated runs; return the
    number of samples of the training run and of each recorded evaluation run."""
    train_samples = scenario.train.run.n_samples if scenario.train.run else 0
    robot = scenario.robot
    # what every run must share with the training run: whiskers, image size, tactile model
    simulated = TactileSource("the simulated runs (robot.tactile_model)", robot.tactile_model)
    train_shape = (robot.n_whiskers, (robot.camera_height, robot.camera_width, 3))
    train_touch = simulated
    if scenario.train.dataset is not None:
        train = _recorded(path, "train.dataset", scenario.train.dataset, 1)
        train_samples, train_shape = len(train), (train.n_whiskers, train.image_shape)
        train_touch = TactileSource(f"the training run {train.path}", recorded_tactile_model(train))
    recorded: list[TactileSource] = []
    lengths: dict[Path, int] = {}
    digests: dict[Path, str] = {}  # each recorded file's content digest, read once
    for i, e in enumerate(scenario.evaluations):
        runs = []
        for side, file in e.recorded().items():
            where = f"evaluations.{i}.datasets.{side}"
            run = _recorded(path, where, file, MIN_EVALUATION_SAMPLES)
            runs.append(run)
            lengths[file] = len(run)
            _check_like_training(path, where, run, train_shape)
            recorded.append(TactileSource(f"{where} {run.path}", recorded_tactile_model(run)))
        if e.datasets is not None:
            _check_distinct(path, f"evaluations.{i}.datasets", e.datasets, digests)
            if e.environment is None:  # no arena to bound tau by: the poses the two runs recorded
                _check_tau_on_poses(path, scenario.scoring.tau, i, runs)
        elif e.run is not None:
            recorded.append(simulated)
    _check_training_run(path, scenario, digests)
    _check_one_tactile_model(path, [train_touch, *recorded])
    if scenario.train.dataset is not None and all(e.datasets is not None for e in scenario.evaluations) \
            and "tactile_model" in robot.model_fields_set:
        log.warning("%s: robot.tactile_model (%s) has no effect: every run is recorded (each file says its own)",
                    path, robot.tactile_model)
    return train_samples, lengths


@dataclass(frozen=True)
class TactileSource:
    """Where a run's whisker signal comes from: a description and its tactile model (None:
    a recorded file that does not say)."""

    what: str
    model: str | None


def _check_one_tactile_model(path: Path, sources: list[TactileSource]) -> None:
    """Every run of a scenario has one tactile model: physical and penetration xy are different
    quantities (|xy| up to 0.22 against 1.29), so a method fitted on one misreads the other.
    Files that do not say are not compared."""
    known = [s for s in sources if s.model is not None]
    other = next((s for s in known if s.model != known[0].model), None)
    if other is not None:
        raise ScenarioError(f"{path}: tactile_model: {known[0].what} has {known[0].model}, {other.what} has "
                            f"{other.model}; every run of a scenario needs the same tactile model")


def _check_station_jitter(path: Path, where: str, run: RunSpec, scenario: Scenario) -> None:
    """Two station drives approach a station up to twice its jitter apart (each within it of
    the station): that must stay within ``scoring.tau`` and the heading tolerance, or a
    touched query could have no true match at its own station."""
    if run.kind != "stations":
        return
    tau, heading = scenario.scoring.tau, scenario.scoring.heading_tolerance_deg
    if 2 * run.station_jitter > tau:
        raise ScenarioError(f"{path}: {where}.run.station_jitter: {run.station_jitter:g} m lets two drives approach a "
                            f"station {2 * run.station_jitter:g} m apart, more than scoring.tau = {tau:g} m; at most "
                            f"{tau / 2:g} m")
    if heading is not None and 2 * run.station_heading_jitter_deg > heading:
        raise ScenarioError(f"{path}: {where}.run.station_heading_jitter_deg: {run.station_heading_jitter_deg:g} deg "
                            f"lets two drives face a station {2 * run.station_heading_jitter_deg:g} deg apart, more "
                            f"than scoring.heading_tolerance_deg = {heading:g}; at most {heading / 2:g} deg")


def _not_a_file(file: Path) -> str:
    """Why ``file``, which is no file, cannot be read: a folder is there, or nothing."""
    return f"{str(file)!r} is a folder; expected a file" if file.is_dir() else f"no such file {str(file)!r}"


def _recorded(path: Path, where: str, file: Path, minimum: int) -> Run:
    """The recorded run ``file``, opened (its attributes, fields, storage and shapes checked)
    and with at least ``minimum`` samples."""
    if not file.is_file():
        raise ScenarioError(f"{path}: {where}: {_not_a_file(file)} (make one with `vitaplace import`)")
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
    problem = shape_problem(run, *train, "the training run")
    if problem:
        raise ScenarioError(f"{path}: {where}: {problem}")


def _recording(file: Path, digests: dict[Path, str]) -> str:
    """What identifies the recording ``file`` holds: its content's digest (a copy or a link
    is the same recording), kept in ``digests`` so that each file is read once."""
    if file not in digests:
        digests[file] = digest(file)
    return digests[file]


def _check_distinct(path: Path, where: str, datasets: RecordedRuns, digests: dict[Path, str]) -> None:
    """Query and reference are two recordings: the same file (or the same content) would
    match every query to itself and score 100 %."""
    if _recording(datasets.query, digests) == _recording(datasets.reference, digests):
        raise ScenarioError(
            f"{path}: {where}: query {datasets.query} and reference {datasets.reference} are the same recording; "
            "an evaluation needs two separate runs"
        )


def _check_training_run(path: Path, scenario: Scenario, digests: dict[Path, str]) -> None:
    """A recorded training run is none of the evaluations' query recordings (the methods would
    be fitted on the very samples that are scored: leakage), and is warned about when it is a
    reference recording (building the map from the reference traverse can be a design, but
    every score of that evaluation then reads features fitted on the run it searches)."""
    train = scenario.train.dataset
    if train is None:
        return
    for i, e in enumerate(scenario.evaluations):
        for side, file in e.recorded().items():
            if _recording(file, digests) != _recording(train, digests):
                continue
            same = f"train.dataset {train} is the same recording as evaluations.{i}.datasets.{side} {file}"
            if side == "query":
                raise ScenarioError(f"{path}: {same}: the methods would be fitted on the queries evaluation {e.name} "
                                    "scores; expected a training run of its own")
            log.warning("%s: %s: the methods are fitted on the run evaluation %s searches, so its scores measure "
                        "recognising places of the training run itself", path, same, e.name)
