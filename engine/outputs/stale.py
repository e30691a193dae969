"""One set of results per output folder: what a run of a scenario's stages carries on to, and
what it removes, so that no file in its folder describes other results than the rest.

* A run carries on to every later stage whose output the folder holds (`held_stage`):
  ``vitaplace evaluate`` into a folder with a report remakes the report (cached when the
  results did not change), ``vitaplace train`` into one with results re-evaluates.
* When it has finished, it removes the outputs no stage of it wrote (`prune`): the
  evaluations, poses, world views and training curves of evaluations and methods the
  scenario no longer has, and the report's figures are drawn anew whenever the report is.
* The rescoring ``vitaplace sensitivity`` wrote into the folder stays only while the
  evaluations it rescored are unchanged (`drop_sensitivity`); a sweep's, until the sweep
  writes its summaries again (`drop_sweep_sensitivity`).
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path

from vitaplace.engine.outputs import outdir

#: what ``vitaplace sensitivity`` writes into the folder it rescores (by default)
SENSITIVITY = ("sensitivity.csv", "sensitivity.md", "sensitivity.json")
#: the result files directly in the folder (the rest are in `_AREAS`)
_TOP = (outdir.RESULTS_JSON, outdir.RESULTS_CSV, outdir.COMPLEMENTARITY, outdir.REPORT)
#: the folders of what the evaluate and report stages write per evaluation or method
_AREAS = ("evaluations", "poses", "arenas", "training")


def held_stage(out: Path) -> str | None:
    """The latest stage whose output ``out`` holds: ``report`` (report.md), ``evaluate``
    (results.json), else None."""
    out = Path(out)
    if (out / outdir.REPORT).is_file():
        return "report"
    return "evaluate" if (out / outdir.RESULTS_JSON).is_file() else None


def prune(out: Path, keep: Iterable[Path]) -> list[Path]:
    """Remove from ``out`` every result file (`_TOP`, and under `_AREAS`) that is not in
    ``keep`` nor inside a kept evaluation's folder (`outdir.evaluation_dir`), with an
    evaluation folder's seal; the figures go with a report that is not kept. Returns what
    was removed."""
    out = Path(out)
    kept = {Path(p) for p in keep}
    removed = _unkept(out, kept)
    for path in removed:
        path.unlink()
    if out / outdir.REPORT not in kept and (out / outdir.FIGURES).is_dir():
        shutil.rmtree(out / outdir.FIGURES)
        removed.append(out / outdir.FIGURES)
    for area in _areas(out):  # the folders left empty, deepest first
        for folder in [*sorted(area.rglob("*"), reverse=True), area]:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
    return removed


def _areas(out: Path) -> list[Path]:
    """The `_AREAS` folders ``out`` has."""
    return [out / name for name in _AREAS if (out / name).is_dir()]


def _unkept(out: Path, kept: set[Path]) -> list[Path]:
    """The result files in ``out`` that `prune` removes (the figures aside)."""
    evaluations = {p.parent for p in kept if p.parent.parent.parent.parent == out / "evaluations"}
    found = [p for p in (out / name for name in _TOP) if p.is_file() and p not in kept]
    for area in _areas(out):
        found += [p for p in sorted(area.rglob("*")) if p.is_file() and p not in kept and not _belongs(p, evaluations)]
    return found


def _belongs(path: Path, evaluations: set[Path]) -> bool:
    """Whether ``path`` is in one of the ``evaluations`` folders or is one's seal."""
    return any(path.is_relative_to(folder) or path.name.startswith(folder.name + ".") and path.parent == folder.parent
               for folder in evaluations)


def _evaluations(files: Mapping[str, str]) -> dict[str, str]:
    """The evaluation files among a completion record's ``files``."""
    return {name: sha for name, sha in files.items() if name.startswith("evaluations/")}


def drop_sensitivity(out: Path, before: Mapping[str, str], after: Mapping[str, str]) -> list[Path]:
    """Remove ``vitaplace sensitivity``'s files from ``out`` unless the evaluations it
    rescored are the same: the same evaluation folders, each file both records list with the
    same digest (``before`` and ``after``: the completion records' files, path -> SHA-256, of
    the finished run before and of this one). Returns what was removed."""
    old, new = (_evaluations(files) for files in (before, after))
    if old and {Path(n).parent for n in old} == {Path(n).parent for n in new} and all(
            old[name] == new[name] for name in old.keys() & new.keys()):
        return []
    removed = [p for p in (Path(out) / name for name in SENSITIVITY) if p.is_file()]
    for path in removed:
        path.unlink()
    return removed


def drop_sweep_sensitivity(out: Path, points: Iterable[str]) -> list[Path]:
    """Remove ``vitaplace sensitivity``'s files from the sweep folder ``out`` and its grid
    points' folders (``points``, their names; "" the folder itself), which a sweep that wrote
    its summaries anew may no longer match (other seeds, or another scenario). Returns what was
    removed."""
    folders = {Path(out) / name for name in points} | {Path(out)}
    removed = [p for folder in sorted(folders) for p in (folder / name for name in SENSITIVITY) if p.is_file()]
    for path in removed:
        path.unlink()
    return removed

