"""The output directory a run writes to: its layout, checked writable up front, locked
against a second run, and cleared of temporaries an interrupted run left behind.

Layout (every path relative to OUT): ``results.json``/``results.csv``, ``complementarity.json``,
``manifest.json``,
``report.md`` with ``figures/``, per evaluation x method x direction
``evaluations/ENV/METHOD/DIRECTION/`` (`evaluation_dir`), and what the report reads besides:
``poses/ENV.npz`` (the evaluation's query and reference poses), ``arenas/ENV.json`` (its
environment's top view, for simulated evaluations) and ``training/METHOD.json`` (the
method's per-epoch training curves, for methods that record them).

The lock is an advisory ``flock`` on ``OUT/.vitaplace.lock`` holding the owner's pid: the
operating system releases it when the owner exits, even by ``kill -9``, so a stale lock
never blocks. A second run into the same directory stops at once with exit status 2 and the
holder's pid (where ``fcntl`` is missing, e.g. Windows, runs are not locked).
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import TextIO

from vitaplace.engine.base.errors import UserError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = ".vitaplace.lock"


class OutputDirError(UserError):
    """An output folder (``--out``; ``out`` in the Python API) cannot hold the results, or
    another run holds it."""


def writable_dir(out: Path, option: str = "--out") -> Path:
    """``out`` as a directory that exists and can be written, or OutputDirError saying why
    (naming it as ``option``, the command line's or the API's name of it)."""
    if out.exists() and not out.is_dir():
        raise OutputDirError(f"{option} {out}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".vitaplace-write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise OutputDirError(f"{option} {out}: cannot write there ({exc.strerror or exc})") from None
    return out


def remove_stale_temporaries(out: Path) -> list[Path]:
    """Delete what interrupted atomic writes left under ``out`` (``.NAME.*.part`` files and
    ``.NAME.*`` folders beside their target); call only while holding the lock."""
    removed = []
    for path in sorted(out.rglob(".*"), reverse=True):
        if path.name == LOCK_NAME or path.name.startswith(".vitaplace-write-test"):
            continue
        if path.is_file() and path.name.endswith(".part"):
            path.unlink(missing_ok=True)
            removed.append(path)
        elif path.is_dir() and path.parent.name == "models":
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


class OutputLock:
    """``with OutputLock(out):`` holds ``out`` for this process, or raises OutputDirError
    naming it as ``option``."""

    def __init__(self, out: Path, option: str = "--out") -> None:
        self.path = Path(out) / LOCK_NAME
        self.option = option
        self._file: TextIO | None = None

    def __enter__(self) -> OutputLock:
        if fcntl is None:
            return self
        self._file = open(self.path, "a+")  # noqa: SIM115 - held for the lock's lifetime
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._file.seek(0)
            holder = self._file.read().strip() or "unknown"
            self._file.close()
            self._file = None
            raise OutputDirError(
                f"{self.option} {self.path.parent}: another vitaplace run (pid {holder}) is writing there; "
                f"wait for it to finish or choose another {self.option}"
            ) from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(str(os.getpid()))
        self._file.flush()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._file is not None:
            fcntl.flock(self._file, fcntl.LOCK_UN)
            self._file.close()
            self._file = None


# ---------------------------------------------------------------------------- layout
# What a run writes into its output folder OUT, and where; every module that reads or writes
# these files names them through here.
#
#   OUT/manifest.json, results.json, results.csv, complementarity.json, report.md, figures/,
#       completed.json, scenario.resolved.yaml
#   OUT/evaluations/ENV/METHOD/DIRECTION/summary.json, pr_curve.npz, decisions.npz,
#       decisions.csv, matrices.npz
#   OUT/cache/datasets/LABEL-KEY.h5, models/METHOD-KEY/, models/METHOD-KEY.training.json,
#       features/METHOD-LABEL-KEY.npz           (a sweep shares one cache: OUT/cache)
#   OUT/poses/ENV.npz, arenas/ENV.json, training/METHOD.json (what the report reads besides)
#   OUT/difficulty/ (`vitaplace difficulty --out OUT`: a run folder of its own, OUT/cache its cache)
#   sweep OUT/seed-S/ (one run folder per seed, with error.txt when it failed),
#       seed-S/environments/ (the environment files the seed's scenario names)

MANIFEST = "manifest.json"
#: the completion record a command writes last into a folder it finished
#: (`vitaplace.engine.outputs.completion`)
COMPLETED = "completed.json"
RESULTS_JSON = "results.json"
RESULTS_CSV = "results.csv"
#: per evaluation, direction and vision-only / touch-only pair: what touch rescues
COMPLEMENTARITY = "complementarity.json"
REPORT = "report.md"
FIGURES = "figures"
#: in an evaluation folder (`evaluation_dir`)
SUMMARY = "summary.json"
PR_CURVE = "pr_curve.npz"
DECISIONS = "decisions.npz"
DECISIONS_CSV = "decisions.csv"
MATRICES = "matrices.npz"
#: in a sweep's seed folder (`seed_dir`): the traceback of a failed seed
SEED_ERROR = "error.txt"


def evaluation_dir(out: Path, environment: str, method: str, direction: str) -> Path:
    """The folder of one evaluation: ``environment`` scored with ``method`` in ``direction``."""
    return Path(out) / "evaluations" / environment / method / direction


def cache_dir(out: Path) -> Path:
    """The stage cache of the run (or sweep) writing into ``out``."""
    return Path(out) / "cache"


def dataset_file(cache: Path, label: str, key: str) -> Path:
    """A simulated run ``label`` (``train``, ``E1/query``) made for ``key``."""
    return Path(cache) / "datasets" / f"{label.replace('/', '-')}-{key}.h5"


def model_dir(cache: Path, method: str, key: str) -> Path:
    """The fitted extractor of ``method`` made for ``key``."""
    return Path(cache) / "models" / f"{method}-{key}"


def training_file(model: Path) -> Path:
    """How training of the model in ``model`` (a `model_dir`) went, beside it."""
    return model.with_name(model.name + ".training.json")


def features_file(cache: Path, method: str, label: str, key: str) -> Path:
    """The features ``method`` extracted from run ``label``, made for ``key``."""
    return Path(cache) / "features" / f"{method}-{label.replace('/', '-')}-{key}.npz"


def difficulty_dir(out: Path) -> Path:
    """The folder `vitaplace difficulty --out OUT` writes (its stage cache: ``OUT``'s, `cache_dir`)."""
    return Path(out) / "difficulty"


def seed_dir(out: Path, seed: int) -> Path:
    """The run folder of ``seed`` in a sweep's output folder ``out``."""
    return Path(out) / f"seed-{seed}"


def poses_path(out: Path, environment: str) -> Path:
    """The ``query`` and ``reference`` poses of evaluation ``environment`` (an ``.npz``)."""
    return Path(out) / "poses" / f"{environment}.npz"


def arena_path(out: Path, environment: str) -> Path:
    """The top view (JSON) of the environment of evaluation ``environment``."""
    return Path(out) / "arenas" / f"{environment}.json"


def training_path(out: Path, method: str) -> Path:
    """The per-epoch training curves (JSON) of ``method``."""
    return Path(out) / "training" / f"{method}.json"


def refuse_foreign(out: Path, marks: Sequence[str] = (), option: str = "--out") -> None:
    """OutputDirError for a folder that holds files but none of vitaplace's marks: `LOCK_NAME`
    (which every claim leaves) or one of ``marks`` (the file a command that writes without a
    claim leaves, e.g. ``sweep.json``): a project folder, the current one, a run's subfolder."""
    out = Path(out)
    if out.is_dir() and any(out.iterdir()) and not any((out / mark).exists() for mark in (LOCK_NAME, *marks)):
        raise OutputDirError(f"{option} {out}: not empty and not a folder vitaplace wrote (no {LOCK_NAME}); expected "
                             "a new or empty folder, or one a vitaplace command wrote")


@contextmanager
def claimed(out: Path, before_cleaning: Callable[[Path], None] | None = None,
            option: str = "--out") -> Iterator[Path]:
    """``with claimed(out) as out:`` - the one way a command or the Python API takes an output
    folder: ``out`` made a writable directory (`writable_dir`), held by this process
    (`OutputLock`, else OutputDirError), then ``before_cleaning(out)`` if given (the command
    line's log file) and what interrupted writes left removed, each logged. A folder that
    holds files but neither `LOCK_NAME` (which every claim leaves) nor a stage cache (one
    copied in to be reused) nor `COMPLETED` (a finished folder written under another's claim,
    e.g. a sweep's seed folder under the sweep's) is no folder of vitaplace's: refused
    untouched, since a run prunes the result folders it finds there. Errors name the folder as
    ``option`` (the API: ``out``)."""
    out = Path(out)
    refuse_foreign(out, (*(f"cache/{stage}" for stage in ("datasets", "models", "features")), COMPLETED), option)
    out = writable_dir(out, option)
    with OutputLock(out, option):
        if before_cleaning is not None:
            before_cleaning(out)
        for path in remove_stale_temporaries(out):
            logging.getLogger("vitaplace").info("removed %s, left by an interrupted run", path)
        yield out
