"""The completion record of a run folder: proof that the files in it belong to one finished run.

A run deletes ``OUT/completed.json`` before it writes anything else and writes it anew as
its very last step. The record names the SHA-256 of the resolved scenario it ran
(``scenario.resolved.yaml``) and of every file it wrote for readers outside the pipeline
(``manifest.json``, ``results.json``, the PR curves, ...), by path relative to the folder::

    {"scenario": "<sha256 of scenario.resolved.yaml>", "files": {"results.json": "<sha256>", ...}}

A folder whose run was interrupted has no record; one whose files were replaced later (a
rerun with other settings killed half-way, a hand edit) has a record that no longer matches
them. `problem` says which, so readers such as `vitaplace aggregate` refuse such folders.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.outputs.checksum import digest

RECORD = "completed.json"
SCENARIO = "scenario.resolved.yaml"


def clear(out: Path) -> None:
    """Remove the record of an earlier run: from now on the folder is not finished."""
    (Path(out) / RECORD).unlink(missing_ok=True)


def write(out: Path, files: Iterable[Path]) -> None:
    """Write the record for ``out``'s resolved scenario and ``files`` (paths inside ``out``)."""
    out = Path(out)
    record = {
        "scenario": digest(out / SCENARIO),
        "files": {str(Path(f).relative_to(out)): digest(Path(f)) for f in sorted(files)},
    }
    write_text_atomic(out / RECORD, json.dumps(record, indent=2))


def problem(folder: Path, reads: Iterable[str]) -> str | None:
    """None when ``folder`` holds a finished run's record that matches its resolved scenario
    and each of ``reads`` (paths relative to the folder); else what is wrong, in words."""
    folder = Path(folder)
    path = folder / RECORD
    if not path.is_file():
        return f"no {RECORD}: its run did not finish (or a later run into it was interrupted)"
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return f"{RECORD} is unreadable ({type(exc).__name__})"
    files = record.get("files") if isinstance(record, dict) else None
    if not isinstance(files, dict) or not isinstance(record.get("scenario"), str):
        return f"{RECORD} is not a vitaplace completion record"
    if _digest(folder / SCENARIO) != record["scenario"]:
        return f"{SCENARIO} is not the scenario its finished run recorded in {RECORD} (a later run changed it?)"
    for name in reads:
        if name not in files:
            return f"{name} is not among the files its finished run recorded in {RECORD}"
        if _digest(folder / name) != files[name]:
            return f"{name} is not the file its finished run recorded in {RECORD} (changed or damaged since)"
    return None


def _digest(path: Path) -> str | None:
    """The file's digest, or None when it is not a readable file."""
    try:
        return digest(path) if path.is_file() else None
    except OSError:
        return None
