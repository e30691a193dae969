"""The simulate stage's jobs: one `SimulationJob` per run to simulate, run in this process or
in worker processes (`simulations_in_workers`), each writing its run file."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from vitaplace.engine.data.dataset import write_run
from vitaplace.engine.pipeline.processes import interrupts_to_this_process, stop_pool, worker_pool
from vitaplace.engine.sim.environment import load_environment
from vitaplace.engine.sim.plausibility import LONG_SECONDS, duration

log = logging.getLogger("vitaplace")


@dataclass(frozen=True)
class SimulationJob:
    """One run to simulate (plain data: it travels to worker processes)."""

    #: the run's label in the scenario (``train``, ``E1/query``)
    label: str
    #: the environment file
    environment: str
    #: the run and robot settings (`RunSpec`, `RobotSpec` as dicts; `run_spec` reads the former)
    run: dict[str, Any]
    robot: dict[str, Any]
    seed: int
    #: the simulate stage's key for this run
    key: str
    #: the run file to write
    path: Path
    #: estimated seconds on one core (`estimated_seconds`)
    estimate: float


def simulate_to_file(job: SimulationJob, progress: bool) -> tuple[int, float]:
    """Simulate ``job``'s run and write its run file (a top-level function: runs in worker
    processes); returns its number of samples and the seconds it took."""
    from vitaplace.engine.sim.robot import RobotSpec
    from vitaplace.engine.sim.simulate import run_spec, simulate_run

    start = time.perf_counter()
    simulated = simulate_run(load_environment(job.environment), run_spec(job.run), seed=job.seed,
                             robot=RobotSpec(**job.robot), progress=progress, name=job.label)
    simulated.attrs["run_key"] = job.key
    write_run(job.path, simulated)
    return len(simulated), time.perf_counter() - start


def log_simulated(label: str, samples: int, seconds: float, where: str = "") -> None:
    """The line a finished simulation logs: run, samples, seconds (and where it ran)."""
    log.info("%-9s %-28s simulated %d samples in %.1f s%s", "simulate", label, samples, seconds, where)


def _log_finished(label: str, future: Future[tuple[int, float]]) -> None:
    """Done-callback of a simulation in a worker process: log it as soon as it finishes."""
    if not future.cancelled() and future.exception() is None:
        log_simulated(label, *future.result(), " (worker process)")


def simulate_here(job: SimulationJob, progress: bool) -> tuple[int, float]:
    """`simulate_to_file` in this process, then its log line."""
    result = simulate_to_file(job, progress)
    log_simulated(job.label, *result)
    return result


def _await(future: Future, job: SimulationJob) -> tuple[int, float]:
    """The result of a simulation in a worker process; for a long one (`LONG_SECONDS`), a log
    line each tenth of its estimated time while it runs."""
    if job.estimate <= LONG_SECONDS:
        return future.result()
    started = time.perf_counter()
    while True:
        try:
            return future.result(timeout=job.estimate / 10)
        except FutureTimeout:
            log.info("%-9s %-28s running for %s of an estimated %s", "simulate", job.label,
                     duration(time.perf_counter() - started), duration(job.estimate))


@contextmanager
def simulations_in_workers(jobs: Sequence[SimulationJob], workers: int) -> Iterator[dict[str, Callable[[], Any]]]:
    """With more than one of ``workers`` and ``jobs``: start ``jobs`` on that many worker
    processes and give, by label, a call that waits for each one's result; else nothing (the
    caller simulates in this process). Ctrl-C kills the workers; leaving ends the pool."""
    workers = min(workers, len(jobs))
    if workers <= 1:
        yield {}
        return
    pool = worker_pool(workers)
    try:
        with interrupts_to_this_process():
            futures = {job.label: (job, pool.submit(simulate_to_file, job, False)) for job in jobs}
        for label, (_, future) in futures.items():
            future.add_done_callback(partial(_log_finished, label))
        log.info("%-9s %d runs on %d worker processes (no progress bars there; a line as each finishes)",
                 "simulate", len(futures), workers)
        yield {label: partial(_await, future, job) for label, (job, future) in futures.items()}
    except KeyboardInterrupt:
        stop_pool(pool)
        raise
    finally:
        pool.shutdown(cancel_futures=True)
