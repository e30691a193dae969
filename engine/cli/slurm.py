"""Sweep jobs on SLURM through submitit: one array job per sweep, one array task per seed.

The driver (`vitaplace sweep --slurm`) pickles each seed's job into ``OUT/slurm``, submits
one ``sbatch`` array whose tasks run `run_seed_reported` on the nodes, and waits for them;
each task's stdout and stderr land in ``OUT/slurm`` too. A seed whose task fails (an error in
the pipeline, a time limit, a node lost) is reported in one line; the summary is built from
the seeds that finished, as for local and Ray sweeps. ``--slurm local`` runs the same array
through submitit's local executor: each task a process on this machine (for trying a sweep
out, and for the tests).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vitaplace.engine.base.errors import UserError

log = logging.getLogger("vitaplace")

#: sbatch options with an option of their own in `vitaplace sweep`
OWN_OPTIONS = {"partition": "--partition", "time": "--time", "mem": "--mem", "cpus-per-task": "--cpus-per-job",
               "gpus-per-node": "--gpus-per-job", "array": "(one array per sweep)",
               "output": "(logs go to OUT/slurm)", "error": "(logs go to OUT/slurm)"}
#: sbatch's --time formats: M, M:S, H:M:S, D-H, D-H:M, D-H:M:S
TIME = re.compile(r"^(?:(?P<days>\d+)-(?P<dh>\d+)(?::(?P<dm>\d+)(?::(?P<ds>\d+))?)?|(?P<a>\d+)(?::(?P<b>\d+)(?::(?P<c>\d+))?)?)$")
#: seconds between checks of the array's state (submitit caches sacct between them)
POLL_S = {"slurm": 15.0, "local": 0.5}


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


def parse_time(text: str) -> int:
    """sbatch's ``--time`` (minutes, M:S, H:M:S, D-H, D-H:M or D-H:M:S) in whole minutes, rounded up."""
    match = TIME.match(text.strip())
    if match is None:
        raise UserError(f"--time {text}: expected a time limit as sbatch reads it: MINUTES, HH:MM:SS or DAYS-HH[:MM[:SS]]")
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
    own = {"--partition": args.partition, "--time": args.time, "--mem": args.mem, "--sbatch": args.sbatch}
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
    return SlurmSettings(args.slurm, parse_time(args.time), int(args.cpus_per_job), int(args.gpus_per_job),
                         args.partition, args.mem, parse_sbatch(args.sbatch))


def executor(settings: SlurmSettings, folder: Path, name: str) -> Any:
    """A submitit executor for ``settings`` that keeps its scripts, pickles and logs in ``folder``."""
    try:
        import submitit
    except ImportError:
        raise UserError("--slurm needs the optional dependency: pip install 'vitaplace[slurm]'") from None
    try:
        ex = submitit.AutoExecutor(folder=folder, cluster=settings.cluster)
    except RuntimeError as exc:  # no srun/sbatch on this machine
        raise UserError(f"--slurm: {' '.join(str(exc).split())} (--slurm local runs the tasks on this machine)") from None
    extra = {**({"mem": settings.mem} if settings.mem else {}), **settings.sbatch}
    ex.update_parameters(
        name=name, timeout_min=settings.time_min, cpus_per_task=settings.cpus, gpus_per_node=settings.gpus,
        nodes=1, tasks_per_node=1, slurm_partition=settings.partition, slurm_additional_parameters=extra or None,
    )
    return ex


def run_array(
    task: Callable[[Any], dict[str, Any]], jobs: Sequence[Any], settings: SlurmSettings, folder: Path, name: str
) -> Iterator[tuple[Any, Any, str | None]]:
    """Submit ``task(job)`` for each of ``jobs`` (a sweep's `run_seed_reported` over its
    `SeedJob`s) as one array now; the iterator returned yields (job, result, failure) as each
    task ends (`_wait`). A task reports its own failure as ``{"failure": "..."}``."""
    tasks = executor(settings, folder, name).map_array(task, jobs)
    array = tasks[0].job_id.split("_")[0] if settings.cluster == "slurm" else " ".join(t.job_id for t in tasks)
    log.info("SLURM (%s): job %s, %d task(s); scripts and logs in %s", settings.cluster, array, len(tasks), folder)
    return _wait(tasks, jobs, POLL_S[settings.cluster])


def _wait(tasks: Sequence[Any], jobs: Sequence[Any], poll_s: float) -> Iterator[tuple[Any, Any, str | None]]:
    """Yield (job, result, failure) as each submitit task ends; an interrupted driver cancels
    the tasks still queued or running."""
    import submitit

    by_id = {task.job_id: job for task, job in zip(tasks, jobs)}
    ended: set[str] = set()
    try:
        for task in submitit.helpers.as_completed(tasks, poll_frequency=poll_s):
            ended.add(task.job_id)
            job = by_id[task.job_id]
            try:
                result = task.result()
            except Exception:  # noqa: BLE001 - submitit's Failed/UncompletedJobError: no result came back
                yield job, None, f"its task {task.job_id} ended without a result ({task.state}); log: {task.paths.stderr}"
                continue
            yield (job, None, result["failure"]) if "failure" in result else (job, result, None)
    finally:
        for task in tasks:
            if task.job_id not in ended:
                task.cancel(check=False)
