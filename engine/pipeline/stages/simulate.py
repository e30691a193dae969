"""The simulate stage: every run of the scenario recorded (several by parallel processes) or
taken from the run file the scenario gives, then checked for runs a stuck or colliding
robot made."""

from __future__ import annotations

import logging
import time
from functools import partial
from pathlib import Path

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.config.scenario import EvaluationPair, Scenario
from vitaplace.engine.data.dataset import run_facts
from vitaplace.engine.evaluation.difficulty import STAY_RADIUS, longest_stay
from vitaplace.engine.extension.features import warn_once
from vitaplace.engine.outputs import checksum, outdir
from vitaplace.engine.pipeline.keys import recorded_key, simulate_key
from vitaplace.engine.pipeline.records import RunFile, SimulateRecord, StageRecord
from vitaplace.engine.pipeline.simulation import SimulationJob, simulate_here, simulations_in_workers
from vitaplace.engine.pipeline.store import Store
from vitaplace.engine.sim.plausibility import LONG_SECONDS, duration, estimated_seconds

#: a run that stays in one place this long (share of its samples, and samples) is warned about:
#: a quarter of any run, and 10 samples (5 s) at least, so that a short run's stay is found too
STUCK_SHARE, STUCK_SAMPLES = 0.25, 10

log = logging.getLogger("vitaplace")


def is_stuck(stay: int, samples: int) -> bool:
    """Whether a longest stay of ``stay`` samples in a run of ``samples`` is a stuck drive:
    at least `STUCK_SHARE` of the run and `STUCK_SAMPLES`."""
    return stay >= max(STUCK_SAMPLES, STUCK_SHARE * samples)


def simulate(store: Store, scenario: Scenario) -> SimulateRecord:
    """Record every run not cached yet; several runs are recorded by parallel processes."""
    recorded = plan.recorded_files(scenario)
    made: dict[str, tuple[Path, str, str, int | None]] = {}  # label -> path, key, digest, seed
    jobs = []
    for label, (entry, seed) in plan.runs(scenario).items():
        if label in recorded:
            made[label] = use_recorded(store, label, recorded[label])
            continue
        run = entry.run_for(label.rsplit("/", 1)[1]) if isinstance(entry, EvaluationPair) else entry.run
        assert entry.environment is not None and run is not None  # validated: simulated
        key = simulate_key(scenario, entry, label, seed)
        jobs.append(SimulationJob(label, str(entry.environment), run.model_dump(), scenario.robot.model_dump(), seed,
                                  key, outdir.dataset_file(store.cache, label, key),
                                  estimated_seconds(run, scenario.robot)))
    pending = [job for job in jobs
               if "simulate" in store.force or not store.done("simulate", job.label, job.path, job.key)]
    for job in pending:
        if job.estimate > LONG_SECONDS:
            log.warning("%-9s %-28s a long simulation: about %s on one core (estimate)", "simulate", job.label,
                        duration(job.estimate))
    with simulations_in_workers(pending, store.workers) as in_workers:
        for job in jobs:
            work = in_workers.get(job.label) or partial(simulate_here, job, store.progress)
            done = store.stage("simulate", job.label, job.key, job.path, work, done=job not in pending)
            if done.result is not None:  # the simulation's own time, not the wait for its worker
                store.records[-1].seconds = round(done.result[1], 3)
            made[job.label] = (job.path, job.key, done.digest, job.seed)
    runs = {label: run_file(store, scenario, label, *made[label], recorded=label in recorded)
            for label in plan.runs(scenario)}
    warn_collisions(store, runs)
    warn_stays(store, runs)
    warn_trained_on_a_reference(store, runs)
    return SimulateRecord(runs)


def use_recorded(store: Store, label: str, path: Path) -> tuple[Path, str, str, None]:
    """A recorded run instead of a simulation: open and check it (format, shapes, finite
    values); its key is the file's SHA-256, so a changed file re-runs what depends on it."""
    start = time.perf_counter()
    store.open(label, path).validate()
    digest = checksum.digest(path)
    key = recorded_key(digest)
    log.info("%-9s %-28s recorded run %s (%s)", "simulate", label, path, key)
    store.record(StageRecord("simulate", label, key, "recorded", round(time.perf_counter() - start, 3), [], str(path)))
    return path, key, digest, None


def run_file(store: Store, scenario: Scenario, label: str, path: Path, key: str, digest: str, seed: int | None,
             recorded: bool) -> RunFile:
    """The record of run ``label``: its file, key and digest, its facts and its drop-out (`plan.dropout_of`)."""
    run = store.open(label, path)
    missing, dropout_seed = plan.dropout_of(scenario, label, len(run))
    return RunFile(label, path, key, digest, recorded, seed, run_facts(run), missing, dropout_seed)


def warn_collisions(store: Store, runs: dict[str, RunFile]) -> None:
    """Warn (log, manifest.json, report.md) about every run in which the robot's body or
    head touched the world (``body_collision_instants`` > 0 in its attributes)."""
    for label, record in runs.items():
        run = store.run(record)
        instants = int(run.attrs.get("body_collision_instants", 0))
        if instants > 0:
            warn_once(run, "body_collision_instants",
                      f"run {label}: the robot's body or head touched a landmark or wall at {instants} "
                      f"whisk-series instant(s) (body_collision_instants): it was not driven clear of the world")


def warn_trained_on_a_reference(store: Store, runs: dict[str, RunFile]) -> None:
    """Warn (log, manifest.json, report.md) when the training run holds the same recording as
    an evaluation's reference run (equal content digests): every score of that evaluation then
    reads features fitted on the run it searches. A query recording is refused before this
    (`vitaplace.engine.config.inputs`). A recorded training run's is kept, not logged again:
    loading the scenario logged it, naming the files."""
    train = runs["train"]
    for label, record in runs.items():
        if label.endswith("/reference") and record.digest == train.digest:
            feature, message = f"trained on {label}", (
                f"run train is the same recording as {label}: the methods are fitted on the run evaluation "
                f"{label.rpartition('/')[0]} searches, so its scores measure recognising places of the training run "
                "itself")
            if train.recorded:
                store.run(train).warnings.setdefault(feature, message)
            else:
                warn_once(store.run(train), feature, message)


def warn_stays(store: Store, runs: dict[str, RunFile]) -> None:
    """Warn about every run whose robot stayed in one place (`longest_stay`) for at least
    `STUCK_SHARE` of its samples, and at least `STUCK_SAMPLES`: a stuck drive, whose samples
    repeat one place and would make that world's scores unrepresentative."""
    for label, record in runs.items():
        run = store.run(record)
        length, start = longest_stay(run.poses[:, :2])
        if is_stuck(length, len(run.poses)):
            warn_once(run, "longest_stay",
                      f"run {label}: the robot stayed within {STAY_RADIUS} m of one place for {length} of its "
                      f"{len(run.poses)} samples, from sample {start} (longest_stay): it got stuck there")
