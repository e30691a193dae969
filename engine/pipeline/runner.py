"""The scenario pipeline's stages: simulate -> fit -> transform -> evaluate -> report, cached per stage
(`vitaplace.engine.pipeline.orchestrate.run_stages` runs them in order).

Every stage's output is named by a hash of everything it depends on
(config, upstream keys, format versions, the code digest of the plugin that runs it) and of
the digests of the upstream outputs it reads, as DVC does: a re-run skips finished stages,
an interrupted run resumes with the first missing output, and ``force`` redoes named stages
and, when their output changed, every stage downstream that reads it (an identical output
leaves the downstream keys, and so their cached work, as they were). A run ends by writing
its completion record (`vitaplace.engine.outputs.completion`). Where each output lives
(`vitaplace.engine.outputs.outdir`): runs, models and features in the cache (``OUT/cache``, or
the sweep's shared one), each evaluation under ``OUT/evaluations``, the report and what it is
built from in ``OUT`` itself.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import EvaluationPair, Method, Scenario, ScenarioError, TrainingData, training_world_evaluation
from vitaplace.engine.data.dataset import SCHEMA_VERSION, Run, dropout_masks, open_run, run_facts
from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation.difficulty import STAY_RADIUS, longest_stay
from vitaplace.engine.config.methods import complementarity_pairs
from vitaplace.engine.evaluation.complementarity import complementarity
from vitaplace.engine.evaluation.pairfiles import evaluate_pair, load_curve, load_decisions
from vitaplace.engine.outputs import checksum
from vitaplace.engine.outputs import outdir
from vitaplace.engine.base.cpus import usable_cpus
from vitaplace.engine.outputs.keys import content_hash
from vitaplace.engine.extension.features import FeatureExtractor, feature_facts, load_features, save_features, warn_once
from vitaplace.engine.pipeline.fusing import evaluate_fusions
from vitaplace.engine.pipeline.output_checks import check_distance, check_features
from vitaplace.engine.pipeline.records import (EvaluateRecord, FitRecord, RunRecord, SimulateRecord, StageRecord,
                                              TransformRecord)
from vitaplace.engine.pipeline.simulation import SimulationJob, simulate_here, simulations_in_workers
from vitaplace.engine.extension.registry import Registry, discover, plugin_distributions
from vitaplace.engine.sim import SIMULATOR_VERSION
from vitaplace.engine.sim.controllers import key_form
from vitaplace.engine.sim.environment import load_environment
from vitaplace.engine.sim.plausibility import LONG_SECONDS, duration, estimated_seconds

STAGES = ("simulate", "fit", "transform", "evaluate", "report")
#: Bump when a stage's output format or algorithm changes, to invalidate old caches.
STAGE_VERSION = {"simulate": SCHEMA_VERSION, "fit": 3, "transform": 4, "evaluate": 7, "report": 10}

#: a run that stays in one place this long (share of its samples, and samples) is warned about:
#: a quarter of any run, and 10 samples (5 s) at least, so that a short run's stay is found too
STUCK_SHARE, STUCK_SAMPLES = 0.25, 10
#: an evaluation with fewer queries that have a true match is warned about: below 10, one
#: query's decision moves recall by more than 10 points, too coarse to compare methods by
MIN_REVISITS = 10

log = logging.getLogger("vitaplace")


def is_stuck(stay: int, samples: int) -> bool:
    """Whether a longest stay of ``stay`` samples in a run of ``samples`` is a stuck drive:
    at least `STUCK_SHARE` of the run and `STUCK_SAMPLES`."""
    return stay >= max(STUCK_SAMPLES, STUCK_SHARE * samples)


@dataclass
class RunnerState:
    records: list[StageRecord] = field(default_factory=list)
    datasets: dict[str, str] = field(default_factory=dict)  # run label -> dataset key
    #: output path -> SHA-256 of its content, for each output done in this run (`checksum`)
    digests: dict[str, str] = field(default_factory=dict)


def seed_for(scenario_seed: int, *path: int) -> int:
    """Independent, reproducible seeds for the runs of a scenario (numpy SeedSequence)."""
    return int(np.random.SeedSequence([scenario_seed, *path]).generate_state(1)[0])


class Pipeline:
    """Runs the stages of one scenario into an output directory."""

    def __init__(
        self,
        scenario: Scenario,
        resolved: dict[str, Any],
        out: Path,
        force: Iterable[str] = (),
        progress: bool = True,
        registry: Registry | None = None,
        workers: int | None = None,
        cache: Path | None = None,
    ) -> None:
        self.scenario, self.resolved, self.out = scenario, resolved, Path(out)
        self.force = set(force)
        unknown = self.force - set(STAGES)
        if unknown:
            raise ScenarioError(f"--force: unknown stage(s) {', '.join(sorted(unknown))}; stages: {', '.join(STAGES)}")
        self.progress = progress
        #: processes recording runs in parallel (default: one per CPU this process may use)
        self.workers = workers or usable_cpus()
        self.registry = registry or discover()
        #: where stage outputs are cached (default OUT/cache; sweeps share one across seeds)
        self.cache = Path(cache) if cache is not None else outdir.cache_dir(self.out)
        self.state = RunnerState()
        self.extractors: dict[str, FeatureExtractor] = {}
        self.opened: dict[str, Run] = {}
        #: run label -> recorded run file, for runs the scenario gives as files (not simulated)
        self.recorded: dict[str, Path] = {}
        if scenario.train.dataset is not None:
            self.recorded["train"] = scenario.train.dataset
        for e in scenario.evaluations:
            self.recorded.update({f"{e.name}/{side}": file for side, file in e.recorded().items()})

    # ------------------------------------------------------------------ bookkeeping
    def done(self, stage: str, item: str, output: Path, key: str) -> bool:
        """The one "done" rule of every stage: ``output`` is there and sealed for ``key`` with
        a matching digest (`checksum`); anything else but "not made yet" is logged."""
        problem = checksum.check(output, key)
        if problem is None:
            return True
        if problem not in ("absent", "made for other settings"):
            log.warning("%-9s %-28s cached output %s is %s: recomputing", stage, item, output.name, problem)
        return False

    def stage(
        self, stage: str, item: str, key: str, output: Path, work: Callable[[], Any], inputs: Iterable[str] = (),
        done: bool | None = None,
    ) -> Any:
        """Run ``work()`` unless ``output`` is done for ``key`` (`done`, or ``done`` when the
        caller has checked already) and the stage is not forced; seal what it wrote."""
        start = time.perf_counter()
        if done is None:
            done = self.done(stage, item, output, key)
        if done and stage not in self.force:
            status = "cached"
            log.info("%-9s %-28s cached (%s)", stage, item, key)
            result = None
            self._restore_warnings(output)
        else:
            status = "ran"
            log.info("%-9s %-28s running (%s)", stage, item, key)
            before = {label: set(run.warnings) for label, run in self.opened.items()}
            result = work()
            self._keep_warnings(output, before)
            checksum.seal(output, key)
        self.state.digests[str(output)] = checksum.sealed_digest(output)
        seconds = time.perf_counter() - start
        where = output.relative_to(self.out) if output.is_relative_to(self.out) else output
        log.debug("%-9s %-28s %s in %.2f s: %s", stage, item, status, seconds, where)
        self.state.records.append(StageRecord(stage, item, key, status, round(seconds, 3), list(inputs), str(where)))
        return result

    @staticmethod
    def _warnings_path(output: Path) -> Path:
        return output.with_name(output.name + ".warnings.json")

    def _keep_warnings(self, output: Path, before: dict[str, set[str]]) -> None:
        """Beside a stage's output, the run warnings its work raised (label -> feature ->
        message), so that a later run that finds the stage cached reports them too."""
        raised = {label: {k: v for k, v in run.warnings.items() if k not in before.get(label, set())}
                  for label, run in self.opened.items()}
        raised = {label: warnings for label, warnings in raised.items() if warnings}
        path = self._warnings_path(output)
        if raised:
            write_text_atomic(path, json.dumps(raised))
        else:
            path.unlink(missing_ok=True)

    def _restore_warnings(self, output: Path) -> None:
        """The run warnings the work of a now cached stage raised (`_keep_warnings`)."""
        path = self._warnings_path(output)
        if path.is_file():
            for label, warnings in json.loads(path.read_text()).items():
                for feature, message in warnings.items():
                    self.open(label).warnings.setdefault(feature, message)

    # ------------------------------------------------------------------ simulate
    def runs(self) -> dict[str, tuple[TrainingData | EvaluationPair, int]]:
        """Every run of the scenario: label -> (spec, seed); `recorded` ones are not simulated."""
        s = self.scenario
        runs = {"train": (s.train, seed_for(s.seed, 0))}
        for i, e in enumerate(s.evaluations):
            runs[f"{e.name}/query"] = (e, seed_for(s.seed, i + 1, 1))
            runs[f"{e.name}/reference"] = (e, seed_for(s.seed, i + 1, 2))
        return runs

    def output_digest(self, path: Path) -> str:
        """SHA-256 of the content of an output this run has made or verified (or of a recorded
        run file): the part of a downstream key that follows what the stage actually read."""
        return self.state.digests[str(path)]

    def dataset_digest(self, label: str) -> str:
        return self.output_digest(self.dataset_path(label))

    def dataset_path(self, label: str) -> Path:
        if label in self.recorded:
            return self.recorded[label]
        return outdir.dataset_file(self.cache, label, self.state.datasets[label])

    def dropout_of(self, label: str, samples: int) -> dict[str, np.ndarray]:
        """The drop-out masks of run ``label`` of ``samples`` samples (`dropout_masks`): for the
        query run of an evaluation with a ``query_dropout``, drawn from a seed of the scenario
        seed and the evaluation's place; empty for every other run."""
        for i, e in enumerate(self.scenario.evaluations):
            if e.query_dropout is not None and label == f"{e.name}/query":
                return dropout_masks(samples, e.query_dropout.model_dump(), self.dropout_seed(i))
        return {}

    def dropout_seed(self, index: int) -> int:
        """The seed that draws the query drop-out of evaluation ``index`` (its runs' are 1 and 2)."""
        return seed_for(self.scenario.seed, index + 1, 3)

    def dropout_record(self) -> dict[str, dict[str, Any]]:
        """Per query run with a drop-out: its seed and the samples that lack each sensor."""
        record = {}
        for i, e in enumerate(self.scenario.evaluations):
            if e.query_dropout is not None:
                masks = self.open(f"{e.name}/query").missing
                record[f"{e.name}/query"] = {"seed": self.dropout_seed(i),
                                             **{sensor: np.flatnonzero(m).tolist() for sensor, m in masks.items()}}
        return record

    def use_recorded(self, label: str) -> None:
        """A recorded run instead of a simulation: open and check it (format, shapes, finite
        values); its key is the file's SHA-256, so a changed file re-runs what depends on it."""
        start = time.perf_counter()
        path = self.recorded[label]
        run = open_run(path)
        run.validate()
        run.name = label  # warnings and errors name the run as the scenario does
        run.missing = self.dropout_of(label, len(run))
        self.opened[label] = run
        digest = checksum.digest(path)
        key = content_hash("recorded", STAGE_VERSION["simulate"], digest)
        self.state.datasets[label] = key
        self.state.digests[str(path)] = digest
        log.info("%-9s %-28s recorded run %s (%s)", "simulate", label, path, key)
        seconds = round(time.perf_counter() - start, 3)
        self.state.records.append(StageRecord("simulate", label, key, "recorded", seconds, [], str(path)))

    def simulate(self) -> SimulateRecord:
        """Record every run not cached yet; several runs are recorded by parallel processes."""
        jobs = []
        for label, (entry, seed) in self.runs().items():
            if label in self.recorded:
                self.use_recorded(label)
                continue
            assert entry.environment is not None and entry.run is not None  # validated: simulated
            environment = load_environment(entry.environment)
            run = entry.run_for(label.rsplit("/", 1)[1]) if isinstance(entry, EvaluationPair) else entry.run
            spec = [environment.model_dump(mode="json"), key_form(run)]  # the version-6 key form: keys stay valid
            key = content_hash("simulate", STAGE_VERSION["simulate"], SIMULATOR_VERSION, spec,
                               self.scenario.robot.model_dump(mode="json"), seed)
            self.state.datasets[label] = key
            jobs.append(SimulationJob(label, str(entry.environment), run.model_dump(), self.scenario.robot.model_dump(),
                                      seed, key, self.dataset_path(label), estimated_seconds(run, self.scenario.robot)))
        pending = [job for job in jobs if "simulate" in self.force or not self.done("simulate", job.label, job.path, job.key)]
        for job in pending:
            if job.estimate > LONG_SECONDS:
                log.warning("%-9s %-28s a long simulation: about %s on one core (estimate)", "simulate", job.label,
                            duration(job.estimate))
        with simulations_in_workers(pending, self.workers) as in_workers:
            for job in jobs:
                work = in_workers.get(job.label) or partial(simulate_here, job, self.progress)
                simulated = self.stage("simulate", job.label, job.key, job.path, work, done=job not in pending)
                if simulated is not None:  # the simulation's own time, not the wait for its worker
                    self.state.records[-1].seconds = round(simulated[1], 3)
        self.warn_collisions()
        self.warn_stays()
        return SimulateRecord(
            datasets=dict(self.state.datasets), recorded={label: str(path) for label, path in self.recorded.items()},
            run_seeds={label: seed for label, (_, seed) in self.runs().items() if label not in self.recorded},
            runs={label: run_facts(self.open(label)) for label in self.runs()}, dropout=self.dropout_record(),
        )

    def warn_collisions(self) -> None:
        """Warn (log, manifest.json, report.md) about every run in which the robot's body or
        head touched the world (``body_collision_instants`` > 0 in its attributes)."""
        for label in self.runs():
            run = self.open(label)
            instants = int(run.attrs.get("body_collision_instants", 0))
            if instants > 0:
                warn_once(run, "body_collision_instants",
                          f"run {label}: the robot's body or head touched a landmark or wall at {instants} "
                          f"whisk-series instant(s) (body_collision_instants): it was not driven clear of the world")

    def warn_stays(self) -> None:
        """Warn about every run whose robot stayed in one place (`longest_stay`) for at
        least `STUCK_SHARE` of its samples, and at least `STUCK_SAMPLES`: a stuck drive, whose
        samples repeat one place and would make that world's scores unrepresentative."""
        for label in self.runs():
            run = self.open(label)
            length, start = longest_stay(run.poses[:, :2])
            if is_stuck(length, len(run.poses)):
                warn_once(run, "longest_stay",
                          f"run {label}: the robot stayed within {STAY_RADIUS} m of one place for {length} of its "
                          f"{len(run.poses)} samples, from sample {start} (longest_stay): it got stuck there")

    def open(self, label: str) -> Run:
        """The recorded run ``label``, opened once per pipeline (its fields load lazily, once)."""
        if label not in self.opened:
            run = open_run(self.dataset_path(label))
            run.missing = self.dropout_of(label, len(run))
            self.opened[label] = run
        return self.opened[label]

    # ------------------------------------------------------------------ fit / transform
    def params_for(self, method: Method) -> dict[str, Any]:
        """The parameters handed to the method's plugin: the scenario's, with ``seed`` derived from the scenario seed when the
        extractor takes one and the scenario does not set it (so every scenario seed also
        changes the method's initialisation)."""
        params = dict(method.params)
        if "seed" not in params and "seed" in self.registry.get(method.plugin).Params.model_fields:
            index = [m.name for m in self.scenario.methods].index(method.name)
            params["seed"] = seed_for(self.scenario.seed, 1000 + index)
        return params

    def model_key(self, method: Method) -> str:
        return content_hash(
            "fit", STAGE_VERSION["fit"], method.plugin, self.registry.version_of(method.plugin),
            self.registry.code_digest(method.plugin), self.params_for(method), self.state.datasets["train"],
            self.dataset_digest("train"),
        )

    def model_dir(self, method: Method) -> Path:
        return outdir.model_dir(self.cache, method.name, self.model_key(method))

    def fit(self) -> FitRecord:
        for method in self.scenario.methods:
            directory = self.model_dir(method)
            directory.parent.mkdir(parents=True, exist_ok=True)
            self.stage("fit", method.name, self.model_key(method), directory, partial(self._fit, method, directory),
                       [self.state.datasets["train"]])
        return FitRecord({m.name: s for m in self.scenario.methods if (s := self.training_record(m)["summary"])})

    def _fit(self, method: Method, directory: Path) -> None:
        """Fit ``method`` on the training run and save it into ``directory`` (atomically)."""
        extractor = self.registry.create(method.plugin, self.params_for(method))
        extractor.progress = self.progress
        extractor.fit(self.open("train"))
        tmp = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
        try:
            extractor.save(tmp)
            if directory.exists():
                shutil.rmtree(directory)
            os.replace(tmp, directory)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self.extractors[method.name] = extractor
        record = {"history": extractor.training_history(), "summary": extractor.training_summary()}
        write_text_atomic(self.training_file(method), json.dumps(record))

    def training_file(self, method: Method) -> Path:
        """Where the fit stage records how training went, beside the model in the cache (the
        report reads its copy, `outdir.training_path`)."""
        return outdir.training_file(self.model_dir(method))

    def training_record(self, method: Method) -> dict[str, Any]:
        """``{"history": per-epoch curves, "summary": how training ended}`` saved by the fit stage."""
        path = self.training_file(method)
        return json.loads(path.read_text()) if path.exists() else {"history": {}, "summary": {}}

    def extractor(self, method: Method) -> FeatureExtractor:
        if method.name not in self.extractors:
            self.extractors[method.name] = self.registry.get(method.plugin).load(self.model_dir(method))
            self.extractors[method.name].progress = self.progress
        return self.extractors[method.name]

    def features_key(self, method: Method, label: str) -> str:
        """The transform's key: the model's and the run's, and the run's drop-out when it has one."""
        missing = self.open(label).missing
        dropout = [{sensor: np.flatnonzero(mask).tolist() for sensor, mask in missing.items()}] if missing else []
        return content_hash("transform", STAGE_VERSION["transform"], self.model_key(method),
                            self.output_digest(self.model_dir(method)), self.state.datasets[label], self.dataset_digest(label),
                            *dropout)

    def features_path(self, method: Method, label: str) -> Path:
        return outdir.features_file(self.cache, method.name, label, self.features_key(method, label))

    def transform(self) -> TransformRecord:
        labels = [label for label in self.runs() if label != "train"]
        for method in self.scenario.methods:
            for label in labels:
                path = self.features_path(method, label)
                self.stage("transform", f"{method.name} {label}", self.features_key(method, label), path,
                           partial(self._transform, method, label, path), [self.model_key(method), self.state.datasets[label]])
        return TransformRecord({m.name: {label: feature_facts(load_features(self.features_path(m, label))) for label in labels}
                                for m in self.scenario.methods})

    def _transform(self, method: Method, label: str, path: Path) -> None:
        """The features of run ``label`` by the fitted ``method``, checked, saved to ``path``."""
        run = self.open(label)
        features = self.extractor(method).transform(run)
        save_features(path, check_features(features, len(run), f"transform {method.name} {label}"))

    # ------------------------------------------------------------------ evaluate
    def directions(self) -> list[tuple[str, str, str]]:
        d = self.scenario.scoring.direction
        pairs = [("query-to-reference", "query", "reference"), ("reference-to-query", "reference", "query")]
        return [p for p in pairs if d in (p[0], "both")]

    def evaluate(self) -> EvaluateRecord:
        settings = self.scenario.scoring
        rows, files = [], []
        for e in self.scenario.evaluations:
            for method in self.scenario.methods:
                for direction, q, r in self.directions():
                    qpath = self.features_path(method, f"{e.name}/{q}")
                    rpath = self.features_path(method, f"{e.name}/{r}")
                    key = content_hash(
                        "evaluate", STAGE_VERSION["evaluate"], self.model_key(method), qpath.name, rpath.name,
                        [self.output_digest(p) for p in (qpath, rpath)],
                        [self.dataset_digest(f"{e.name}/{side}") for side in (q, r)],
                        settings.model_dump(exclude={"complementarity"}),  # pairs methods, scores none
                    )
                    folder = outdir.evaluation_dir(self.out, e.name, method.name, direction)
                    work = partial(self._evaluate, method, f"{e.name}/{q}", f"{e.name}/{r}", folder)
                    self.stage("evaluate", f"{e.name} {method.name} {direction}", key, folder, work,
                               [qpath.stem, rpath.stem])
                    summary = json.loads((folder / outdir.SUMMARY).read_text())
                    rows.append({"environment": e.name, "method": method.name, "direction": direction, **summary,
                                 **self.dropout_row(e)})
                    files += [folder / outdir.SUMMARY, folder / outdir.PR_CURVE]
        fused_rows, fused_files = evaluate_fusions(self)
        rows, files = rows + fused_rows, files + fused_files
        self.add_f1_at_training_threshold(rows)
        self.warn_few_revisits(rows)
        return EvaluateRecord(rows, files, self.complementarity())

    def complementarity(self) -> list[dict[str, Any]]:
        """Per evaluation, direction and (vision, touch) pair of `complementarity_pairs`:
        what the touch method gets right of the vision method's wrong best matches
        (`vitaplace.engine.evaluation.complementarity`), from the two evaluations' decisions."""
        pairs = complementarity_pairs(self.scenario, self.registry)
        records = []
        for e in self.scenario.evaluations:
            for direction, _, _ in self.directions():
                for vision, touch in pairs:
                    decisions = [load_decisions(outdir.evaluation_dir(self.out, e.name, m, direction) / outdir.DECISIONS)
                                 for m in (vision, touch)]
                    records.append({"environment": e.name, "direction": direction, "vision": vision, "touch": touch,
                                    **complementarity(*decisions)})
        return records

    def dropout_row(self, e: EvaluationPair) -> dict[str, Any]:
        """``query_dropout`` of a results row: the shares of the query samples that lacked each
        sensor (as drawn: whole samples); nothing for an evaluation without drop-out."""
        if e.query_dropout is None:
            return {}
        missing = self.open(f"{e.name}/query").missing
        return {"query_dropout": {sensor: float(mask.mean()) if len(mask) else 0.0 for sensor, mask in missing.items()}}

    def warn_few_revisits(self, rows: list[dict[str, Any]]) -> None:
        """Warn (log, manifest.json, report.md; on the run whose samples are the queries) about
        every evaluation direction in which fewer than `MIN_REVISITS` queries have a true
        match: with none, its max F1 of 0 says nothing about a method."""
        for row in rows:
            n, queries = row["n_revisit"], row["n_queries"]
            if n >= MIN_REVISITS:
                continue
            side = "query" if row["direction"] == "query-to-reference" else "reference"
            what = ("none of its {q} queries has" if n == 0 else "only {n} of its {q} queries have").format(n=n, q=queries)
            warn_once(self.open(f"{row['environment']}/{side}"), f"revisits {row['direction']}",
                      f"evaluation {row['environment']} {row['direction']}: {what} a true match within tau = "
                      f"{row['tau']:g} m (n_revisit < {MIN_REVISITS}): its max F1 and recall rest on too few samples "
                      "to compare methods by")

    def _evaluate(self, method: Method, query: str, reference: str, folder: Path) -> None:
        """Score ``method``'s distances from the ``query`` run's samples to the ``reference``
        run's into ``folder`` (summary, curves, matrices)."""
        folder.mkdir(parents=True, exist_ok=True)
        q, r = self.open(query), self.open(reference)
        distances = self.extractor(method).distance(load_features(self.features_path(method, query)),
                                                    load_features(self.features_path(method, reference)))
        tme = check_distance(distances, (len(q), len(r)), f"evaluate {query.split('/')[0]} {method.name}")
        write_text_atomic(folder / outdir.SUMMARY, json.dumps(self.score(folder, tme, query, reference), indent=2))

    def score(self, folder: Path, tme: np.ndarray, query: str, reference: str) -> dict[str, Any]:
        """The distances ``tme`` from run ``query``'s samples to run ``reference``'s scored with
        the scenario's settings into ``folder`` (`evaluate_pair`); returns the summary."""
        settings = self.scenario.scoring
        q, r = self.open(query), self.open(reference)
        return evaluate_pair(
            folder, tme, q.poses, r.poses, settings.tau, query_touch=q.touch_mask(), reference_touch=r.touch_mask(),
            delta=settings.delta, heading_tolerance_deg=settings.heading_tolerance_deg, ks=tuple(settings.recall_k),
            sequence=self.sequence_for(query, len(q)),
        )

    def sequence_for(self, query: str, n_queries: int) -> dict[str, Any] | None:
        """The scenario's sequence matching settings (None for single samples), checked against
        the length of the query run ``query`` (a recorded run's is known only here)."""
        sequence = self.scenario.scoring.sequence
        if sequence.length == 1:
            return None
        if sequence.length > n_queries:
            raise ScenarioError(f"scoring.sequence.length: {sequence.length} is longer than run {query} "
                            f"({n_queries} samples); expected at most that")
        return sequence.model_dump()

    def add_f1_at_training_threshold(self, rows: list[dict[str, Any]]) -> None:
        """``f1_at_e1_threshold`` in every row: F1 at the threshold that maximised the same
        method's F1 (same direction) on the training world's evaluation
        (`training_world_evaluation`), applied unchanged, and that threshold, ``e1_threshold``
        (None when it is -inf: accept nothing); both None when there is no such evaluation."""
        source, _ = training_world_evaluation(self.scenario)
        for row in rows:
            row["f1_at_e1_threshold"] = row["e1_threshold"] = None
            if source is None:
                continue
            curve = load_curve(outdir.evaluation_dir(self.out, source, row["method"], row["direction"]) / outdir.PR_CURVE)
            with np.load(outdir.evaluation_dir(self.out, row["environment"], row["method"], row["direction"]) / outdir.MATRICES) as m:
                row["f1_at_e1_threshold"] = ev.f1_at_threshold_of(curve, m["tme"], m["gtm"], row["tau"])
            row["e1_threshold"] = curve.delta_at_max_f1 if np.isfinite(curve.delta_at_max_f1) else None

    # ------------------------------------------------------------------ report
    def write_report_inputs(self) -> None:
        """Into the output folder: each evaluation's query and reference poses and, when
        simulated, its environment's top view; each method's training curves, when it has them."""
        for e in self.scenario.evaluations:
            save_features(outdir.poses_path(self.out, e.name),
                          {side: self.open(f"{e.name}/{side}").poses for side in ("query", "reference")})
            if e.environment is not None:
                write_text_atomic(outdir.arena_path(self.out, e.name),
                                  json.dumps(load_environment(e.environment).top_view()))
        for method in self.scenario.methods:
            history = self.training_record(method)["history"]
            if history:
                write_text_atomic(outdir.training_path(self.out, method.name), json.dumps(history))

    def method_settings(self) -> dict[str, dict[str, Any]]:
        """Per method, as the manifest records it: its plugin, the parameters handed to it
        (`params_for`: the scenario's, with the derived seed) and the plugin's defaults for the
        others."""
        out = {}
        for method in self.scenario.methods:
            given = self.params_for(method)
            full = self.registry.get(method.plugin).validate_params(given).model_dump(mode="json")
            out[method.name] = {"plugin": method.plugin, "params": {k: full[k] for k in full if k in given},
                                "defaults": {k: v for k, v in full.items() if k not in given}}
        return out

    def run_record(self, until: str, simulated: SimulateRecord) -> RunRecord:
        """The record of this run up to ``until``, its later stages' records still to come."""
        return RunRecord(out=self.out, scenario=self.scenario.name, seed=self.scenario.seed, until=until,
                         methods=self.method_settings(), training_world=training_world_evaluation(self.scenario)[1],
                         plugins=plugin_distributions(self.registry), simulate=simulated)

    def close_record(self, record: RunRecord, seconds: float) -> RunRecord:
        """``record`` with every stage item's record, the runs' warnings so far and the time."""
        record.stages = list(self.state.records)
        record.warnings = {label: dict(run.warnings) for label, run in self.opened.items() if run.warnings}
        record.seconds = round(seconds, 3)
        return record
