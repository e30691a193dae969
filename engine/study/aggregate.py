"""`vitaplace aggregate`: the sweep summary from run folders made by independent jobs.

Each folder is the output of one ``vitaplace run --set seed=N --out DIR`` (or a sweep's
``seed-N``). `validate_run_folder` accepts a folder only when its completion record
(``completed.json``, written last by the run) matches its ``scenario.resolved.yaml`` and
every file read (``manifest.json``, ``results.json``, each row's ``pr_curve.npz``), and
every result row is well formed (`vitaplace.engine.outputs.rows.ResultRow`). Folders must hold one scenario: the same
name in the manifest and the same resolved scenario apart from its seed (environment files
compared by file name, since a sweep job keeps its own copies), and each seed once. Nothing
is written before every folder passed.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.base.cpus import usable_cpus
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.scenario import RENAMED_KEYS
from vitaplace.engine.evaluation.pairfiles import load_curve
from vitaplace.engine.outputs import completion
from vitaplace.engine.outputs.keys import content_hash
from vitaplace.engine.outputs.outdir import COMPLETED, MANIFEST, MATRICES, RESULTS_JSON, writable_dir
from vitaplace.engine.outputs.rows import ResultRow, parse_row
from vitaplace.engine.report.figures import write_pr_bands
from vitaplace.engine.study.summary import write_summary

REQUIRED = (COMPLETED, MANIFEST, RESULTS_JSON, completion.SCENARIO)


class AggregateError(UserError):
    """Run folders that cannot be summarised together; the message names the folder or file."""


@dataclass
class RunFolder:
    """The validated content of one finished run folder."""

    folder: Path
    seed: int
    scenario: str  #: the scenario's name in the manifest
    identity: str  #: `scenario_identity` of its resolved scenario
    rows: list[ResultRow]  #: its result rows

    def tagged(self) -> list[dict[str, Any]]:
        """Its rows as the summary reads them: each row's fields, then ``seed``."""
        return [{**row.dump(), "seed": self.seed} for row in self.rows]


def scenario_identity(resolved: dict[str, Any]) -> str:
    """A hash of the resolved scenario without its seed, environments by file name, keys
    under their current names (a folder written before a key's rename matches one after)."""
    data = copy.deepcopy({RENAMED_KEYS.get(k, k): v for k, v in resolved.items() if k != "seed"})
    for key in ("train", "evaluations"):
        entries = data.get(key)
        entries = entries if isinstance(entries, list) else [entries]
        for entry in entries:
            if isinstance(entry, dict) and isinstance(entry.get("environment"), str):
                entry["environment"] = Path(entry["environment"]).name
    return content_hash(data)


def _read(folder: Path, name: str, parse: Callable[[str], Any]) -> Any:
    try:
        return parse((folder / name).read_text())
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
        raise AggregateError(f"{folder / name}: unreadable ({type(exc).__name__}: {exc})".splitlines()[0]) from None


def curve_path(row: ResultRow) -> str:
    """Where a run folder keeps the PR curve of a result row (relative to the folder)."""
    return f"evaluations/{row.environment}/{row.method}/{row.direction}/pr_curve.npz"


def validate_run_folder(folder: Path) -> RunFolder:
    """Everything `vitaplace aggregate` reads from one run folder, validated: a completion
    record (`vitaplace.engine.outputs.completion`) that matches the resolved scenario, the manifest,
    the results and every row's PR curve; each result row parsed (`parse_row`). Raises
    AggregateError, one line naming the folder or the file (and field) at fault."""
    folder = Path(folder)
    missing = [name for name in REQUIRED if not (folder / name).is_file()]
    if missing:
        raise AggregateError(f"{folder}: incomplete run folder (no {', '.join(missing)}); did its run finish?")
    wrong = completion.problem(folder, [MANIFEST, RESULTS_JSON])
    if wrong:
        raise AggregateError(f"{folder}: not a finished run: {wrong}")
    manifest = _read(folder, MANIFEST, json.loads)
    rows = _read(folder, RESULTS_JSON, json.loads)
    resolved = _read(folder, completion.SCENARIO, yaml.safe_load)
    if (not isinstance(manifest, dict) or not isinstance(manifest.get("seed"), int)
            or isinstance(manifest["seed"], bool)):
        raise AggregateError(
            f"{folder / 'manifest.json'}: field 'seed' missing or not an integer; not a vitaplace run's")
    if not isinstance(manifest.get("scenario"), str):
        raise AggregateError(f"{folder / 'manifest.json'}: field 'scenario' missing or not text; not a vitaplace run's")
    if not isinstance(resolved, dict):
        raise AggregateError(f"{folder / completion.SCENARIO}: not a scenario mapping")
    if not isinstance(rows, list) or not rows:
        raise AggregateError(f"{folder / 'results.json'}: holds no result rows, expected a non-empty list")
    rows = [parse_row(row, f"{folder / 'results.json'}: row {i}", AggregateError) for i, row in enumerate(rows)]
    curves = [curve_path(row) for row in rows]
    wrong = completion.problem(folder, curves)
    if wrong:
        raise AggregateError(f"{folder}: not a finished run: {wrong}")
    for name in curves:
        try:
            load_curve(folder / name)
        except Exception as exc:  # noqa: BLE001 - numpy/zipfile raise many kinds on a damaged file
            raise AggregateError(
                f"{folder / name}: unreadable PR curve ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    seed = manifest["seed"]
    return RunFolder(folder, seed, manifest["scenario"], scenario_identity(resolved), rows)


def one_scenario(runs: Sequence[RunFolder]) -> dict[int, Path]:
    """Seed -> folder of ``runs`` (validated run folders) when they hold one scenario (the
    same name, the same `scenario_identity`) and each seed once; else AggregateError naming
    the folder at fault. The one check of a set of run folders (aggregate, sensitivity)."""
    seen: dict[int, Path] = {}
    for run in runs:
        if run.scenario != runs[0].scenario or run.identity != runs[0].identity:
            raise AggregateError(
                f"{run.folder}: scenario '{run.scenario}' differs from {runs[0].folder}'s '{runs[0].scenario}' "
                "(beyond the seed); only runs of one scenario go together"
            )
        if run.seed in seen:
            raise AggregateError(f"{run.folder}: seed {run.seed} again (also {seen[run.seed]})")
        seen[run.seed] = run.folder
    return seen


def check_recorded(run: RunFolder, names: Sequence[str]) -> None:
    """AggregateError unless each of ``names`` (paths in the run folder) is a file its
    completion record names with the digest it has now."""
    wrong = completion.problem(run.folder, names)
    if wrong:
        raise AggregateError(f"{run.folder}: not a finished run: {wrong}")


def written_matrices(run: RunFolder) -> list[str]:
    """The ``matrices.npz`` of ``run``'s evaluations that its run wrote or its record names: a
    pair over `FULL_MATRIX_LIMIT` has none (its bootstrap intervals are NaN), one deleted since
    the run is named by the record and found missing."""
    recorded = completion.files_of(run.folder)
    names = [str(Path(curve_path(row)).parent / MATRICES) for row in run.rows]
    return [name for name in names if name in recorded or (run.folder / name).exists()]


def aggregate_runs(folders: Sequence[Path], out: Path | None = None) -> tuple[Path, dict[str, Any]]:
    """Check that ``folders`` are finished runs of one scenario with distinct seeds
    (`validate_run_folder`, every folder before anything is written) and write their summary
    into ``out`` (default: their common parent folder). Returns (out, sweep.json)."""
    runs = [validate_run_folder(Path(f)) for f in folders]
    first = runs[0]
    seen = one_scenario(runs)
    for run in runs:  # the block bootstrap reads each evaluation's matrices: as the run left them
        check_recorded(run, written_matrices(run))
    if out is None:
        parents = {run.folder.resolve().parent for run in runs}
        if len(parents) != 1:
            raise AggregateError("the run folders are in different parent folders: give --out")
        out = parents.pop()
    out = writable_dir(Path(out))
    rows = [row for run in runs for row in run.tagged()]
    info = {"scenario": first.scenario, "seeds": sorted(seen), "failed": {},
            "folders": {str(s): str(f) for s, f in sorted(seen.items())}}
    record = write_summary(out, rows, f"{first.scenario}: {len(seen)} seed(s)", info, seen, usable_cpus())
    write_pr_bands(out, seen, rows)
    return out, record
