"""Worker processes: pools of spawned workers that end with the process that made them
(Linux: the kernel's parent-death signal through ``prctl``), and Ctrl-C kept to the driver
while they start."""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from vitaplace.engine.base.cpus import limit_blas_threads


def process_identity(pid: int) -> str:
    """``pid`` with its start time where the OS says it (Linux ``/proc``), so a reused pid
    does not pass for the process that had it before."""
    try:
        start = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        start = "?"
    return f"{pid}:{start}"


#: multiprocessing's resource tracker (a process of its own) reports the semaphores that a
#: Ctrl-C left to it, and cleans them up: its report would follow the one-line interrupt
#: message, so it is silenced, by a -W option that the tracker inherits
TRACKER_REPORT = "ignore:resource_tracker:UserWarning:multiprocessing.resource_tracker"


def worker_pool(workers: int, blas_threads: int | None = None) -> ProcessPoolExecutor:
    """A pool of spawned worker processes that end with the process that made it
    (`die_with_parent`), each limited to ``blas_threads`` BLAS threads when given."""
    if TRACKER_REPORT not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_REPORT)  # passed on as -W to the processes started from now on
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
