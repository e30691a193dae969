"""Sweeps: one scenario over many seeds, on a local process pool, a Ray cluster or SLURM.

The driver validates the scenario once and sends each job everything it needs as data: the
resolved scenario with the job's seed set, the resolved content of every environment file
it names, and absolute paths. A job writes its environments into ``OUT/seed-<s>/environments``
and runs the whole pipeline into ``OUT/seed-<s>``; all jobs share the stage cache
``OUT/cache`` (content-hash keys, atomic renames). A job that fails leaves its traceback in
``OUT/seed-<s>/error.txt``; the driver reports it in one line and goes on with the others.

When every job has ended, the summary of the seeds that succeeded is written
(`vitaplace.engine.study.summary`). `run_sweep` returns which seeds failed; the CLI exits 1 when
any did (2 stays for user errors found before any job starts).

``OUT`` must be storage every worker shares for the seed folders and the cache to land in
one place: each job reports its host name and whether it sees a marker file the driver
wrote into ``OUT``; the driver warns once when one does not.

Before submitting to Ray, the driver names the cluster's address, runs a probe task on every
node and refuses a node whose vitaplace version, git commit, uncommitted changes or installed
feature plugins differ from its own (`vitaplace.engine.cli.installation`), and refuses
resources no node has. SLURM arrays go through submitit (`vitaplace.engine.cli.slurm`), each
task checking its installation the same way.
"""

from __future__ import annotations

import copy
import logging
import os
import re
import socket
import sys
import time
import traceback
import typing
import uuid
from collections.abc import Generator, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.cpus import blas_threads, configure_blas_threads, usable_cpus
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.cli.installation import describe, installation, mismatch
from vitaplace.engine.cli.ray_auth import held_stderr, init_ray
from vitaplace.engine.cli.slurm import SlurmSettings, run_array
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import Scenario, ScenarioError
from vitaplace.engine.outputs.outdir import SEED_ERROR, cache_dir, seed_dir
from vitaplace.engine.outputs.stale import drop_sweep_sensitivity
from vitaplace.engine.study.grid import (
    GridPoint,
    check_replace,
    check_seeds,
    progress_bar,
    summarise_point,
    write_grid_summary,
)

log = logging.getLogger("vitaplace")

ANSI = re.compile(r"\x1b\[[0-9;?]*[ -/]*[@-~]")
#: the longest failure message a one-line report quotes
MAX_MESSAGE = 300


@dataclass(frozen=True)
class SeedJob:
    """Everything one seed needs, as data: no path in it is relative or read from the driver."""

    #: the validated, resolved scenario mapping with this job's seed
    scenario: dict[str, Any]
    #: environment as named in ``scenario`` -> its resolved specification (extends merged)
    environments: dict[str, dict[str, Any]]
    seed: int
    #: the sweep's output folder, absolute
    out: str
    force: tuple[str, ...] = ()
    progress: bool = False
    #: a file the driver wrote into ``out``; a job that cannot see it is on other storage
    marker: str = ""
    #: the job's grid point, its folder in ``out`` (`vitaplace.engine.study.grid`); "" without a grid
    point: str = ""

    @property
    def key(self) -> int | str:
        """The job's name in a sweep's outcome: the seed, or ``<point>/seed-<s>`` on a grid."""
        return f"{self.point}/seed-{self.seed}" if self.point else self.seed

    @property
    def label(self) -> str:
        """``seed <s>``, or ``<point> seed <s>`` on a grid (log lines, Ray task names)."""
        return f"{self.point} seed {self.seed}" if self.point else f"seed {self.seed}"

    @property
    def folder(self) -> Path:
        """The job's run folder: ``OUT[/<point>]/seed-<s>``."""
        return seed_dir(Path(self.out) / self.point, self.seed)


class SeedFailed(Exception):
    """A job's exception, reduced to its type name and message (always picklable)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(kind, message)
        self.kind, self.message = kind, message

    def __str__(self) -> str:
        return f"{self.kind}: {self.message}"


@dataclass
class SweepOutcome:
    """What a sweep did: result rows of the seeds that succeeded, one line per failed seed."""

    out: Path
    rows: list[dict[str, Any]] = field(default_factory=list)
    #: `SeedJob.key` (the seed, or ``<point>/seed-<s>`` on a grid) -> its failure in one line
    failed: dict[int | str, str] = field(default_factory=dict)
    #: hosts whose jobs could not see the driver's ``OUT``
    unshared: list[str] = field(default_factory=list)
    #: the summary rows written to sweep.csv (on a grid: grid.csv, each row naming its point)
    summary: list[dict[str, Any]] = field(default_factory=list)


def one_line(text: str) -> str:
    """``text`` without ANSI colour codes, its whitespace collapsed, capped at `MAX_MESSAGE`."""
    text = " ".join(ANSI.sub("", text).split())
    return text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 3] + "..."


def describe_failure(exc: BaseException) -> str:
    """``Type: message`` of a job's failure, without any remote traceback."""
    cause = getattr(exc, "cause", None)  # Ray wraps the task's exception in a RayTaskError
    if isinstance(cause, BaseException):
        exc = cause
    if isinstance(exc, SeedFailed):
        return one_line(str(exc))
    lines = [line for line in ANSI.sub("", str(exc)).splitlines() if line.strip()]
    return one_line(f"{type(exc).__name__}: {lines[0] if lines else ''}")


def _localise(job: SeedJob, folder: Path) -> dict[str, Any]:
    """The job's scenario with each environment written into ``folder/environments``."""
    resolved = copy.deepcopy(job.scenario)
    files: dict[str, Path] = {}
    for named, spec in job.environments.items():
        stem = base = Path(named).stem or "environment"
        k = 2
        while any(p.stem == stem for p in files.values()):
            stem, k = f"{base}-{k}", k + 1
        files[named] = folder / "environments" / f"{stem}.yaml"
        write_text_atomic(files[named], yaml.safe_dump(spec, sort_keys=False))
    for entry in _runs(resolved):
        if isinstance(entry.get("environment"), str):
            entry["environment"] = str(files[entry["environment"]])
    return resolved


def _runs(resolved: dict[str, Any]) -> list[dict[str, Any]]:
    """The train and evaluation entries of a resolved scenario mapping."""
    return [entry for entry in [resolved.get("train"), *resolved.get("evaluations", [])] if isinstance(entry, dict)]


def _absolute_files(resolved: dict[str, Any]) -> dict[str, Any]:
    """``resolved`` with recorded-run file paths (``dataset``, ``datasets``) made absolute:
    workers read those files where they are, so they must be on storage the workers share."""
    resolved = copy.deepcopy(resolved)
    for entry in _runs(resolved):
        holders = [(entry, "dataset")]
        if isinstance(entry.get("datasets"), dict):
            holders += [(entry["datasets"], "query"), (entry["datasets"], "reference")]
        for holder, key in holders:
            if isinstance(holder.get(key), str):
                holder[key] = os.path.abspath(holder[key])
    return resolved


def run_seed(job: SeedJob) -> dict[str, Any]:
    """One sweep job (runs in a worker): the whole pipeline for ``job.seed``. Returns its
    result rows tagged with the seed, the host and whether it saw the driver's marker;
    raises SeedFailed, with the traceback in ``OUT/seed-<s>/error.txt``."""
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store

    configure_blas_threads()  # within a Ray task's or SLURM task's CPUs, a pool worker's share
    host, sees_out = socket.gethostname(), not job.marker or Path(job.marker).exists()
    if not sees_out:
        log.warning("%s on %s: %s is not visible here: --out is not on shared storage", job.label, host, job.out)
    folder = job.folder
    handler = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / SEED_ERROR).unlink(missing_ok=True)  # from an earlier attempt
        handler = logging.FileHandler(folder / "log.txt")
        handler.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)
        resolved = _localise(job, folder)
        scenario = Scenario.model_validate(resolved)
        store = Store(folder, force=job.force, progress=job.progress, workers=1, cache=cache_dir(Path(job.out)))
        rows = [{"seed": job.seed, **row.dump()} for row in run_stages(scenario, resolved, store)]
    except Exception as exc:
        try:
            write_text_atomic(folder / SEED_ERROR, traceback.format_exc())
        except OSError:
            pass
        raise SeedFailed(type(exc).__name__, one_line(str(exc))) from None
    finally:
        if handler is not None:
            log.removeHandler(handler)
            handler.close()
    return {"seed": job.seed, "rows": rows, "host": host, "sees_out": sees_out}


def run_seed_reported(job: SeedJob) -> dict[str, Any]:
    """`run_seed` for schedulers that hand back only a traceback of a job's exception
    (submitit): a seed's failure comes back as ``{"seed": s, "failure": "Type: message"}``."""
    try:
        return run_seed(job)
    except SeedFailed as exc:
        return {"seed": job.seed, "failure": str(exc)}


def gpu_overrides(scenario: Scenario) -> list[str]:
    """``--set`` assignments giving every method whose extractor has a ``backend`` parameter
    its GPU backend (``cuda``, else ``warp``), unless the scenario chose one other than auto."""
    from vitaplace.engine.extension.registry import discover

    registry = discover()
    overrides = []
    for i, method in enumerate(scenario.methods):
        backend = registry.get(method.plugin).Params.model_fields.get("backend")
        choices = typing.get_args(backend.annotation) if backend is not None else ()
        gpu = next((c for c in ("cuda", "warp") if c in choices), None)
        if gpu is None:
            continue
        if method.params.get("backend", "auto") != "auto":
            log.info("method %s keeps its backend %s (--gpus-per-job)", method.name, method.params["backend"])
            continue
        overrides.append(f"methods.{i}.params.backend={gpu}")
    return overrides


def load_sweep_scenario(
    name: str, overrides: Sequence[str], gpus_per_job: float = 0
) -> tuple[Scenario, dict[str, Any]]:
    """The validated scenario and its resolved mapping; with GPUs per job, methods that have
    a backend parameter are set to their GPU backend (`gpu_overrides`)."""
    scenario, resolved = load_scenario(name, overrides)
    if gpus_per_job > 0:
        extra = gpu_overrides(scenario)
        if extra:
            log.info("GPU jobs: %s", " ".join(f"--set {e}" for e in extra))
            scenario, resolved = load_scenario(name, [*overrides, *extra])
    return scenario, resolved


#: the figures each seed's report draws unless the scenario's ``report.figures`` says: the PR
#: curves and training energy a reader of the sweep looks at, not every method's matrices
SEED_FIGURES = "summary"


def seed_jobs(
    scenario: Scenario, resolved: dict[str, Any], seeds: Sequence[int], out: Path, force: Sequence[str] = (),
    progress: bool = False, marker: str = "", point: str = "",
) -> list[SeedJob]:
    """One job per seed (of the grid point ``point``); each seed is validated here, so a bad
    one is a user error up front. Each seed's report draws `SEED_FIGURES` unless the scenario
    sets ``report.figures``."""
    from vitaplace.engine.pipeline.keys import STAGES
    from vitaplace.engine.sim.environment import load_environment

    unknown = set(force) - set(STAGES)
    if unknown:
        raise ScenarioError(f"--force: unknown stage(s) {', '.join(sorted(unknown))}; stages: {', '.join(STAGES)}")
    check_seeds(seeds)
    named = [entry["environment"] for entry in _runs(resolved) if isinstance(entry.get("environment"), str)]
    environments = {n: load_environment(n).model_dump(mode="json") for n in named}
    resolved = _absolute_files(resolved)
    resolved["report"] = {"figures": SEED_FIGURES, **(resolved.get("report") or {})}
    jobs = []
    for seed in seeds:
        data = {**copy.deepcopy(resolved), "seed": seed}
        jobs.append(SeedJob(data, environments, seed, str(out), tuple(force), progress, marker, point))
    return jobs


def sweep_jobs(
    points: Sequence[GridPoint], seeds: Sequence[int], out: Path, force: Sequence[str] = (), progress: bool = False,
    marker: str = "", bar: bool = False,
) -> list[SeedJob]:
    """The jobs of a sweep, point by point (`seed_jobs` of each loaded grid point): what every
    backend runs. ``bar``: a progress bar over the points (`progress_bar`)."""
    jobs: list[SeedJob] = []
    for point in progress_bar(points, "grid points prepared", bar):
        assert point.scenario is not None  # loaded: load_points
        jobs += seed_jobs(point.scenario, dict(point.resolved), seeds, out, force, progress, marker, point.name)
    return jobs


def _local(jobs: Sequence[SeedJob], workers: int) -> Iterator[tuple[SeedJob, dict[str, Any] | None, str | None]]:
    """Run ``jobs`` on a process pool; yield (job, result, failure) as each one ends.

    A worker process that dies (killed, out of memory, a crash in native code) breaks the
    pool and every job still in it; those jobs run again, each in a pool of its own, so the
    one that kills its process fails alone (its finished stages are cached and resume)."""
    rounds = [(list(jobs), workers)]
    retried: set[int | str] = set()
    while rounds:
        batch, width = rounds.pop(0)
        broken = yield from _pool_round(batch, width)
        for job in broken:
            if job.key in retried:
                yield job, None, "its worker process died (killed, out of memory or crashed in native code)"
            else:
                retried.add(job.key)
                rounds.append(([job], 1))


def _pool_round(
    jobs: Sequence[SeedJob], workers: int
) -> Generator[tuple[SeedJob, dict[str, Any] | None, str | None], None, list[SeedJob]]:
    """One process pool over ``jobs``: yields (job, result, failure) for the jobs that ended,
    returns those lost to a broken pool."""
    from vitaplace.engine.pipeline.processes import interrupts_to_this_process, stop_pool, worker_pool

    # spawned, not forked (GL and Warp state are not fork-safe); BLAS threads: each worker its share
    pool = worker_pool(workers, blas_threads=blas_threads(workers))
    broken: list[SeedJob] = []
    try:
        with interrupts_to_this_process():
            pending = {pool.submit(run_seed, job): job for job in jobs}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                job = pending.pop(future)
                try:
                    yield job, future.result(), None
                except BrokenProcessPool:
                    broken.append(job)
                except Exception as exc:
                    yield job, None, describe_failure(exc)
    except BaseException:
        stop_pool(pool)  # interrupted: do not wait for running seeds
        raise
    pool.shutdown()
    return broken


#: seconds to wait for a Ray address to accept a connection, and for the probe tasks
CONNECT_TIMEOUT_S = 5.0
PROBE_TIMEOUT_S = 120.0


def _check_reachable(address: str) -> None:
    """Refuse, within seconds, a Ray address nothing listens on (Ray itself retries for minutes)."""
    target = address.split("://", 1)[-1].rstrip("/")
    host, colon, port = target.rpartition(":")
    if not colon or not host or not port.isdigit():
        raise UserError(f"--ray {address}: expected auto, HOST:PORT or ray://HOST:PORT")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise UserError(f"--ray {address}: nothing answers at {host}:{port} ({exc.strerror or exc}); "
                        "is the cluster up?") from None


def connect_ray(address: str) -> tuple[Any, str]:
    """The ``ray`` module, connected, and the cluster's address: ``auto`` joins the cluster
    ``RAY_ADDRESS`` or a ``ray start`` on this machine names, or starts a local one; anything
    else is a cluster address. A runtime this process started is reused."""
    try:
        import ray
    except ImportError:
        raise UserError("--ray needs the optional dependency: pip install 'vitaplace[ray]'") from None
    how = "connected to"
    if ray.is_initialized():
        how = "using the runtime this process already started,"
    elif address == "auto":
        if os.environ.get("RAY_ADDRESS", "auto") != "auto":
            _check_reachable(os.environ["RAY_ADDRESS"])
        try:
            init_ray(ray, "auto", f"--ray auto (RAY_ADDRESS={os.environ.get('RAY_ADDRESS', 'unset')})")
        except ConnectionError:
            ray.init(address="local")
            how = "no running cluster found; started a local one,"
    else:
        _check_reachable(address)
        try:
            init_ray(ray, address, f"--ray {address}")
        except ConnectionError as exc:
            raise UserError(f"--ray {address}: {one_line(str(exc))}") from None
    try:
        where = ray.get_runtime_context().gcs_address
    except Exception:  # noqa: BLE001 - a Ray Client connection does not know the GCS address
        where = address
    log.info("Ray: %s cluster %s", how, where)
    return ray, where


def _probe() -> dict[str, Any]:
    """Probe task: this worker's host and `installation`, and what the worker wrote to stderr
    meanwhile (``stderr``: shown only when the check fails)."""
    with held_stderr() as held:
        found = installation()
    return {"host": socket.gethostname(), **found, "stderr": held.text}


def check_ray_cluster(ray: Any, where: str, cpus: float, gpus: float) -> None:
    """Refuse, before any seed is submitted, a cluster that cannot run the sweep right: a node
    whose `installation` differs from the driver's, or no node with ``cpus`` CPUs and ``gpus``
    GPUs (the seeds would wait forever). What the check writes to stderr, on the driver and in
    the probe tasks (Ray's native stack traces among it), is shown only when it fails."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [node for node in ray.nodes() if node.get("Alive")]
    sizes = [(node["Resources"].get("CPU", 0), node["Resources"].get("GPU", 0)) for node in nodes]
    if not any(c >= cpus and g >= gpus for c, g in sizes):
        have = ", ".join(f"{c:g} CPUs/{g:g} GPUs" for c, g in sizes) or "no nodes"
        raise UserError(f"--cpus-per-job {cpus:g} --gpus-per-job {gpus:g}: no node of the Ray cluster {where} has "
                        f"that many (its nodes: {have}); the seeds would wait forever")
    probe = ray.remote(_probe)
    refs = [
        probe.options(name="vitaplace probe", num_cpus=0, max_retries=0,
                      scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote()
        for node in nodes
    ]
    found: list[dict[str, Any]] = []
    with held_stderr() as held:
        mine = installation()
        try:
            found = ray.get(refs, timeout=PROBE_TIMEOUT_S)
            failure = next(filter(None, (mismatch(mine, theirs, f"node {theirs['host']}") for theirs in found)), None)
        except Exception as exc:  # noqa: BLE001 - e.g. vitaplace cannot be imported on a node
            failure = f"the probe task failed on the cluster: {describe_failure(exc)}"
    if failure is not None:
        sys.stderr.write(held.text + "".join(theirs.get("stderr", "") for theirs in found))
        raise UserError(f"--ray {where}: {failure}")
    log.info("Ray: %d node(s) run %s", len(found), describe(mine))


def _ray(
    jobs: Sequence[SeedJob], name: str, address: str, cpus: float, gpus: float, env: Mapping[str, str] | None = None
) -> Iterator[tuple[SeedJob, dict[str, Any] | None, str | None]]:
    """Connect to the cluster and check it (now, before any seed runs), then run ``jobs`` as
    Ray tasks (`_ray_tasks`)."""
    ray, where = connect_ray(address)
    check_ray_cluster(ray, where, cpus, gpus)
    return _ray_tasks(ray, jobs, name, cpus, gpus, env)


def _ray_tasks(
    ray: Any, jobs: Sequence[SeedJob], name: str, cpus: float, gpus: float, env: Mapping[str, str] | None = None
) -> Iterator[tuple[SeedJob, dict[str, Any] | None, str | None]]:
    """Run ``jobs`` as Ray tasks named "<scenario> seed <s>" (on a grid "<scenario> <point> seed <s>"),
    with the environment variables ``env`` (the plugins' `vitaplace_sweep_started` asks; a worker
    has the raylet's environment, not the driver's); yield as each one ends."""
    remote = ray.remote(run_seed)
    extra = {"runtime_env": {"env_vars": dict(env)}} if env else {}
    pending = {
        remote.options(name=f"{name} {job.label}", num_cpus=cpus, num_gpus=gpus, **extra).remote(job): job
        for job in jobs
    }
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    yield job, ray.get(ref), None
                except Exception as exc:
                    yield job, None, describe_failure(exc)
    finally:
        for ref in pending:
            ray.cancel(ref)


def check_placement(
    workers: int | None, ray_address: str | None, slurm: SlurmSettings | None, gpus_per_job: float
) -> None:
    """Refuse options that do not apply where the seeds run (they would be ignored, or worse)."""
    if gpus_per_job and not (ray_address or slurm):
        raise UserError("--gpus-per-job: applies to --ray and --slurm jobs; on this machine every seed uses the "
                        "methods' own backend (e.g. --set methods.0.params.backend=warp)")
    if workers and (ray_address or slurm):
        raise UserError("--workers: applies to sweeps on this machine; --ray and --slurm place seeds by "
                        "--cpus-per-job and --gpus-per-job")


def run_sweep(
    scenario: Scenario,
    resolved: dict[str, Any],
    seeds: Sequence[int],
    out: Path,
    workers: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    force: Sequence[str] = (),
    cpus_per_job: float = 1,
    gpus_per_job: float = 0,
    slurm: SlurmSettings | None = None,
    grid: Sequence[GridPoint] = (),
    replace: bool = False,
) -> SweepOutcome:
    """Run every seed (of every point of ``grid``, loaded by
    `vitaplace.engine.study.grid.load_points`; without one, of ``scenario``), locally (process
    pool), on Ray or as a SLURM array (``slurm``; its settings then give the CPUs and GPUs),
    and write the summary of those that succeeded into ``out`` (`vitaplace.engine.study.summary`;
    on a grid, each point's into ``out/<point>`` and the table across points into ``out``). A
    failed seed does not stop the others. An ``out`` whose summary covers seeds or grid points
    this sweep lacks is refused before anything runs, unless ``replace`` (`check_replace`)."""
    from vitaplace.engine.extension.registry import announce_sweep_finished, announce_sweep_started, discover

    check_placement(workers, ray_address, slurm, gpus_per_job)
    out = Path(os.path.abspath(out))
    out.mkdir(parents=True, exist_ok=True)
    points = list(grid) or [GridPoint("", scenario=scenario, resolved=resolved)]
    check_replace(out, points, seeds, replace)
    marker = out / f".sweep-marker-{uuid.uuid4().hex}"
    local = not (ray_address or slurm)
    jobs = sweep_jobs(points, seeds, out, force, progress and len(seeds) * len(points) == 1 and local, str(marker),
                      progress)
    registry = discover()
    worker_env = announce_sweep_started(registry, out, scenario, list(seeds), list(grid))  # e.g. a tracker's parent run
    saved_env = {name: os.environ.get(name) for name in worker_env}
    os.environ.update(worker_env)  # inherited by the local workers and SLURM's tasks; Ray's get them below
    marker.write_text("")
    try:
        if ray_address:
            ended = _ray(jobs, scenario.name, ray_address, cpus_per_job, gpus_per_job, worker_env)
        elif slurm:  # sbatch refusing the array is a UserError here: the marker goes all the same
            ended = run_array(run_seed_reported, jobs, slurm, out / "slurm", f"vitaplace-{scenario.name}")
        else:
            ended = _local(jobs, workers or max(1, min(len(jobs), usable_cpus() // max(1, int(cpus_per_job)))))
        outcome, by_point = _collect(out, ended, len(jobs), progress)
    finally:
        marker.unlink(missing_ok=True)
        for name, value in saved_env.items():  # the driver's environment as it was
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    found = {p.name: by_point.get(p.name, ([], {})) for p in points}
    for path in drop_sweep_sensitivity(out, found):
        log.info("removed %s: it rescored the evaluations this sweep summarises anew", path)
    summaries = {p.name: summarise_point(out, p, scenario.name, *found[p.name], usable_cpus())
                 for p in progress_bar(points, "grid point summaries", progress)}
    outcome.summary = (write_grid_summary(out, scenario.name, points, seeds, summaries,
                                          {name: failed for name, (_, failed) in found.items()})
                       if grid else summaries[""])
    ok = sorted({row["seed"] for row in outcome.rows})
    announce_sweep_finished(registry, out, scenario, ok, dict(outcome.failed), worker_env)
    return outcome


def _collect(
    out: Path, ended: Iterator[tuple[SeedJob, dict[str, Any] | None, str | None]], total: int, progress: bool
) -> tuple[SweepOutcome, dict[str, tuple[list[dict[str, Any]], dict[int, str]]]]:
    """Go through the ``total`` jobs as they end, each logged: the sweep's outcome, and per
    grid point (its name) the result rows of its seeds that succeeded and its failed seeds."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    outcome = SweepOutcome(out)
    by_point: dict[str, tuple[list[dict[str, Any]], dict[int, str]]] = {}
    started = time.perf_counter()
    with logging_redirect_tqdm([log]), tqdm(total=total, desc="seeds", unit="seed", disable=not progress) as bar:
        for job, result, failure in ended:
            bar.update()
            rows, failed = by_point.setdefault(job.point, ([], {}))
            if failure is not None:
                outcome.failed[job.key] = failed[job.seed] = failure
                trace = job.folder / SEED_ERROR
                where = f" (traceback in {trace})" if trace.is_file() else ""
                log.error("%s failed: %s%s", job.label, failure, where)
                continue
            assert result is not None  # a job that did not fail has its result
            outcome.rows += result["rows"]
            rows += result["rows"]
            if not result["sees_out"] and not outcome.unshared:
                log.warning(
                    "--out %s is not on storage the workers share: node %s cannot see it, so its seed folders "
                    "and cache stay on that node (the summary is still complete)", out, result["host"],
                )
            if not result["sees_out"]:
                outcome.unshared.append(result["host"])
            log.info("%s done on %s (%.0f s into the sweep)", job.label, result["host"], time.perf_counter() - started)
    return outcome, by_point
