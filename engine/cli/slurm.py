"""Sweep jobs on SLURM through submitit: one array job per sweep, one array task per seed.

The driver (`vitaplace sweep --slurm`) pickles each seed's job into ``OUT/slurm``, submits
one ``sbatch`` array whose tasks run `run_seed_reported` on the nodes (in ``OUT/slurm``, so
nothing in the submit directory shadows an installed module), and waits for them; each
task's stdout and stderr land in ``OUT/slurm`` too. A seed whose task fails (an error in the
pipeline, a time limit, a node lost) is reported in one line; the summary is built from the
seeds that finished, as for local and Ray sweeps. ``--slurm local`` runs the same array
through submitit's local executor: each task a process on this machine (for trying a sweep
out, and for the tests).

What the driver does not leave to submitit:

* sbatch refusing the array (a partition that does not exist, GPUs where there is no GRES,
  no slurm.conf, no controller answering) is a `UserError` quoting sbatch's own message;
* each task first compares its installation with the driver's (`CheckedTask`);
* the array's state comes from ``squeue`` alone (`QueueWatch`), never from ``sacct``, which
  clusters without accounting lack: a task squeue no longer lists and that left no result
  within `LOST_MARGIN_S`, or one still running `LOST_MARGIN_S` past its ``--time``, is lost;
* the array's job id is recorded in ``OUT/slurm/job.json``; a rerun into ``OUT`` while any
  of its tasks is still queued or running is refused, and an interrupted driver cancels the
  tasks and waits (up to `DRAIN_S`) for them to leave the queue.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import re
import socket
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.cli.installation import installation, mismatch

log = logging.getLogger("vitaplace")

#: sbatch options with an option of their own in `vitaplace sweep`
OWN_OPTIONS = {"partition": "--partition", "time": "--time", "mem": "--mem", "cpus-per-task": "--cpus-per-job",
               "gpus-per-node": "--gpus-per-job", "array": "(one array per sweep)",
               "output": "(logs go to OUT/slurm)", "error": "(logs go to OUT/slurm)",
               "chdir": "(tasks run in OUT/slurm)"}
#: sbatch's --time formats: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S
TIME = re.compile(r"^(?:(?P<days>\d+)-(?P<dh>\d+)(?::(?P<dm>\d+)(?::(?P<ds>\d+))?)?"
                  r"|(?P<a>\d+)(?::(?P<b>\d+)(?::(?P<c>\d+))?)?)$")
#: seconds between checks of the array's state (submitit caches sacct between them)
POLL_S = {"slurm": 15.0, "local": 0.5}
#: the shortest --time accepted, in minutes: submitit signals a task 90 s before its limit
#: (to requeue it), and a seed needs the rest to start Python, import the simulator and run
MIN_TIME_MIN = 5
#: seconds a task squeue no longer lists gets for its result file to appear (shared
#: storage may show it late), and a running task gets past its --time, before it is lost
LOST_MARGIN_S = 120.0
#: seconds an interrupted driver waits for its cancelled tasks to leave the queue
DRAIN_S = 60.0
#: the array job's id, in OUT/slurm, for a rerun to check the queue
JOB_RECORD = "job.json"


@dataclass(frozen=True)
class SlurmSettings:
    """What one array job asks the scheduler for; a task is one seed."""

    #: ``slurm``, or ``local`` for submitit's local executor
    cluster: str
    #: wall-clock limit of one task, in minutes
    time_min: int
    cpus: int = 1
    gpus: int = 0
    partition: str | None = None
    #: sbatch's --mem, as sbatch reads it (e.g. 16G)
    mem: str | None = None
    #: other sbatch options: name (without --) -> value, True for a flag
    sbatch: Mapping[str, Any] = field(default_factory=dict)
    #: at most this many tasks at once (sbatch's ``--array=...%N``); None: every task
    max_parallel: int | None = None


def parse_time(text: str) -> int:
    """sbatch's ``--time`` (minutes, M:S, H:M:S, D-H, D-H:M or D-H:M:S) in whole minutes, rounded up."""
    match = TIME.match(text.strip())
    if match is None:
        raise UserError(f"--time {text}: expected a time limit as sbatch reads it: "
                        "MINUTES, HH:MM:SS or DAYS-HH[:MM[:SS]]")
    g = {k: int(v) for k, v in match.groupdict().items() if v is not None}
    if "days" in g:
        seconds = ((g["days"] * 24 + g["dh"]) * 60 + g.get("dm", 0)) * 60 + g.get("ds", 0)
    elif "c" in g:
        seconds = (g["a"] * 60 + g["b"]) * 60 + g["c"]
    else:
        seconds = g["a"] * 60 + g.get("b", 0)
    if seconds <= 0:
        raise UserError(f"--time {text}: the time limit must be positive")
    return -(-seconds // 60)


def parse_sbatch(options: Sequence[str]) -> dict[str, Any]:
    """``--sbatch NAME=VALUE`` (or ``NAME`` for a flag) options, for sbatch's ``--NAME=VALUE``."""
    parsed: dict[str, Any] = {}
    for option in options:
        name, has_value, value = option.partition("=")
        name = name.strip().lstrip("-")
        if not name or (has_value and not value):
            raise UserError(f"--sbatch {option}: expected NAME=VALUE (e.g. --sbatch account=myproject) or a flag NAME")
        if name in OWN_OPTIONS:
            raise UserError(f"--sbatch {option}: use {OWN_OPTIONS[name]} instead")
        parsed[name] = value if has_value else True
    return parsed


def settings_from_args(args: Any) -> SlurmSettings | None:
    """The SLURM settings of `vitaplace sweep`'s arguments; None without --slurm. Options that
    only apply to SLURM are refused without it."""
    own = {"--partition": args.partition, "--time": args.time, "--mem": args.mem, "--sbatch": args.sbatch,
           "--max-parallel": args.max_parallel is not None}
    if args.slurm is None:
        given = [name for name, value in own.items() if value]
        if given:
            raise UserError(f"{' '.join(given)}: only with --slurm")
        return None
    if args.ray:
        raise UserError("--slurm and --ray: choose one")
    if args.time is None:
        raise UserError("--slurm needs --time, the time limit of one seed's task (e.g. --time 04:00:00)")
    for name in ("cpus_per_job", "gpus_per_job"):
        value = getattr(args, name)
        if value != int(value):
            raise UserError(f"--{name.replace('_', '-')} {value:g}: SLURM allots whole CPUs and GPUs")
    minutes = parse_time(args.time)
    if minutes < MIN_TIME_MIN:
        raise UserError(f"--time {args.time}: at least {MIN_TIME_MIN} minutes; submitit signals a task 90 s before "
                        "its limit, which leaves a shorter task no time to run its seed")
    if args.max_parallel is not None and args.max_parallel < 1:
        raise UserError(f"--max-parallel {args.max_parallel}: expected a number of tasks at once, at least 1")
    if args.max_parallel is not None and args.slurm == "local":
        raise UserError("--max-parallel: throttles an array on a SLURM cluster; "
                        "--slurm local starts every task at once")
    return SlurmSettings(args.slurm, minutes, int(args.cpus_per_job), int(args.gpus_per_job),
                         args.partition, args.mem, parse_sbatch(args.sbatch), args.max_parallel)


def executor(settings: SlurmSettings, folder: Path, name: str) -> Any:
    """A submitit executor for ``settings`` that keeps its scripts, pickles and logs in ``folder``."""
    try:
        import submitit
    except ImportError:
        raise UserError("--slurm needs the optional dependency: pip install 'vitaplace[slurm]'") from None
    try:
        ex = submitit.AutoExecutor(folder=folder, cluster=settings.cluster)
    except RuntimeError as exc:  # no srun/sbatch on this machine
        raise UserError(f"--slurm: {' '.join(str(exc).split())} "
                        "(--slurm local runs the tasks on this machine)") from None
    extra = {**({"mem": settings.mem} if settings.mem else {}), "chdir": str(folder), **settings.sbatch}
    throttle = {"slurm_array_parallelism": settings.max_parallel} if settings.max_parallel else {}
    ex.update_parameters(
        name=name, timeout_min=settings.time_min, cpus_per_task=settings.cpus, gpus_per_node=settings.gpus,
        nodes=1, tasks_per_node=1, slurm_partition=settings.partition, slurm_additional_parameters=extra, **throttle,
    )
    return ex


@dataclass(frozen=True)
class CheckedTask:
    """A task that first compares the node's `installation` with the driver's (``driver``):
    a node that runs other code fails its seed in one line instead of running it."""

    task: Callable[[Any], dict[str, Any]]
    driver: dict[str, Any]

    def __call__(self, job: Any) -> dict[str, Any]:
        differs = mismatch(self.driver, installation(), f"node {socket.gethostname()}")
        if differs:
            return {"seed": getattr(job, "seed", None), "failure": differs}
        return self.task(job)


def queued(array: str) -> dict[str, str] | None:
    """The tasks of array job ``array`` that squeue lists (``12_3`` -> state, e.g. PENDING),
    {} when it lists none (squeue forgets a job that ended), None when squeue fails."""
    try:
        result = subprocess.run(["squeue", "--noheader", "--array", f"--jobs={array}", "--format=%i %T"],
                                capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.warning("SLURM: squeue failed: %s", exc)
        return None
    if result.returncode != 0:
        if "Invalid job id" in result.stderr:
            return {}
        log.warning("SLURM: squeue failed: %s", " ".join(result.stderr.split()))
        return None
    return dict(line.split(None, 1) for line in result.stdout.splitlines() if len(line.split()) == 2)


def check_queue_clear(folder: Path) -> None:
    """Refuse a sweep whose array folder ``folder`` (``OUT/slurm``) records an earlier array
    (`JOB_RECORD`) that still has tasks in the queue: they would go on writing into the same
    seed folders. Call it before taking ``OUT``, whose cleaning removes the temporary files
    of writes still under way."""
    record = folder / JOB_RECORD
    if not record.is_file():
        return
    try:
        array = str(json.loads(record.read_text())["job"])
    except (ValueError, KeyError, TypeError):
        return  # not a record this module wrote whole (writes are atomic)
    listed = queued(array)
    if listed is None:
        raise UserError(f"--out {folder.parent}: cannot tell whether SLURM job {array} of an earlier sweep into this "
                        "folder is still running (squeue failed); try again when squeue answers")
    if listed:
        states = ", ".join(sorted(set(listed.values())))
        raise UserError(f"--out {folder.parent}: {len(listed)} task(s) of SLURM job {array}, "
                        f"an earlier sweep into this folder, are still in the queue ({states}); "
                        f"wait until `squeue -j {array}` lists none, "
                        f"or `scancel {array}`")


def run_array(
    task: Callable[[Any], dict[str, Any]], jobs: Sequence[Any], settings: SlurmSettings, folder: Path, name: str
) -> Iterator[tuple[Any, Any, str | None]]:
    """Submit ``task(job)`` for each of ``jobs`` (a sweep's `run_seed_reported` over its
    `SeedJob`s) as one array now, each task checked against the driver's installation
    (`CheckedTask`); the iterator returned yields (job, result, failure) as each task ends
    (`_wait`). A task reports its own failure as ``{"failure": "..."}``."""
    import submitit

    slurm = settings.cluster == "slurm"
    ex = executor(settings, folder, name)
    before = set(folder.iterdir()) if folder.is_dir() else None
    try:
        with contextlib.redirect_stderr(io.StringIO()):  # submitit prints sbatch's stderr as well
            tasks = ex.map_array(CheckedTask(task, installation()), jobs)
    except (submitit.core.utils.FailedJobError, submitit.core.utils.FailedSubmissionError, OSError) as exc:
        _remove_new(folder, before)
        message = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise UserError(f"--slurm: sbatch refused the array job: {message or type(exc).__name__}") from None
    array = tasks[0].job_id.split("_")[0] if slurm else " ".join(t.job_id for t in tasks)
    log.info("SLURM (%s): job %s, %d task(s); scripts and logs in %s", settings.cluster, array, len(tasks), folder)
    if not slurm:
        return _wait(tasks, jobs, POLL_S["local"])
    write_text_atomic(folder / JOB_RECORD, json.dumps({"job": array, "tasks": [t.job_id for t in tasks]}) + "\n")
    return _wait(tasks, jobs, POLL_S["slurm"], QueueWatch(array, settings.time_min * 60.0))


def _remove_new(folder: Path, before: set[Path] | None) -> None:
    """Remove what a refused submission left in ``folder`` (its script and pickled jobs): the
    files not in ``before``, and ``folder`` itself when it did not exist (``before`` None)."""
    for path in set(folder.iterdir()) - (before or set()) if folder.is_dir() else ():
        if path.is_file() or path.is_symlink():
            path.unlink()
    if before is None and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()


@dataclass
class QueueWatch:
    """An array's tasks as squeue shows them, without sacct: which are lost (`lost`), and
    whether cancelled ones have left the queue (`drain`)."""

    array: str
    #: a task's time limit, seconds
    limit_s: float
    clock: Callable[[], float] = time.monotonic
    #: task -> when squeue was first seen not listing it
    gone: dict[str, float] = field(default_factory=dict)
    #: task -> when squeue was first seen listing it as running
    running: dict[str, float] = field(default_factory=dict)

    def lost(self, pending: Iterable[str]) -> dict[str, str]:
        """Task id -> why it is lost, for the ``pending`` tasks (no result yet) that squeue
        has not listed for `LOST_MARGIN_S`, or has listed as running for longer than their
        time limit plus `LOST_MARGIN_S`. Nothing when squeue fails this time."""
        listed = queued(self.array)
        if listed is None:
            return {}
        now, lost = self.clock(), {}
        for task in pending:
            state = listed.get(task)
            if state is None:
                if now - self.gone.setdefault(task, now) >= LOST_MARGIN_S:
                    lost[task] = (f"its task {task} left the queue without a result (killed, out of memory or its node "
                                  "lost; without SLURM accounting the reason is in its log)")
                continue
            self.gone.pop(task, None)
            if state == "RUNNING" and now - self.running.setdefault(task, now) >= self.limit_s + LOST_MARGIN_S:
                lost[task] = (f"its task {task} is still listed as running {LOST_MARGIN_S:.0f} s past its time limit "
                              "without a result (its node lost?); cancelled")
        return lost

    def done(self, task: Any) -> bool:
        """Whether ``task`` left its result (submitit's ``done`` would ask sacct)."""
        return task.paths.result_pickle.exists()

    def drain(self) -> None:
        """After cancelling: wait until squeue lists none of the array's tasks, up to `DRAIN_S`."""
        deadline = self.clock() + DRAIN_S
        listed = queued(self.array)
        while listed and self.clock() < deadline:
            time.sleep(min(2.0, DRAIN_S))
            listed = queued(self.array)
        if listed is None:
            log.warning("SLURM: cannot tell whether the cancelled tasks of job %s have left the queue (squeue failed); "
                        "`squeue -j %s` shows them", self.array, self.array)
        elif listed:
            log.warning("SLURM: %d task(s) of job %s are still in the queue %.0f s after cancelling; "
                        "SLURM kills them at the latest after its KillWait (`scontrol show config | grep KillWait`), "
                        "and a rerun into this OUT is refused until `squeue -j %s` lists none",
                        len(listed), self.array, DRAIN_S, self.array)
        else:
            log.info("SLURM: the cancelled tasks of job %s have left the queue", self.array)


def _outcome(task: Any, job: Any, state: str) -> tuple[Any, Any, str | None]:
    """(job, result, failure) of a task that ended; ``state`` names how it ended."""
    try:
        result = task.result()
    except Exception:  # noqa: BLE001 - submitit's Failed/UncompletedJobError: no result came back
        return job, None, f"its task {task.job_id} ended without a result ({state}); log: {task.paths.stderr}"
    return (job, None, result["failure"]) if "failure" in result else (job, result, None)


def _wait(
    tasks: Sequence[Any], jobs: Sequence[Any], poll_s: float, watch: QueueWatch | None = None
) -> Iterator[tuple[Any, Any, str | None]]:
    """Yield (job, result, failure) as each submitit task ends (or, with ``watch``, is lost);
    an interrupted driver cancels the tasks still queued or running (and, with ``watch``,
    waits for them to leave the queue)."""
    pending = {task.job_id: (task, job) for task, job in zip(tasks, jobs, strict=True)}
    try:
        while pending:
            lost = watch.lost(list(pending)) if watch is not None else {}
            for job_id, (task, job) in list(pending.items()):
                if (watch.done(task) if watch is not None else task.done()):
                    del pending[job_id]
                    yield _outcome(task, job, "an error outside the seed's pipeline" if watch else task.state)
                elif job_id in lost:
                    del pending[job_id]
                    task.cancel(check=False)
                    yield job, None, f"{lost[job_id]}; log: {task.paths.stderr}"
            if pending:
                time.sleep(poll_s)
    finally:
        for task, _ in pending.values():
            task.cancel(check=False)
        if pending and watch is not None:
            watch.drain()
