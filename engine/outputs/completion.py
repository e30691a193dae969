"""The completion record of a run folder: proof that the files in it belong to one finished run.

A run deletes ``OUT/completed.json`` just before its first write into the folder itself (its
stages before that write only into the cache, so a command that fails there leaves a
finished folder as it was) and writes it anew as its very last step. The record names the
SHA-256 of the resolved scenario it ran (``scenario.resolved.yaml``) and of every file it
wrote for readers outside the pipeline (``manifest.json``, ``results.json``, the PR curves,
...), by path relative to the folder::

    {"scenario": "<sha256 of scenario.resolved.yaml>", "command": "run", "files": {"results.json": "<sha256>", ...}}

A folder whose run was interrupted has no record; one whose files were replaced later (a
rerun with other settings killed half-way, a hand edit) has a record that no longer matches
them. `problem` says which, so readers such as `vitaplace aggregate` refuse such folders.

``command`` is the kind of command that finished the folder (`KINDS`; records without one
are runs'): with the summaries a sweep or ``vitaplace aggregate`` writes, it says whose
finished output a folder holds (`holder`), and a command refuses a folder holding another
kind's (`refuse_other`): no command writes its results into another one's.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.outputs.checksum import digest
from vitaplace.engine.outputs.outdir import COMPLETED, OutputDirError

SCENARIO = "scenario.resolved.yaml"
#: the kinds of finished output a folder can hold, as a refusal names them
KINDS = {
    "run": "a run of a scenario's stages (`vitaplace run`, `simulate`, `train`, `evaluate`, `report`)",
    "difficulty": "`vitaplace difficulty`",
    "summary": "the summary of `vitaplace sweep` or `vitaplace aggregate`",
}
#: the files that make a folder a summary's (a sweep's or an aggregate's)
SUMMARIES = ("sweep.json", "grid.json")


def clear(out: Path) -> None:
    """Remove the record of an earlier run: from now on the folder is not finished."""
    (Path(out) / COMPLETED).unlink(missing_ok=True)


def write(out: Path, files: Iterable[Path], command: str = "run") -> None:
    """Write the record for ``out``'s resolved scenario and ``files`` (paths inside ``out``),
    made by a command of kind ``command`` (`KINDS`)."""
    out = Path(out)
    record = {
        "scenario": digest(out / SCENARIO),
        "command": command,
        "files": digests(out, files),
    }
    write_text_atomic(out / COMPLETED, json.dumps(record, indent=2))


def digests(out: Path, files: Iterable[Path]) -> dict[str, str]:
    """The SHA-256 of each of ``files`` (paths inside ``out``), by path relative to ``out``."""
    return {str(Path(f).relative_to(out)): digest(Path(f)) for f in sorted(files)}


def problem(folder: Path, reads: Iterable[str]) -> str | None:
    """None when ``folder`` holds a finished run's record that matches its resolved scenario
    and each of ``reads`` (paths relative to the folder); else what is wrong, in words."""
    folder = Path(folder)
    path = folder / COMPLETED
    if not path.is_file():
        return f"no {COMPLETED}: its run did not finish (or a later run into it was interrupted)"
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return f"{COMPLETED} is unreadable ({type(exc).__name__})"
    files = record.get("files") if isinstance(record, dict) else None
    if not isinstance(files, dict) or not isinstance(record.get("scenario"), str):
        return f"{COMPLETED} is not a vitaplace completion record"
    if _digest(folder / SCENARIO) != record["scenario"]:
        return f"{SCENARIO} is not the scenario its finished run recorded in {COMPLETED} (a later run changed it?)"
    for name in reads:
        if name not in files:
            return f"{name} is not among the files its finished run recorded in {COMPLETED}"
        if _digest(folder / name) != files[name]:
            return f"{name} is not the file its finished run recorded in {COMPLETED} (changed or damaged since)"
    return None


def files_of(folder: Path) -> dict[str, str]:
    """The files (relative path -> SHA-256) ``folder``'s completion record lists; none when
    it has no readable record."""
    files = _read_record(folder).get("files")
    return dict(files) if isinstance(files, dict) else {}


def holder(folder: Path) -> str | None:
    """The kind (`KINDS`) of finished output ``folder`` holds: ``summary`` when it holds a
    summary's files, else the command its completion record names; None when it holds no
    finished output (an interrupted command's leaves any command free to write there)."""
    folder = Path(folder)
    if any((folder / name).is_file() for name in SUMMARIES):
        return "summary"
    record = _read_record(folder)
    if not record:
        return None
    command = record.get("command", "run")
    return command if command in KINDS else "run"


def refuse_other(folder: Path, kind: str, option: str = "--out") -> None:
    """OutputDirError naming ``option`` when ``folder`` holds the finished output of a kind
    other than ``kind`` (`holder`): a kind of `KINDS`, or the words naming a command that
    finishes no folder of its own (`vitaplace simulate ENV.yaml`'s run file), which any
    finished output refuses."""
    held = holder(folder)
    if held is not None and held != kind:
        raise OutputDirError(f"{option} {folder}: holds the finished output of {KINDS[held]}, which "
                             f"{KINDS.get(kind, kind)} would mix its own into; choose another {option}")


def _read_record(folder: Path) -> dict[str, Any]:
    """``folder``'s completion record as read, or an empty one when it has none readable."""
    try:
        record = json.loads((Path(folder) / COMPLETED).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def _digest(path: Path) -> str | None:
    """The file's digest, or None when it is not a readable file."""
    try:
        return digest(path) if path.is_file() else None
    except OSError:
        return None
