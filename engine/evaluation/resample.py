"""Within-seed intervals: a block bootstrap over contiguous segments of the query run.

One evaluation (one seed x environment x method x direction) scores the Q samples of a
query run against a reference run. Neighbouring queries are correlated (the robot sees one
place for several samples), so queries are resampled in contiguous segments, not one by
one (the non-overlapping block bootstrap of Carlstein, 1986):

* block length ``L = ceil(sqrt(Q))`` (`block_length`: 18 for Q = 300); the queries, in the
  order of the run, are cut into ``b = ceil(Q / L)`` segments ``[kL, min((k+1)L, Q))``, the
  last one possibly shorter;
* a replicate draws ``b`` segments uniformly with replacement and concatenates their
  queries; every metric is recomputed by `vitaplace.engine.evaluation.evaluate.evaluate` on those rows
  of the saved distance and ground-truth matrices (``matrices.npz``), the reference run
  fixed;
* `RESAMPLES` replicates from a generator seeded with ``(BLOCK_SEED, run seed)``: all
  methods of one seed and environment draw the same segments (the replicates pair across
  methods), different seeds draw independently.

The percentile interval of these replicates is conditional on the reference run, the
training run and the network's initialisation: it measures how much a score depends on
which stretch of the query drive was tested, not how it varies between seeds. It is what a
single-seed run can have instead of an interval over seeds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.evaluation.evaluate import curve_from, query_stats, summary_from
from vitaplace.engine.outputs.outdir import MATRICES, evaluation_dir

#: replicates per evaluation
RESAMPLES = 1000
#: first word of every replicate generator's seed (the second is the run's seed)
BLOCK_SEED = 20260


def block_length(n_queries: int) -> int:
    """Queries per contiguous segment: ``ceil(sqrt(n_queries))``."""
    return max(1, math.ceil(math.sqrt(n_queries)))


def block_draws(n_queries: int, seed: int, resamples: int | None = None) -> list[np.ndarray]:
    """Query row indices of each of ``resamples`` (default `RESAMPLES`) replicates:
    ``ceil(Q / L)`` segments of `block_length` drawn with replacement from the generator
    seeded with ``(BLOCK_SEED, seed)``."""
    resamples = RESAMPLES if resamples is None else resamples
    length = block_length(n_queries)
    starts = np.arange(0, n_queries, length)
    chosen = np.random.default_rng((BLOCK_SEED, seed)).integers(0, len(starts), size=(resamples, len(starts)))
    return [np.concatenate([np.arange(s, min(s + length, n_queries)) for s in starts[row]]) for row in chosen]


def compact_matrices(tme: np.ndarray, gtm: np.ndarray, kmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Per query, the few references that decide its scores, so that replicates are cheap.

    Each row keeps, in stable order (ties by reference index), its references up to the
    ``kmax``-th nearest in TME and every reference tied with that one (the tie rule counts the
    whole tie: `vitaplace.engine.evaluation.evaluate`; a tie at +inf, never a hit, is cut at
    ``kmax``), then its nearest reference in ground truth when not among those; the rows are
    padded to one width with columns that match nothing (+inf in both). Any later column ranks
    after every kept tie, so `evaluate` of any set of rows of the compact matrices equals that
    of the same rows of the full ones for K <= ``kmax`` (``n_references`` aside): the best match
    and its tie, whether a revisit exists and the ties up to rank K are unchanged."""
    n_ref = tme.shape[1]
    if kmax + 1 >= n_ref:
        return tme, gtm
    order = np.argsort(tme, axis=1, kind="stable")
    edge = np.take_along_axis(tme, order[:, kmax - 1 : kmax], axis=1)
    kept = np.where(np.isfinite(edge[:, 0]), (tme <= edge).sum(axis=1), kmax)
    width = int(kept.max()) + 1
    if width >= n_ref:
        return tme, gtm
    rows = np.arange(len(tme))
    columns = np.arange(width)
    keep = np.where(columns < kept[:, None], order[:, :width], -1)  # -1: a padding column
    nearest = np.argmin(gtm, axis=1)
    absent = ~(keep == nearest[:, None]).any(axis=1)
    keep[rows[absent], kept[absent]] = nearest[absent]
    padded = keep < 0
    tme_c = np.where(padded, np.inf, np.take_along_axis(tme, np.maximum(keep, 0), axis=1))
    gtm_c = np.where(padded, np.inf, np.take_along_axis(gtm, np.maximum(keep, 0), axis=1))
    return tme_c, gtm_c


def replicate_rows(tme: np.ndarray, gtm: np.ndarray, row: Mapping[str, Any], seed: int,
                   resamples: int | None = None) -> list[dict[str, Any]]:
    """`evaluate` of each block-bootstrap replicate of one evaluation, with the ``tau``,
    fixed ``delta`` and recall@K of its results row ``row``; where the row has an
    ``f1_at_e1_threshold``, each replicate's F1 at the row's ``e1_threshold`` too (null: the
    training world's best was to accept nothing, so nothing is accepted)."""
    ks = tuple(sorted(int(k) for k in row.get("recall_at_k") or {})) or (1,)
    tme_c, gtm_c = compact_matrices(np.asarray(tme, dtype=float), np.asarray(gtm, dtype=float), max(ks))
    delta, tau = row.get("delta"), row["tau"]
    transferred = row.get("f1_at_e1_threshold") is not None
    threshold = -math.inf if row.get("e1_threshold") is None else float(row["e1_threshold"])
    stats = query_stats(tme_c, gtm_c, tau, ks)  # each replicate takes its queries' rows of these
    replicates = []
    for rows in block_draws(tme_c.shape[0], seed, resamples):
        drawn = stats.take(rows)
        replicate = summary_from(drawn, delta, ks)
        if transferred:
            replicate["f1_at_e1_threshold"] = float(curve_from(drawn, [threshold]).f1[0])
        replicates.append(replicate)
    return replicates


def evaluation_replicates(run_folder: Path, row: Mapping[str, Any],
                          resamples: int | None = None) -> list[dict[str, Any]] | None:
    """`replicate_rows` of the evaluation that made ``row`` (a results row with its ``seed``)
    in the run folder ``run_folder``; None when its matrices were not saved there."""
    path = evaluation_dir(run_folder, row["environment"], row["method"], row["direction"]) / MATRICES
    if not path.is_file():
        return None
    with np.load(path) as saved:
        tme, gtm = saved["tme"], saved["gtm"]
    return replicate_rows(tme, gtm, row, row["seed"], resamples)
