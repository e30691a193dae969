"""The files of one evaluation pair: `evaluate_pair` scores a query run against a reference
run and writes ``matrices.npz``, ``decisions.csv``, ``decisions.npz`` and ``pr_curve.npz``
(every write atomic); `load_curve` and `load_decisions` read the last two back.

The scores come from each query's row alone (`vitaplace.engine.evaluation.ranking`): a pair
of at most `FULL_MATRIX_LIMIT` entries is held whole, as ``matrices.npz`` (and the figures
drawn from it) need; a larger one is read a chunk of queries at a time, in memory linear in
the number of samples, and its ``matrices.npz`` is not written.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from vitaplace.engine.base.atomic import atomic_path
from vitaplace.engine.evaluation.difficulty import difficulty_from
from vitaplace.engine.evaluation.evaluate import (
    Decisions,
    PRCurve,
    curve_from,
    decisions_from,
    ground_truth_matrix,
    summary_from,
    true_matches,
)
from vitaplace.engine.evaluation.ranking import Rows, scan
from vitaplace.engine.evaluation.sequence import sequence_rows, travelled
from vitaplace.engine.outputs.outdir import DECISIONS, DECISIONS_CSV, MATRICES, PR_CURVE

__all__ = [
    "export_decisions_csv",
    "export_matrices_npz",
    "save_curve_and_decisions",
    "evaluate_pair",
    "load_curve",
    "load_decisions",
    "FULL_MATRIX_LIMIT",
]

log = logging.getLogger("vitaplace")

#: the largest pair (queries x references entries) whose matrices are held whole and written
#: to ``matrices.npz``: 25 million entries, 200 MB per float64 matrix (a 5,000 x 5,000 pair)
FULL_MATRIX_LIMIT = 25_000_000


def export_decisions_csv(
    path: str | os.PathLike,
    decisions: Decisions,
    extra_columns: Mapping[str, Sequence] | None = None,
) -> None:
    """Write one row per query (atomically): query, best_match (the lowest index of a tie),
    best_tme, best_gtm, has_revisit (0/1), accepted (0/1), outcome ('TP', 'FP', 'FP+FN', 'FN',
    'TN', 'TP|FP': `Decisions.outcome`), n_best (references at the best distance), correct_share
    (the share of those that are true matches), then any ``extra_columns`` (each a sequence
    with one value per query)."""
    n = decisions.n_queries
    extra = dict(extra_columns or {})
    for name, col in extra.items():
        if len(col) != n:
            raise ValueError(f"extra column {name!r} has {len(col)} values, expected {n} (one per query)")
    header = ["query", "best_match", "best_tme", "best_gtm", "has_revisit", "accepted", "outcome", "n_best",
              "correct_share", *extra]
    outcome = decisions.outcome
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for i in range(n):
                w.writerow(
                    [
                        i,
                        int(decisions.best_match[i]),
                        repr(float(decisions.best_tme[i])),
                        repr(float(decisions.best_gtm[i])),
                        int(bool(decisions.has_revisit[i])),
                        int(bool(decisions.accepted[i])),
                        outcome[i],
                        int(decisions.n_best[i]),
                        repr(float(decisions.correct_share[i])),
                        *(extra[k][i] for k in extra),
                    ]
                )


def export_matrices_npz(path: str | os.PathLike, tme: ArrayLike, gtm: ArrayLike, **extra: ArrayLike) -> None:
    """Save ``tme`` and ``gtm`` (and any extra named arrays) to a compressed ``.npz``, atomically."""
    tme_a = np.asarray(tme)
    gtm_a = np.asarray(gtm)
    if tme_a.shape != gtm_a.shape:
        raise ValueError(f"tme and gtm must have the same shape: tme {tme_a.shape} vs gtm {gtm_a.shape}")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:  # file object: numpy would append '.npz' to a bare name
            arrays: dict[str, Any] = {k: np.asarray(v) for k, v in extra.items()}  # Any: not allow_pickle's bool
            np.savez_compressed(fh, tme=tme_a, gtm=gtm_a, **arrays)


def save_curve_and_decisions(folder: str | os.PathLike, curve: PRCurve, decisions: Decisions) -> None:
    """``pr_curve.npz`` and ``decisions.npz`` in ``folder``, every field, atomically: what
    the report reads back with `load_curve` and `load_decisions`."""
    folder = Path(folder)
    for name, obj in ((PR_CURVE, curve), (DECISIONS, decisions)):
        with atomic_path(folder / name) as tmp, open(tmp, "wb") as f:
            arrays: dict[str, Any] = {k: np.asarray(v) for k, v in dataclasses.asdict(obj).items()}
            np.savez(f, **arrays)


_Saved = TypeVar("_Saved", PRCurve, Decisions)


def _load(cls: type[_Saved], path: str | os.PathLike) -> _Saved:
    with np.load(path) as data:
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name in data:
                arr = data[f.name]
                values[f.name] = arr.item() if arr.ndim == 0 else arr
    if cls is Decisions and "n_best" not in values:  # written before the tie rule: by the lowest index
        answered = np.isfinite(values["best_tme"])
        values["n_best"] = answered.astype(int)
        values["correct_share"] = (answered & (values["best_gtm"] <= values["tau"])).astype(float)
    return cls(**values)


def load_curve(path: str | os.PathLike) -> PRCurve:
    """The PRCurve `save_curve_and_decisions` wrote."""
    return _load(PRCurve, path)


def load_decisions(path: str | os.PathLike) -> Decisions:
    """The Decisions `save_curve_and_decisions` wrote."""
    return _load(Decisions, path)


def window_span(reference_poses: np.ndarray, window: int) -> float:
    """The median length of reference drive (metres, along its path) that the local contrast's
    window of ``window`` references on either side of a reference covers (cut at the run's ends)."""
    path = travelled(reference_poses)
    j = np.arange(len(path))
    return float(np.median(path[np.minimum(j + window, len(path) - 1)] - path[np.maximum(j - window, 0)]))


def evaluate_pair(
    folder: str | os.PathLike,
    tme: np.ndarray | Rows,
    query_poses: np.ndarray,
    reference_poses: np.ndarray,
    tau: float,
    delta: float | None = None,
    ks: Sequence[int] = (1, 5, 10),
    *,
    heading_tolerance_deg: float | None = None,
    query_touch: np.ndarray | None = None,
    reference_touch: np.ndarray | None = None,
    sequence: Mapping[str, Any] | None = None,
) -> dict:
    """Everything about one query run against one reference run, written to ``folder``:
    the ground truth from the poses (`ground_truth_matrix`), ``matrices.npz`` (TME, GTM and
    the poses, so that other ground truths can be scored later: `vitaplace.engine.study.sensitivity`), the
    decisions at the F1-maximising threshold (``decisions.csv``, ``decisions.npz``), the PR
    curve (``pr_curve.npz``); returns the summary (`evaluate`) with ``heading_tolerance_deg``
    and ``difficulty`` (`difficulty`, from the poses and the runs' touch masks, when given)
    added. With ``sequence`` (`sequence_scores`' settings) the sequence scores are what is
    scored and saved as ``tme``, the method's own distances as ``distance``, and the summary
    names the settings (``sequence``: length, velocity_min, velocity_max, velocity_steps,
    window, and ``metres`` when sequences run over travelled distance: the sequences then
    follow the two runs' poses) and the reference drive the window covers (``window_span_m``,
    `window_span`).
    ``tme`` may be a `Rows` (the method's distances computed a block of queries at a time):
    above `FULL_MATRIX_LIMIT` entries nothing is held whole and ``matrices.npz`` is skipped
    (one line in the log)."""
    folder = Path(folder)
    distance = tme if isinstance(tme, Rows) else Rows.of(tme)
    whole = distance.shape[0] * distance.shape[1] <= FULL_MATRIX_LIMIT
    if whole:
        distance = Rows.of(distance.whole())
    scored = (distance if sequence is None
              else sequence_rows(distance, **sequence, poses=(query_poses, reference_poses)))
    if whole:
        scored = Rows.of(scored.whole())
    truth = true_matches(query_poses, reference_poses, tau, heading_tolerance_deg)
    stats = scan(scored, truth, tuple(ks))
    curve = curve_from(stats)
    summary = summary_from(stats, delta, tuple(ks), curve=curve)
    summary["heading_tolerance_deg"] = heading_tolerance_deg
    if sequence is not None:  # numbers only, as every field of a results row
        (slowest, fastest), rest = sequence["velocities"], {k: v for k, v in sequence.items() if k != "velocities"}
        summary["sequence"] = {**rest, "velocity_min": slowest, "velocity_max": fastest,
                               "window_span_m": window_span(reference_poses, int(sequence["window"]))}
    summary["difficulty"] = difficulty_from(query_poses, reference_poses, truth, query_touch, reference_touch)
    decisions = decisions_from(stats, curve.delta_at_max_f1)
    if whole:
        extra = {} if sequence is None else {"distance": distance.whole()}
        export_matrices_npz(folder / MATRICES, scored.whole(), ground_truth_matrix(query_poses, reference_poses,
                            heading_tolerance_deg), query_poses=query_poses, reference_poses=reference_poses, **extra)
    else:
        log.warning("%s: %d x %d samples is over %d entries: matrices.npz not written", folder,
                    *distance.shape, FULL_MATRIX_LIMIT)
    export_decisions_csv(folder / DECISIONS_CSV, decisions)
    save_curve_and_decisions(folder, curve, decisions)
    return summary
