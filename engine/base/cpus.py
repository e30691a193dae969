"""How many CPUs this process may use, and BLAS thread pools sized to them.

`os.cpu_count` counts the machine's cores, not the ones a job was given: under ``taskset``,
a container's CPU set or a SLURM allocation it overcounts, and pools sized by it run more
workers and BLAS threads than there are cores for them. `usable_cpus` takes the smallest of
the process's CPU affinity (``os.sched_getaffinity``, where the platform has it), SLURM's
``SLURM_CPUS_PER_TASK`` (the allocation, which SLURM does not always pin) and ``VITAPLACE_CPUS``
(the user's override).
"""

from __future__ import annotations

import os

from vitaplace.engine.base.errors import UserError

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
    """CPUs this process may use: min(affinity, ``SLURM_CPUS_PER_TASK``, ``VITAPLACE_CPUS``)."""
    affinity = getattr(os, "sched_getaffinity", None)
    counts = [len(affinity(0)) if affinity is not None else os.cpu_count() or 1]
    counts += [n for n in (_positive(SLURM_ENV), _positive(OVERRIDE_ENV)) if n is not None]
    return max(1, min(counts))


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
