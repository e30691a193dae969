"""How many CPUs this process may use, and BLAS thread pools sized to them.

`os.cpu_count` counts the machine's cores, not the ones a job was given: under ``taskset``,
a container's CPU set or quota, or a SLURM allocation it overcounts, and pools sized by it run
more workers and BLAS threads than there are cores for them. `usable_cpus` takes the smallest
of what loky's ``cpu_count`` reads (the process's CPU affinity and a cgroup v1/v2 CPU quota;
loky ships with joblib, a dependency of scikit-learn), SLURM's ``SLURM_CPUS_PER_TASK`` (the
allocation, which SLURM does not always pin) and ``VITAPLACE_CPUS`` (the user's override).

BLAS threads: one per process unless ``VITAPLACE_BLAS_THREADS`` asks for more (`blas_threads`),
and never more than the process's share of the usable CPUs. Two-thread GEMMs at this project's
sizes gain little on an idle machine and lose several times over when another job takes a core
(docs/PERFORMANCE.md, "BLAS threads"); with more than one thread, small batches (the settling
solver's last samples) still run on one (`small_batch_threads`).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator
from typing import TYPE_CHECKING

from vitaplace.engine.base.errors import UserError

if TYPE_CHECKING:
    from threadpoolctl import ThreadpoolController

#: environment variable that caps the CPUs vitaplace uses (worker pools, BLAS threads, compile threads)
OVERRIDE_ENV = "VITAPLACE_CPUS"
SLURM_ENV = "SLURM_CPUS_PER_TASK"


def _positive(name: str) -> int | None:
    """The positive integer in environment variable ``name``, None when unset or empty."""
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise UserError(f"environment variable {name}={text!r}: expected a positive whole number of CPUs")
    return value


def usable_cpus() -> int:
    """CPUs this process may use: min(affinity and cgroup quota, ``SLURM_CPUS_PER_TASK``, ``VITAPLACE_CPUS``)."""
    from joblib.externals.loky import cpu_count

    counts = [cpu_count(only_physical_cores=False)]
    counts += [n for n in (_positive(SLURM_ENV), _positive(OVERRIDE_ENV)) if n is not None]
    return max(1, min(counts))


#: environment variable that sets each vitaplace process's BLAS threads (default `DEFAULT_BLAS_THREADS`)
BLAS_ENV = "VITAPLACE_BLAS_THREADS"
#: BLAS threads per process unless `BLAS_ENV` says otherwise
DEFAULT_BLAS_THREADS = 1
#: batches of at most this many samples run their GEMMs on one BLAS thread (`small_batch_threads`)
SMALL_BATCH = 32


def blas_threads(processes: int = 1) -> int:
    """BLAS threads for each of ``processes`` processes that share this process's CPUs:
    ``VITAPLACE_BLAS_THREADS`` (default 1), lowered so that processes x threads <= `usable_cpus`."""
    wanted = _positive(BLAS_ENV) or DEFAULT_BLAS_THREADS
    return max(1, min(wanted, usable_cpus() // max(1, processes)))


def configure_blas_threads(processes: int = 1) -> int:
    """`limit_blas_threads` to `blas_threads` (``processes`` sharing the CPUs): what ``vitaplace
    run``, ``sweep``, the Python API and the Gymnasium environment call first. Returns the cap."""
    return limit_blas_threads(blas_threads(processes))


#: the variables BLAS and OpenMP libraries read for their thread count when they load
THREAD_ENVS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads(threads: int) -> int:
    """Size the BLAS and OpenMP thread pools of this process (and of processes it starts) to
    ``threads``, or fewer where one of `THREAD_ENVS` is set lower (by the user, or by an
    earlier call: a cap only ever goes down). Libraries loaded already are capped through
    threadpoolctl, later ones read the variables, which are set to the cap. Returns the cap."""
    import numpy  # noqa: F401 - loads numpy's BLAS, so that the cap reaches it
    from threadpoolctl import threadpool_limits

    user = [_positive(name) for name in THREAD_ENVS]
    threads = max(1, min([threads, *[n for n in user if n is not None]]))
    for name in THREAD_ENVS:
        os.environ[name] = str(threads)
    threadpool_limits(limits=threads)
    return threads


def blas_libraries() -> list[dict[str, str | int | None]]:
    """The BLAS libraries this process has loaded (numpy's among them): threadpoolctl's
    ``internal_api``, version, ``architecture`` (the kernel family OpenBLAS picked for this CPU,
    or ``OPENBLAS_CORETYPE``'s) and threads. Another architecture rounds its sums differently,
    so a run's manifest records them (docs/DESIGN.md, "Rounding")."""
    import numpy  # noqa: F401 - loads numpy's BLAS, so that it is listed
    from threadpoolctl import threadpool_info

    return [{"library": lib["internal_api"], "version": lib.get("version"), "architecture": lib.get("architecture"),
             "threads": lib["num_threads"]} for lib in threadpool_info() if lib["user_api"] == "blas"]


@functools.cache
def _blas_controller() -> ThreadpoolController:
    """The BLAS libraries loaded when first asked (numpy's among them), found once."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController().select(user_api="blas")


@contextlib.contextmanager
def small_batch_threads(rows: int) -> Iterator[None]:
    """One BLAS thread inside while ``rows`` <= `SMALL_BATCH` and the BLAS pools have more: a
    GEMM with a short side of a few rows is split into slivers whose threads mostly wait on
    each other. Otherwise (and with one thread already) it changes nothing."""
    if rows > SMALL_BATCH:
        yield
        return
    controller = _blas_controller()
    if all(lib.num_threads <= 1 for lib in controller.lib_controllers):
        yield
        return
    with controller.limit(limits=1):
        yield
