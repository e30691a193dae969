"""`vitaplace sensitivity`: how the scores depend on the ground truth's tolerances, from the
matrices an evaluation saved (no re-simulation, no re-transform).

Each evaluation folder ``OUT/evaluations/ENV/METHOD/DIRECTION/`` keeps ``matrices.npz``:
the TME (the method's distances, queries x references), and the query and reference poses
(x, y, yaw) it was scored against. For every ground truth in a grid (`GRID`: revisit
tolerances τ in metres x heading tolerance, or position only), the ground-truth matrix is
rebuilt from the poses (`ground_truth_matrix`) and the TME scored by the evaluation's own
functions (`pr_curve`: ``max_f1``, ``recall_at_100_precision``; ``n_revisit`` the queries
with a true match). Both match directions are scored where the run evaluated both
(``scoring.direction: both``); the TME of one direction is never transposed into the
other, since a method's distance need not be symmetric.

Input: one finished run folder, or a sweep folder (its ``seed-*`` run folders, each
validated as `vitaplace aggregate` does). Output, written atomically into the folder (or
``--out``): ``sensitivity.csv`` (one row per seed x environment x method x direction x τ x
heading tolerance), ``sensitivity.md`` (mean ± std over seeds with the percentile bootstrap
interval over seeds, `vitaplace.engine.study.summary.describe`) and ``sensitivity.json`` (both).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.scenario import ScoringSettings
from vitaplace.engine.study.aggregate import RunFolder, curve_path, validate_run_folder
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve
from vitaplace.engine.outputs.outdir import MATRICES
from vitaplace.engine.study.summary import bounds, cell, csv_text, describe, interval, json_safe

#: revisit tolerances τ [m] of the default grid
TAUS = (0.2, 0.3, 0.5)
#: heading tolerance [deg] of the default grid beside position only (None): the scoring default
HEADING_TOLERANCE_DEG = ScoringSettings.model_fields["heading_tolerance_deg"].default
#: the scores recomputed per ground truth (both proportions in [0, 1])
METRICS = ("max_f1", "recall_at_100_precision")
COLUMNS = ("seed", "environment", "method", "direction", "tau", "heading_tolerance_deg", "n_revisit", *METRICS)


class SensitivityError(UserError):
    """A folder whose saved evaluations cannot be rescored; the message names the file."""


def run_folders(folder: Path) -> list[RunFolder]:
    """The validated run folders under ``folder``: itself when it is a run folder (it has
    ``results.json``), else its ``seed-*`` subfolders (a sweep)."""
    folder = Path(folder)
    if (folder / "results.json").is_file():
        return [validate_run_folder(folder)]
    seeds = sorted(p for p in folder.glob("seed-*") if p.is_dir())
    if not seeds:
        raise SensitivityError(f"{folder}: neither a run folder (no results.json) nor a sweep folder (no seed-*/)")
    return [validate_run_folder(p) for p in seeds]


def load_evaluation(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(TME, query poses, reference poses) saved in one evaluation's ``matrices.npz``."""
    try:
        with np.load(path) as saved:
            if "query_poses" not in saved or "reference_poses" not in saved:
                raise SensitivityError(
                    f"{path}: no query_poses/reference_poses (saved since evaluate stage version 4); "
                    "run the scenario again into the same folder to re-evaluate from the cache"
                )
            return saved["tme"], saved["query_poses"], saved["reference_poses"]
    except (OSError, ValueError, KeyError) as exc:
        raise SensitivityError(f"{path}: unreadable matrices ({type(exc).__name__}: {exc})".splitlines()[0]) from None


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
                     heading_tolerances: Sequence[float | None] = (HEADING_TOLERANCE_DEG, None)) -> list[dict[str, Any]]:
    """`rescore` of every evaluation of every run, tagged with seed, environment, method and
    direction, in seed order."""
    out = []
    for run in sorted(runs, key=lambda r: r.seed):
        for row in run.rows:
            path = run.folder / Path(curve_path(row)).parent / MATRICES
            if not path.is_file():
                raise SensitivityError(f"{path}: missing; the evaluation's matrices are needed")
            identity = {"seed": run.seed, **{k: row[k] for k in ("environment", "method", "direction")}}
            out += [{**identity, **scored} for scored in rescore(*load_evaluation(path), taus, heading_tolerances)]
    return out


def summarise(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per environment x method x direction x heading tolerance x τ x metric, `describe` of
    the values over seeds (intervals inside the metric's bounds)."""
    keys = ("environment", "method", "direction", "heading_tolerance_deg", "tau")
    groups: dict[tuple, list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    return [{**dict(zip(keys, key)), "metric": metric, **describe([r[metric] for r in group], bounds(metric))}
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
        lines.append(f"| {r['environment']} | {r['method']} | {r['direction']} | {_heading(r['heading_tolerance_deg'])} "
                     f"| {r['tau']:g} | {r['metric']} | {r['n']} | {cell(r)} | {interval(r, 'boot')} |")
    return "\n".join(lines) + "\n"


def write_sensitivity(folder: Path, out: Path | None = None, taus: Sequence[float] = TAUS,
                      heading_tolerance_deg: float = HEADING_TOLERANCE_DEG) -> tuple[Path, dict[str, Any]]:
    """Rescore every saved evaluation of the run or sweep ``folder`` (`sensitivity_rows`) and
    write sensitivity.csv, .md and .json into ``out`` (default ``folder``), atomically, after
    every folder was read. Returns (out, what sensitivity.json holds)."""
    if not taus or any(not math.isfinite(t) or t <= 0 for t in taus):
        raise SensitivityError(f"--tau {' '.join(map(str, taus))}: expected positive distances in metres")
    if not 0 <= heading_tolerance_deg <= 180:
        raise SensitivityError(f"--heading-tolerance {heading_tolerance_deg}: expected degrees in [0, 180]")
    runs = run_folders(folder)
    rows = sensitivity_rows(runs, taus, (heading_tolerance_deg, None))
    summary = summarise(rows)
    out = Path(folder) if out is None else Path(out)
    write_text_atomic(out / "sensitivity.csv", csv_text(rows, COLUMNS))
    seeds = sorted({r.seed for r in runs})
    write_text_atomic(out / "sensitivity.md", markdown(summary, f"{runs[0].scenario}: sensitivity, {len(seeds)} seed(s)"))
    record = {"scenario": runs[0].scenario, "seeds": seeds, "taus": list(taus),
              "heading_tolerances_deg": [heading_tolerance_deg, None], "rows": rows, "summary": summary}
    write_text_atomic(out / "sensitivity.json", json.dumps(json_safe(record), indent=2))
    return out, record
