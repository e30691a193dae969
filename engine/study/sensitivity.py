"""`vitaplace sensitivity`: how the scores depend on the ground truth's tolerances, from the
matrices an evaluation saved (no re-simulation, no re-transform).

Each evaluation folder ``OUT/evaluations/ENV/METHOD/DIRECTION/`` keeps ``matrices.npz``:
the TME (the method's distances, queries x references), and the query and reference poses
(x, y, yaw) it was scored against. For every ground truth in a grid (`GRID`: revisit
tolerances τ in metres x heading tolerance, or position only), the ground-truth matrix is
rebuilt from the poses (`ground_truth_matrix`) and the TME scored by the evaluation's own
functions (`pr_curve`: ``max_f1``, ``recall_at_100_precision``; ``n_revisit`` the queries
with a true match). Each τ is given once and is below the diagonal of each evaluation's
arena (`check_taus`), as a scenario's ``scoring.tau`` must be. Both match directions are
scored where the run evaluated both (``scoring.direction: both``); the TME of one direction
is never transposed into the other, since a method's distance need not be symmetric.

Input: one finished run folder, or a sweep folder (its ``seed-*`` run folders), validated
as `vitaplace aggregate` validates them (`validate_run_folder`, then `one_scenario`: one
scenario, each seed once), each ``matrices.npz`` against the digest in ``completed.json``
too; a failed seed (the sweep's ``error.txt``) is left out with one line. Output, written atomically into the folder (or
``--out``): ``sensitivity.csv`` (one row per seed x environment x method x direction x τ x
heading tolerance), ``sensitivity.md`` (mean ± std over seeds with the percentile bootstrap
interval over seeds, `vitaplace.engine.study.summary.describe`) and ``sensitivity.json`` (both).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.inputs import tau_problem
from vitaplace.engine.config.scenario import ScoringSettings, SequenceSettings
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve
from vitaplace.engine.evaluation.sequence import sequence_scores
from vitaplace.engine.outputs.outdir import MATRICES, RESULTS_JSON, SEED_ERROR, arena_path, writable_dir
from vitaplace.engine.study.aggregate import RunFolder, check_recorded, curve_path, one_scenario, validate_run_folder
from vitaplace.engine.study.grid import check_once
from vitaplace.engine.study.summary import bounds, cell, csv_text, describe, interval, json_safe

#: revisit tolerances τ [m] of the default grid
TAUS = (0.2, 0.3, 0.5)
#: heading tolerance [deg] of the default grid beside position only (None): the scoring default
HEADING_TOLERANCE_DEG = ScoringSettings.model_fields["heading_tolerance_deg"].default
#: the scores recomputed per ground truth (both proportions in [0, 1])
METRICS = ("max_f1", "recall_at_100_precision")
log = logging.getLogger("vitaplace")

COLUMNS = ("seed", "environment", "method", "direction", "tau", "heading_tolerance_deg", "n_revisit", *METRICS)


class SensitivityError(UserError):
    """A folder whose saved evaluations cannot be rescored; the message names the file."""


def run_folders(folder: Path) -> tuple[list[RunFolder], dict[str, str]]:
    """(the validated run folders under ``folder``, seed folder name -> why for the failed seeds left out):
    ``folder`` itself when it is a run folder (it has ``results.json``), else its ``seed-*``
    subfolders (a sweep), which must hold one scenario, each seed once (`one_scenario`). A
    seed folder with the sweep's ``error.txt`` is a failed seed: left out with one log line."""
    folder = Path(folder)
    if (folder / RESULTS_JSON).is_file():
        return [validate_run_folder(folder)], {}
    seeds = sorted(p for p in folder.glob("seed-*") if p.is_dir())
    if not seeds:
        raise SensitivityError(f"{folder}: neither a run folder (no results.json) nor a sweep folder (no seed-*/)")
    failed: dict[str, str] = {}
    for path in seeds:
        if (path / SEED_ERROR).is_file():
            why = _last_line(path / SEED_ERROR)
            failed[path.name] = why
            log.error("%s failed, left out: %s (traceback in %s)", path.name, why, path / SEED_ERROR)
    runs = [validate_run_folder(p) for p in seeds if p.name not in failed]
    if not runs:
        raise SensitivityError(f"{folder}: every seed folder failed ({', '.join(failed)}); nothing to rescore")
    one_scenario(runs)
    return runs, failed


def _last_line(path: Path) -> str:
    """The last non-empty line of a text file (a traceback's exception), or why it cannot be read."""
    try:
        lines = path.read_text(errors="replace").strip().splitlines()
    except OSError as exc:
        return f"{path.name} unreadable ({exc.strerror or exc})"
    return lines[-1] if lines else f"{path.name} is empty"


def check_taus(runs: Sequence[RunFolder], taus: Sequence[float]) -> None:
    """SensitivityError naming --tau when a τ is not below the diagonal of an evaluation's arena
    (`tau_problem`: the check scenario validation makes of ``scoring.tau``), each arena as its run
    recorded it (``arenas/EVALUATION.json``, its digest in ``completed.json``). An evaluation of
    recorded runs has no arena, and no bound, as in a scenario."""
    for run in runs:
        for evaluation in dict.fromkeys(row.environment for row in run.rows):
            path = arena_path(run.folder, evaluation)
            if not path.is_file():
                continue
            check_recorded(run, [path.relative_to(run.folder).as_posix()])
            try:
                arena = json.loads(path.read_text())
                half_x, half_y, name = arena["width"] / 2, arena["depth"] / 2, str(arena["name"])
            except (OSError, UnicodeDecodeError, ValueError, TypeError, KeyError) as exc:
                raise SensitivityError(f"{path}: unreadable arena ({type(exc).__name__}: {exc})".splitlines()[0]) \
                    from None
            problem = next(filter(None, (tau_problem(tau, half_x, half_y, name) for tau in taus)), None)
            if problem:
                raise SensitivityError(f"--tau: {problem}")


def load_evaluation(path: Path, sequence_length: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(TME, query poses, reference poses) saved in one evaluation's ``matrices.npz``: a
    finite queries x references TME and finite (x, y, yaw) rows of each; else SensitivityError.
    With ``sequence_length``, the TME is the sequence score of that length (the other settings
    at their defaults) of the method's own distances (``distance``, saved when the evaluation
    matched sequences; else the TME itself)."""
    try:
        with np.load(path) as saved:
            names = set(saved.files)
            if {"query_poses", "reference_poses"} <= names:
                raw = "distance" if sequence_length is not None and "distance" in names else "tme"
                tme, query, reference = (np.asarray(saved[k], dtype=np.float64)
                                         for k in (raw, "query_poses", "reference_poses"))
    except Exception as exc:  # noqa: BLE001 - numpy/zipfile raise many kinds on a damaged file
        raise SensitivityError(f"{path}: unreadable matrices ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    if not {"query_poses", "reference_poses"} <= names:
        raise SensitivityError(
            f"{path}: no query_poses/reference_poses (saved since evaluate stage version 4); "
            "run the scenario again into the same folder to re-evaluate from the cache"
        )
    for name, poses in (("query_poses", query), ("reference_poses", reference)):
        if poses.ndim != 2 or poses.shape[1] != 3 or not np.isfinite(poses).all():
            raise SensitivityError(f"{path}: {name} of shape {poses.shape} (or not finite), expected finite N x 3 "
                                   "(x, y, yaw)")
    if tme.shape != (len(query), len(reference)) or not np.isfinite(tme).all():
        raise SensitivityError(f"{path}: tme of shape {tme.shape} (or not finite), expected a finite "
                               f"{len(query)} x {len(reference)} matrix (queries x references)")
    if sequence_length is not None:
        if sequence_length > len(query):
            raise SensitivityError(
                f"--sequence-length {sequence_length}: longer than the {len(query)} queries of {path}")
        tme = sequence_scores(tme, sequence_length, **SequenceSettings().model_dump(exclude={"length"}))
    return tme, query, reference


def rescore(tme: np.ndarray, query_poses: np.ndarray, reference_poses: np.ndarray, taus: Sequence[float],
            heading_tolerances: Sequence[float | None]) -> list[dict[str, Any]]:
    """One row per heading tolerance x τ: ``tau``, ``heading_tolerance_deg``, ``n_revisit``
    and `METRICS` of the TME against the ground truth rebuilt from the poses."""
    rows = []
    for heading in heading_tolerances:
        gtm = ground_truth_matrix(query_poses, reference_poses, heading)
        for tau in taus:
            curve = pr_curve(tme, gtm, tau)
            rows.append({"tau": float(tau), "heading_tolerance_deg": heading, "n_revisit": curve.n_revisit,
                         "max_f1": curve.max_f1, "recall_at_100_precision": curve.recall_at_full_precision})
    return rows


def sensitivity_rows(runs: Sequence[RunFolder], taus: Sequence[float] = TAUS,
                     heading_tolerances: Sequence[float | None] = (HEADING_TOLERANCE_DEG, None),
                     sequence_length: int | None = None) -> list[dict[str, Any]]:
    """`rescore` of every evaluation of every run (of its sequence scores, with
    ``sequence_length``: `load_evaluation`), tagged with seed, environment, method and
    direction, in seed order."""
    out = []
    for run in sorted(runs, key=lambda r: r.seed):
        for row in run.rows:
            name = str(Path(curve_path(row)).parent / MATRICES)
            path = run.folder / name
            if not path.is_file():
                raise SensitivityError(f"{path}: missing; the evaluation's matrices are needed")
            check_recorded(run, [name])
            identity = {"seed": run.seed, "environment": row.environment, "method": row.method,
                        "direction": row.direction}
            out += [{**identity, **scored} for scored in rescore(*load_evaluation(path, sequence_length), taus,
                                                                 heading_tolerances)]
    return out


def summarise(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per environment x method x direction x heading tolerance x τ x metric, `describe` of
    the values over seeds (intervals inside the metric's bounds)."""
    keys = ("environment", "method", "direction", "heading_tolerance_deg", "tau")
    groups: dict[tuple, list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    return [{**dict(zip(keys, key, strict=True)), "metric": metric,
             **describe([r[metric] for r in group], bounds(metric))}
            for key, group in groups.items() for metric in METRICS]


def _heading(value: float | None) -> str:
    return "position only" if value is None else f"≤ {value:g}°"


def markdown(summary: Sequence[Mapping[str, Any]], title: str) -> str:
    """sensitivity.md: one line per environment x method x direction x ground truth x τ."""
    lines = [f"# {title}", "",
             "Scores recomputed from each evaluation's saved matrices for other ground truths: revisit tolerance τ "
             "and heading tolerance (or position only). Mean ± sample standard deviation over seeds, percentile "
             "bootstrap 95 % interval of the mean over seeds (inside [0, 1]); n=1: one seed.", "",
             "| environment | method | direction | heading | τ (m) | metric | n | mean ± std | bootstrap 95 % |",
             "|" + " --- |" * 9]
    for r in summary:
        lines.append(f"| {r['environment']} | {r['method']} | {r['direction']} "
                     f"| {_heading(r['heading_tolerance_deg'])} "
                     f"| {r['tau']:g} | {r['metric']} | {r['n']} | {cell(r)} | {interval(r, 'boot')} |")
    return "\n".join(lines) + "\n"


def write_sensitivity(folder: Path, out: Path | None = None, taus: Sequence[float] = TAUS,
                      heading_tolerance_deg: float = HEADING_TOLERANCE_DEG,
                      sequence_length: int | None = None) -> tuple[Path, dict[str, Any]]:
    """Rescore every saved evaluation of the run or sweep ``folder`` (`sensitivity_rows`) and
    write sensitivity.csv, .md and .json into ``out`` (default ``folder``), atomically, after
    every folder was read (``out`` made and checked writable once the arguments and folders
    are known to be usable, before any rescoring). Returns (out, what sensitivity.json
    holds; its ``failed``: the failed seed folders left out, by name, with why)."""
    if not taus or any(not math.isfinite(t) or t <= 0 for t in taus):
        raise SensitivityError(f"--tau {' '.join(map(str, taus))}: expected positive distances in metres")
    check_once("--tau", [f"{tau:g}" for tau in taus], [float(tau) for tau in taus])
    if not 0 <= heading_tolerance_deg <= 180:
        raise SensitivityError(f"--heading-tolerance {heading_tolerance_deg}: expected degrees in [0, 180]")
    if sequence_length is not None and sequence_length < 1:
        raise SensitivityError(f"--sequence-length {sequence_length}: expected a whole number of queries >= 1")
    if not Path(folder).is_dir():
        raise SensitivityError(f"{folder}: not a folder; expected a finished run folder or a sweep folder (seed-*/)")
    runs, failed = run_folders(folder)
    check_taus(runs, taus)
    out = writable_dir(Path(folder) if out is None else Path(out))
    rows = sensitivity_rows(runs, taus, (heading_tolerance_deg, None), sequence_length)
    summary = summarise(rows)
    write_text_atomic(out / "sensitivity.csv", csv_text(rows, COLUMNS))
    seeds = sorted({r.seed for r in runs})
    matched = "" if sequence_length is None else f", sequences of {sequence_length} queries"
    write_text_atomic(out / "sensitivity.md",
                      markdown(summary, f"{runs[0].scenario}: sensitivity, {len(seeds)} seed(s){matched}"))
    record = {"scenario": runs[0].scenario, "seeds": seeds, "taus": list(taus),
              "heading_tolerances_deg": [heading_tolerance_deg, None], "sequence_length": sequence_length,
              "failed": failed, "rows": rows,
              "summary": summary}
    write_text_atomic(out / "sensitivity.json", json.dumps(json_safe(record), indent=2))
    return out, record
