"""The scenario pipeline: simulate -> fit -> transform -> evaluate -> report, cached per stage.

Every stage's output lives under ``OUT/cache`` named by a hash of everything it depends on
(config, upstream keys, format versions, the code digest of the plugin that runs it) and of
the digests of the upstream outputs it reads, as DVC does: a re-run skips finished stages,
an interrupted run resumes with the first missing output, and ``force`` redoes named stages
and, when their output changed, every stage downstream that reads it (an identical output
leaves the downstream keys, and so their cached work, as they were). A run ends by writing
its completion record (`vitaplace.engine.completion`).
"""

from __future__ import annotations

import ctypes
import json
import logging
import multiprocessing
import os
import shutil
import signal
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vitaplace.engine.errors import UserError
from vitaplace.engine.provenance import provenance
from vitaplace.engine import checksum, completion
from vitaplace.engine import evaluate as ev
from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.cpus import limit_blas_threads, usable_cpus
from vitaplace.engine.dataset import SCHEMA_VERSION, Run, open_run, write_run
from vitaplace.engine.features import FeatureExtractor, Features, load_features, save_features, warn_once
from vitaplace.engine.plausibility import LONG_SECONDS, duration, estimated_seconds
from vitaplace.engine.plugins import Registry, announce_run_finished, discover, plugin_distributions
from vitaplace.engine.scenario import (
    EvaluationRuns, Method, Scenario, ScenarioError, TrainingRun, content_hash, training_world_evaluation,
)
from vitaplace.engine.sim import SIMULATOR_VERSION
from vitaplace.engine.sim.environment import load_environment

STAGES = ("simulate", "fit", "transform", "evaluate", "report")
#: Bump when a stage's output format or algorithm changes, to invalidate old caches.
STAGE_VERSION = {"simulate": SCHEMA_VERSION, "fit": 1, "transform": 2, "evaluate": 4, "report": 5}

log = logging.getLogger("vitaplace")


class StageError(UserError, RuntimeError):
    """A stage produced unusable output (e.g. non-finite features); names the stage and item."""


def check_finite(features: Features, what: str) -> Features:
    """Raise StageError if any feature array holds NaN or infinite values."""
    for key, values in features.items():
        values = np.asarray(values)
        if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
            rows = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1)).all(axis=1))
            raise StageError(
                f"{what}: feature '{key}' has NaN or infinite values in {len(rows)} samples (first: {rows[0]}); "
                "check the method's parameters (e.g. lower learning rates) and the dataset"
            )
    return features


def process_identity(pid: int) -> str:
    """``pid`` with its start time where the OS says it (Linux ``/proc``), so a reused pid
    does not pass for the process that had it before."""
    try:
        start = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        start = "?"
    return f"{pid}:{start}"


def worker_pool(workers: int, blas_threads: int | None = None) -> ProcessPoolExecutor:
    """A pool of spawned worker processes that end with the process that made it
    (`die_with_parent`), each limited to ``blas_threads`` BLAS threads when given."""
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                               initargs=(process_identity(os.getpid()), blas_threads))


def _start_worker(parent: str, blas_threads: int | None) -> None:
    """Worker-process initializer: `die_with_parent`, then the BLAS thread limit."""
    die_with_parent(parent)
    if blas_threads is not None:
        limit_blas_threads(blas_threads)


@contextmanager
def interrupts_to_this_process() -> Iterator[None]:
    """Processes started inside ignore Ctrl-C from their first instant (an ignored SIGINT
    survives exec, and Python keeps it ignored), so a Ctrl-C stops this process alone, with
    one line, instead of a traceback from every worker still importing; `stop_pool` then
    ends them. A Ctrl-C during the few milliseconds it takes to start them is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """End ``pool`` now, killing its workers mid-task (after Ctrl-C: nothing they do is kept)."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):  # the executor's own record
        process.kill()
    pool.shutdown(cancel_futures=True)  # quick once they are dead; frees the pool's queues and semaphores


def die_with_parent(parent: str) -> None:
    """Worker-process initializer: end this worker when the process that started it dies
    (even by kill -9), so no simulation keeps running orphaned. ``parent`` is that process's
    `process_identity`: a worker whose parent died while it was starting (its parent is now
    another process) exits at once. Linux: then the kernel's parent-death signal; elsewhere a
    daemon thread that notices the parent is gone."""
    parent_pid = os.getppid()
    if process_identity(parent_pid) != parent:
        os._exit(1)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signal.SIGTERM) == 0 and os.getppid() == parent_pid:  # PR_SET_PDEATHSIG
            return
    except (OSError, AttributeError):
        pass

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def check_features(features: Any, samples: int, what: str) -> Features:
    """An extractor's ``transform`` output must be a mapping of arrays with one row per sample."""
    if not isinstance(features, dict) or not features:
        raise StageError(f"{what}: transform returned {type(features).__name__}, expected a non-empty mapping of arrays")
    for key, values in features.items():
        shape = np.shape(values)
        if not shape or shape[0] != samples:
            raise StageError(f"{what}: feature '{key}' has shape {shape}, expected {samples} rows (one per sample)")
    return check_finite(features, what)


def check_distance(tme: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    """An extractor's ``distance`` output must be a finite (n_query, n_reference) matrix."""
    tme = np.asarray(tme)
    if tme.shape != shape:
        raise StageError(f"{what}: distance returned shape {tme.shape}, expected {shape} (queries x references)")
    check_finite({"distance": tme}, what)
    return tme


@dataclass
class StageRecord:
    """One stage of one item: what keyed it (the keys of its inputs), where its output is,
    and whether it ran or came from the cache."""

    stage: str
    item: str
    key: str
    status: str  # "ran" or "cached"
    seconds: float
    inputs: list[str] = field(default_factory=list)  # keys of the upstream outputs it was made from
    output: str = ""  # its output, relative to the output directory when inside it


@dataclass
class RunnerState:
    records: list[StageRecord] = field(default_factory=list)
    datasets: dict[str, str] = field(default_factory=dict)  # run label -> dataset key
    #: output path -> SHA-256 of its content, for each output done in this run (`checksum`)
    digests: dict[str, str] = field(default_factory=dict)


def record_run(
    environment: str, run: dict[str, Any], robot: dict[str, Any], seed: int, label: str, key: str, path: Path,
    progress: bool,
) -> tuple[int, float]:
    """Simulate one run and write its dataset (a top-level function: runs in worker processes);
    returns its number of samples and the seconds it took."""
    from vitaplace.engine.sim.robot import RobotSpec
    from vitaplace.engine.sim.simulate import RunSpec, simulate_run

    start = time.perf_counter()
    recorded = simulate_run(
        load_environment(environment), RunSpec(**run), seed=seed, robot=RobotSpec(**robot), progress=progress, name=label
    )
    recorded.attrs["scenario_hash"] = key
    write_run(path, recorded)
    return len(recorded), time.perf_counter() - start


def log_recorded(label: str, samples: int, seconds: float, where: str = "") -> None:
    """The line a finished simulation logs: run, samples, seconds (and where it ran)."""
    log.info("%-9s %-28s recorded %d samples in %.1f s%s", "simulate", label, samples, seconds, where)


def _log_finished(label: str, future: Any) -> None:
    """Done-callback of a simulation in a worker process: log it as soon as it finishes."""
    if not future.cancelled() and future.exception() is None:
        log_recorded(label, *future.result(), " (worker process)")


def _record_and_log(*args: Any) -> tuple[int, float]:
    """`record_run` in this process, then its log line."""
    result = record_run(*args)
    log_recorded(args[4], *result)
    return result


def _await(future: Future, label: str, estimate: float) -> tuple[int, float]:
    """The result of a simulation in a worker process; for a long one (`LONG_SECONDS`), a log
    line each tenth of its estimated time while it runs."""
    if estimate <= LONG_SECONDS:
        return future.result()
    started = time.perf_counter()
    while True:
        try:
            return future.result(timeout=estimate / 10)
        except FutureTimeout:
            log.info("%-9s %-28s running for %s of an estimated %s", "simulate", label,
                     duration(time.perf_counter() - started), duration(estimate))


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
        self.cache = Path(cache) if cache is not None else self.out / "cache"
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
    def _done(self, stage: str, item: str, output: Path, key: str) -> bool:
        """The one "done" rule of every stage: ``output`` is there and sealed for ``key`` with
        a matching digest (`checksum`); anything else but "not made yet" is logged."""
        problem = checksum.check(output, key)
        if problem is None:
            return True
        if problem not in ("absent", "made for other settings"):
            log.warning("%-9s %-28s cached output %s is %s: recomputing", stage, item, output.name, problem)
        return False

    def _stage(
        self, stage: str, item: str, key: str, output: Path, work, inputs: Iterable[str] = (), done: bool | None = None
    ) -> Any:
        """Run ``work()`` unless ``output`` is done for ``key`` (`_done`, or ``done`` when the
        caller has checked already) and the stage is not forced; seal what it wrote."""
        start = time.perf_counter()
        if done is None:
            done = self._done(stage, item, output, key)
        if done and stage not in self.force:
            status = "cached"
            log.info("%-9s %-28s cached (%s)", stage, item, key)
            result = None
        else:
            status = "ran"
            log.info("%-9s %-28s running (%s)", stage, item, key)
            result = work()
            checksum.seal(output, key)
        self.state.digests[str(output)] = checksum.sealed_digest(output)
        seconds = time.perf_counter() - start
        where = output.relative_to(self.out) if output.is_relative_to(self.out) else output
        log.debug("%-9s %-28s %s in %.2f s: %s", stage, item, status, seconds, where)
        self.state.records.append(StageRecord(stage, item, key, status, round(seconds, 3), list(inputs), str(where)))
        return result

    # ------------------------------------------------------------------ simulate
    def runs(self) -> dict[str, tuple[TrainingRun | EvaluationRuns, int]]:
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
        return self.cache / "datasets" / f"{label.replace('/', '-')}-{self.state.datasets[label]}.h5"

    def use_recorded(self, label: str) -> None:
        """A recorded run instead of a simulation: open and check it (format, shapes, finite
        values); its key is the file's SHA-256, so a changed file re-runs what depends on it."""
        start = time.perf_counter()
        path = self.recorded[label]
        run = open_run(path)
        run.validate()
        run.name = label  # warnings and errors name the run as the scenario does
        self.opened[label] = run
        digest = checksum.digest(path)
        key = content_hash("recorded", STAGE_VERSION["simulate"], digest)
        self.state.datasets[label] = key
        self.state.digests[str(path)] = digest
        log.info("%-9s %-28s recorded run %s (%s)", "simulate", label, path, key)
        seconds = round(time.perf_counter() - start, 3)
        self.state.records.append(StageRecord("simulate", label, key, "recorded", seconds, [], str(path)))

    def simulate(self) -> None:
        """Record every run not cached yet; several runs are recorded by parallel processes."""
        jobs, estimates = {}, {}
        for label, (entry, seed) in self.runs().items():
            if label in self.recorded:
                self.use_recorded(label)
                continue
            assert entry.environment is not None and entry.run is not None  # validated: simulated
            environment = load_environment(entry.environment)
            run = entry.run_for(label.rsplit("/", 1)[1]) if isinstance(entry, EvaluationRuns) else entry.run
            spec = [environment.model_dump(mode="json"), run.model_dump(mode="json")]
            key = content_hash("simulate", STAGE_VERSION["simulate"], SIMULATOR_VERSION, spec,
                               self.scenario.robot.model_dump(mode="json"), seed)
            self.state.datasets[label] = key
            estimates[label] = estimated_seconds(run, self.scenario.robot)
            args = (str(entry.environment), run.model_dump(), self.scenario.robot.model_dump(), seed, label, key)
            jobs[label] = (args, self.dataset_path(label))
        pending = [
            label for label, (job_args, path) in jobs.items()
            if "simulate" in self.force or not self._done("simulate", label, path, job_args[-1])
        ]
        for label in pending:
            if estimates[label] > LONG_SECONDS:
                log.warning("%-9s %-28s a long simulation: about %s on one core (estimate)", "simulate", label,
                            duration(estimates[label]))
        workers = min(self.workers, len(pending))
        pool = worker_pool(workers) if workers > 1 else None
        try:
            with interrupts_to_this_process():
                futures = {label: pool.submit(record_run, *jobs[label][0], jobs[label][1], False)
                           for label in pending} if pool else {}
            for label, future in futures.items():
                future.add_done_callback(partial(_log_finished, label))
            if futures:
                log.info("%-9s %d runs on %d worker processes (no progress bars there; a line as each finishes)",
                         "simulate", len(futures), workers)
            for label, (args, path) in jobs.items():
                work = (partial(_await, futures[label], label, estimates[label]) if label in futures
                        else partial(_record_and_log, *args, path, self.progress))
                self._stage("simulate", label, args[-1], path, work, done=label not in pending)
        except KeyboardInterrupt:
            if pool is not None:
                stop_pool(pool)
            raise
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
        self.warn_collisions()

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

    def open(self, label: str) -> Run:
        """The recorded run ``label``, opened once per pipeline (its fields load lazily, once)."""
        if label not in self.opened:
            self.opened[label] = open_run(self.dataset_path(label))
        return self.opened[label]

    # ------------------------------------------------------------------ fit / transform
    def method_params(self, method: Method) -> dict[str, Any]:
        """The method's parameters, with ``seed`` derived from the scenario seed when the
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
            self.registry.code_digest(method.plugin), self.method_params(method), self.state.datasets["train"],
            self.dataset_digest("train"),
        )

    def model_dir(self, method: Method) -> Path:
        return self.cache / "models" / f"{method.name}-{self.model_key(method)}"

    def fit(self) -> None:
        for method in self.scenario.methods:
            key = self.model_key(method)
            directory = self.model_dir(method)

            def work(method=method, directory=directory) -> None:
                extractor = self.registry.create(method.plugin, self.method_params(method))
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
                write_text_atomic(self.training_path(method), json.dumps(record))

            directory.parent.mkdir(parents=True, exist_ok=True)
            self._stage("fit", method.name, key, directory, work, [self.state.datasets["train"]])

    def training_path(self, method: Method) -> Path:
        """Where the fit stage records how training went (read by the report and the manifest)."""
        return self.model_dir(method).with_name(self.model_dir(method).name + ".training.json")

    def training_record(self, method: Method) -> dict[str, Any]:
        """``{"history": per-epoch curves, "summary": how training ended}`` saved by the fit stage."""
        path = self.training_path(method)
        return json.loads(path.read_text()) if path.exists() else {"history": {}, "summary": {}}

    def extractor(self, method: Method) -> FeatureExtractor:
        if method.name not in self.extractors:
            self.extractors[method.name] = self.registry.get(method.plugin).load(self.model_dir(method))
            self.extractors[method.name].progress = self.progress
        return self.extractors[method.name]

    def features_path(self, method: Method, label: str) -> Path:
        key = content_hash("transform", STAGE_VERSION["transform"], self.model_key(method),
                           self.output_digest(self.model_dir(method)), self.state.datasets[label], self.dataset_digest(label))
        return self.cache / "features" / f"{method.name}-{label.replace('/', '-')}-{key}.npz"

    def transform(self) -> None:
        labels = [label for label in self.runs() if label != "train"]
        for method in self.scenario.methods:
            for label in labels:
                path = self.features_path(method, label)

                def work(method=method, label=label, path=path) -> None:
                    run = self.open(label)
                    features = self.extractor(method).transform(run)
                    save_features(path, check_features(features, len(run), f"transform {method.name} {label}"))

                self._stage("transform", f"{method.name} {label}", path.stem.rsplit("-", 1)[1], path, work,
                            [self.model_key(method), self.state.datasets[label]])

    # ------------------------------------------------------------------ evaluate
    def directions(self) -> list[tuple[str, str, str]]:
        d = self.scenario.evaluation.direction
        pairs = [("query-to-reference", "query", "reference"), ("reference-to-query", "reference", "query")]
        return [p for p in pairs if d in (p[0], "both")]

    def evaluation_dir(self, env: str, method: str, direction: str) -> Path:
        return self.out / "evaluations" / env / method / direction

    def evaluate(self) -> list[dict[str, Any]]:
        settings = self.scenario.evaluation
        rows = []
        for e in self.scenario.evaluations:
            for method in self.scenario.methods:
                for direction, q, r in self.directions():
                    qpath = self.features_path(method, f"{e.name}/{q}")
                    rpath = self.features_path(method, f"{e.name}/{r}")
                    key = content_hash(
                        "evaluate", STAGE_VERSION["evaluate"], self.model_key(method), qpath.name, rpath.name,
                        [self.output_digest(p) for p in (qpath, rpath)],
                        [self.dataset_digest(f"{e.name}/{side}") for side in (q, r)], settings.model_dump(),
                    )
                    folder = self.evaluation_dir(e.name, method.name, direction)
                    summary_path = folder / "summary.json"

                    def work(method=method, qpath=qpath, rpath=rpath, folder=folder, e=e, q=q, r=r) -> None:
                        folder.mkdir(parents=True, exist_ok=True)
                        shape = (len(self.open(f"{e.name}/{q}")), len(self.open(f"{e.name}/{r}")))
                        tme = check_distance(self.extractor(method).distance(load_features(qpath), load_features(rpath)),
                                             shape, f"evaluate {e.name} {method.name}")
                        summary = ev.evaluate_pair(
                            folder, tme, self.open(f"{e.name}/{q}").poses, self.open(f"{e.name}/{r}").poses,
                            settings.tau, query_touch=self.open(f"{e.name}/{q}").touch_mask(),
                            reference_touch=self.open(f"{e.name}/{r}").touch_mask(),
                            delta=settings.delta, heading_tolerance_deg=settings.heading_tolerance_deg,
                            ks=tuple(settings.recall_k),
                        )
                        write_text_atomic(folder / "summary.json", json.dumps(summary, indent=2))

                    item = f"{e.name} {method.name} {direction}"
                    self._stage("evaluate", item, key, folder, work, [qpath.stem, rpath.stem])
                    summary = json.loads(summary_path.read_text())
                    rows.append({"environment": e.name, "method": method.name, "direction": direction, **summary})
        self.add_f1_at_training_threshold(rows)
        return rows

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
            curve = ev.load_curve(self.evaluation_dir(source, row["method"], row["direction"]) / "pr_curve.npz")
            with np.load(self.evaluation_dir(row["environment"], row["method"], row["direction"]) / "matrices.npz") as m:
                row["f1_at_e1_threshold"] = ev.f1_at_threshold_of(curve, m["tme"], m["gtm"], row["tau"])
            row["e1_threshold"] = curve.delta_at_max_f1 if np.isfinite(curve.delta_at_max_f1) else None

    # ------------------------------------------------------------------ everything
    def run(self, until: str = "report") -> list[dict[str, Any]]:
        """Run the stages up to and including ``until``; return the result rows (if evaluated)."""
        self.out.mkdir(parents=True, exist_ok=True)
        completion.clear(self.out)  # first: until the new record, the folder holds no finished run
        write_text_atomic(self.out / completion.SCENARIO, yaml.safe_dump(self.resolved, sort_keys=False))
        started = time.perf_counter()
        rows: list[dict[str, Any]] = []
        stop = STAGES.index(until)
        self.simulate()
        if stop >= STAGES.index("fit"):
            self.fit()
        if stop >= STAGES.index("transform"):
            self.transform()
        if stop >= STAGES.index("evaluate"):
            rows = self.evaluate()
            write_results(self.out, rows)
        if stop >= STAGES.index("report"):
            from vitaplace.engine.report import write_report

            params = [self.method_params(m) for m in self.scenario.methods]
            key = content_hash("report", STAGE_VERSION["report"], rows, params,
                               [self.model_key(m) for m in self.scenario.methods])
            self._stage("report", "report", key, self.out / "report.md", lambda: write_report(self, rows))
        self.write_manifest(time.perf_counter() - started)
        announce_run_finished(self.registry, self.out, self.scenario, rows, until)
        completion.write(self.out, self.finished_files(until))
        return rows

    def finished_files(self, until: str) -> list[Path]:
        """What this run wrote for readers outside the pipeline (the completion record covers
        them): the manifest, results and report, each evaluation's summary and PR curve."""
        names = ["manifest.json"]
        if STAGES.index(until) >= STAGES.index("evaluate"):
            names += ["results.json", "results.csv"]
            names += [str(self.evaluation_dir(e.name, m.name, d).relative_to(self.out) / f)
                      for e in self.scenario.evaluations for m in self.scenario.methods for d, *_ in self.directions()
                      for f in ("summary.json", "pr_curve.npz")]
        if until == "report":
            names.append("report.md")
        return [self.out / name for name in names]

    def write_manifest(self, seconds: float) -> None:
        manifest = {
            "scenario": self.scenario.name,
            **provenance(),
            "plugins": plugin_distributions(self.registry),
            "seed": self.scenario.seed,
            "run_seeds": {label: seed for label, (_, seed) in self.runs().items() if label not in self.recorded},
            "datasets": self.state.datasets,
            "recorded": {label: str(path) for label, path in self.recorded.items()},
            "warnings": {label: dict(run.warnings) for label, run in self.opened.items() if run.warnings},
            "stages": [record.__dict__ for record in self.state.records],
            "training": {m.name: s for m in self.scenario.methods if (s := self.training_record(m)["summary"])},
            "seconds": round(seconds, 3),
        }
        write_text_atomic(self.out / "manifest.json", json.dumps(manifest, indent=2))


RESULT_COLUMNS = (
    "environment", "method", "direction", "max_f1", "precision_at_max_f1", "recall_at_max_f1",
    "delta_at_max_f1", "auc", "recall_at_100_precision", "f1_at_e1_threshold", "e1_threshold", "delta", "precision",
    "recall", "f1", "n_queries", "n_references", "n_revisit",
)


def csv_row(row: dict[str, Any]) -> dict[str, Any]:
    """A results row for results.csv: without a fixed ``evaluation.delta``, delta, precision,
    recall and F1 are those at the max-F1 threshold (instead of empty)."""
    if row.get("f1") is not None:
        return row
    return {**row, "delta": row["delta_at_max_f1"], "precision": row["precision_at_max_f1"],
            "recall": row["recall_at_max_f1"], "f1": row["max_f1"]}


def write_results(out: Path, rows: list[dict[str, Any]]) -> None:
    """results.json (everything) and results.csv (one row per environment x method x direction;
    `csv_row`: delta, precision, recall, F1 at the fixed delta, else at the max-F1 one)."""
    import csv
    import io

    write_text_atomic(out / "results.json", json.dumps(rows, indent=2))
    ks = sorted({k for row in rows for k in row.get("recall_at_k", {})}, key=int)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow([*RESULT_COLUMNS, *(f"recall@{k}" for k in ks)])
    for row in rows:
        filled = csv_row(row)
        writer.writerow([filled.get(c, "") for c in RESULT_COLUMNS] + [row["recall_at_k"].get(k, "") for k in ks])
    write_text_atomic(out / "results.csv", buffer.getvalue())

