"""Place-recognition evaluation: ground truth, decisions, PR curves, recall@K.

Conventions (single-best-match VPR, as VPR_Tutorial's ``createPR(..., matching='single')``):

* ``tme[i, j]`` is the extractor's *distance* between query ``i`` and reference ``j``
  (lower = more similar); ``gtm[i, j]`` the ground-truth distance (metres; ``+inf`` where
  the two headings differ by more than the heading tolerance, `ground_truth_matrix`).  Rows
  are queries, columns references.
* For query ``i``: best match ``j* = argmin_j tme[i, j]``; a true revisit exists when
  ``min_j gtm[i, j] <= tau``; the match is accepted when ``tme[i, j*] <= delta``.
* **Ties**: the best distance may be shared by ``m`` references (exact
  equality of distances, no tolerance), ``c`` of them true matches.  Every measure is the
  expected value under a uniformly random choice among them: the best match is correct with
  ``correct_share = c / m``, so a tied query counts ``c / m`` of a TP and ``1 - c / m`` of an
  FP when accepted (the best distance, hence acceptance, is the same whichever is chosen),
  and recall@K counts the probability that a true match is among the first K when the tie
  group that straddles rank K is drawn at random.  No rule that favours a method: the
  lowest index, VPR_Tutorial's ``argmax``, would make a method whose distances are all
  equal right whenever reference 0 happens to be a true match.  Untied, ``c / m`` is 0 or 1
  and every measure is the plain count.  ``best_match`` keeps the lowest index of the tie
  (what the figures draw); ``tied_share`` (`evaluate`) is the share of queries whose best
  distance is finite and shared.
* TP = accepted and correct; FP = accepted and not correct; FN = true revisit and not TP
  (so an accepted-but-wrong match of a query with a true revisit is both FP and FN);
  TN = no true revisit and rejected.  TP + FN = number of queries with a true revisit.
  With ties TP, FP and FN are expected counts, fractional where a tie splits a query.
* precision = TP / (TP + FP), **defined as 1.0 when nothing is accepted** (TP + FP == 0) —
  the point (recall 0, precision 1) that VPR_Tutorial prepends to every PR curve and that
  scikit-learn's ``precision_recall_curve`` appends;
  recall = TP / (TP + FN), 0.0 when no query has a true revisit;
  F1 = 2PR / (P + R), 0.0 when P + R == 0.
* AUC is the step-wise *average precision* (scikit-learn's ``average_precision_score``
  definition, no interpolation): ``sum_n (R_n - R_{n-1}) * P_n`` over the sampled
  thresholds in increasing ``delta`` order with ``R_{-1} = 0``.  With the default threshold
  sweep it equals scikit-learn's average precision of the scores ``-best_tme`` against the
  labels "best match correct", times ``#correct best matches / #queries with a revisit``
  (our recall denominator counts all queries with a revisit).
* A threshold that must transfer: `f1_at_threshold_of` scores a pair at the threshold that
  maximised F1 on another pair (the runner: the training world's evaluation), unchanged;
  `f1_at_threshold_from` does so from the pair's saved `Decisions`, at any size.
* Linear memory: every measure is computed from each query's row alone (`QueryStats`,
  `vitaplace.engine.evaluation.ranking`), so the matrices need not be held whole: `scan` reads
  the scored matrix a chunk of queries at a time, `true_matches` gives the ground truth from a
  k-d tree over the poses, and `decisions_from`, `curve_from`, `recall_from` and
  `summary_from` score the result exactly as `decide`, `pr_curve`, `recall_at_k` and
  `evaluate` score the whole matrices (which they do through the same path).
* `vitaplace.engine.evaluation.difficulty` measures the pair itself (nearest reference pose,
  chance level, touch, longest stay), whatever the method; `vitaplace.engine.evaluation.pairfiles`
  writes a pair's files (`evaluate_pair`) and reads them back.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from vitaplace.engine.evaluation.ranking import GroundTruth, QueryStats, Rows, check_ks, scan

__all__ = [
    "Decisions",
    "PRCurve",
    "count_value",
    "curve_from",
    "decide",
    "decisions_from",
    "evaluate",
    "f1_at_threshold_from",
    "f1_at_threshold_of",
    "ground_truth_matrix",
    "pr_curve",
    "recall_at_k",
    "recall_from",
    "summary_from",
    "true_matches",
]


# --------------------------------------------------------------------------- validation


def _check_poses(poses: ArrayLike, name: str, need_yaw: bool) -> np.ndarray:
    arr = np.asarray(poses, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < (3 if need_yaw else 2):
        want = "(N, 3) x, y, yaw" if need_yaw else "(N, 2) or (N, 3)"
        raise ValueError(f"{name} must be an array of shape {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr[:, : 3 if need_yaw else 2])):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _check_tau(tau: Any) -> float:
    try:
        tau_f = float(tau)
    except (TypeError, ValueError):
        raise ValueError(f"tau must be a number, got {tau!r}") from None
    if np.isnan(tau_f) or tau_f < 0:
        raise ValueError(f"tau must be a non-negative distance threshold, got {tau!r}")
    return tau_f


def _check_matrices(tme: ArrayLike, gtm: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    tme_a = np.asarray(tme, dtype=float)
    gtm_a = np.asarray(gtm, dtype=float)
    if tme_a.ndim != 2:
        raise ValueError(f"tme must be a 2-D (queries x references) matrix, got shape {tme_a.shape}")
    if tme_a.shape != gtm_a.shape:
        raise ValueError(
            f"tme and gtm must have the same shape (queries x references): "
            f"tme {tme_a.shape} vs gtm {gtm_a.shape}"
        )
    if tme_a.shape[0] == 0 or tme_a.shape[1] == 0:
        raise ValueError(f"tme/gtm must have at least one query and one reference, got {tme_a.shape}")
    if np.isnan(tme_a).any():
        bad = np.argwhere(np.isnan(tme_a))
        raise ValueError(
            f"tme contains {len(bad)} NaN value(s) (first at query {bad[0][0]}, reference {bad[0][1]})"
        )
    if np.isneginf(tme_a).any():
        raise ValueError("tme contains -inf; TME entries must be distances (finite or +inf)")
    if np.isnan(gtm_a).any():
        raise ValueError("gtm contains NaN values")
    if (gtm_a < 0).any():
        raise ValueError("gtm contains negative distances")
    return tme_a, gtm_a


# --------------------------------------------------------------------------- ground truth


def _heading_difference_deg(yaw_a: np.ndarray, yaw_b: np.ndarray) -> np.ndarray:
    """``|wrap(yaw_a - yaw_b)|`` in degrees, in ``[0, 180]`` (yaws in radians, broadcast)."""
    diff = yaw_a - yaw_b
    return np.degrees(np.abs(np.arctan2(np.sin(diff), np.cos(diff))))


def _check_heading(heading_tolerance_deg: float | None) -> float | None:
    if heading_tolerance_deg is None:
        return None
    tolerance = float(heading_tolerance_deg)
    if np.isnan(tolerance) or tolerance < 0:
        raise ValueError(f"heading_tolerance_deg must be >= 0 degrees or None, got {tolerance!r}")
    return tolerance


def ground_truth_matrix(query_poses: ArrayLike, reference_poses: ArrayLike,
                        heading_tolerance_deg: float | None = None) -> np.ndarray:
    """Ground-truth matrix ``GTM[i, j]`` between query and reference poses ``(N, 3)`` (x, y, yaw).

    ``GTM[i, j] = ||xy_i - xy_j||_2`` (metres) where the two headings differ by at most
    ``heading_tolerance_deg`` (the yaw difference wrapped to ``[-180, 180]`` degrees, bound
    included), and ``+inf`` where they differ by more: a reference facing elsewhere is no
    match at any distance, so ``GTM[i, j] <= tau`` is "position within tau and heading within
    the tolerance". ``None``: position only ((N, 2) poses accepted then).
    """
    heading_tolerance_deg = _check_heading(heading_tolerance_deg)
    need_yaw = heading_tolerance_deg is not None
    q = _check_poses(query_poses, "query_poses", need_yaw)
    r = _check_poses(reference_poses, "reference_poses", need_yaw)
    gtm = cdist(q[:, :2], r[:, :2], metric="euclidean")
    if need_yaw:
        gtm[_heading_difference_deg(q[:, 2][:, None], r[:, 2][None, :]) > heading_tolerance_deg] = np.inf
    return gtm


def _pair_ground_truth(q: np.ndarray, r: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                       heading_tolerance_deg: float | None) -> np.ndarray:
    """`ground_truth_matrix`'s entries ``[rows, cols]`` (elementwise), by the same arithmetic
    as its euclidean distance (``sqrt(dx * dx + dy * dy)``, SciPy's ``cdist``) and heading test."""
    dx, dy = q[rows, 0] - r[cols, 0], q[rows, 1] - r[cols, 1]
    gt = np.sqrt(dx * dx + dy * dy)
    if heading_tolerance_deg is not None:
        gt[_heading_difference_deg(q[rows, 2], r[cols, 2]) > heading_tolerance_deg] = np.inf
    return gt


def true_matches(query_poses: ArrayLike, reference_poses: ArrayLike, tau: float,
                 heading_tolerance_deg: float | None = None) -> GroundTruth:
    """`ground_truth_matrix` ``<= tau`` without the matrix: each query's true matches, found
    by a k-d tree over the positions (every pair within a hair over ``tau``) and kept where
    the pair's `ground_truth_matrix` entry, computed the same way, is ``<= tau``; memory in
    proportion to the number of true pairs."""
    heading_tolerance_deg = _check_heading(heading_tolerance_deg)
    need_yaw = heading_tolerance_deg is not None
    q = _check_poses(query_poses, "query_poses", need_yaw)
    r = _check_poses(reference_poses, "reference_poses", need_yaw)
    tau = _check_tau(tau)
    reach = np.nextafter(tau * (1.0 + 1e-9), np.inf)  # the tree's rounding must not lose a pair at tau
    near = cKDTree(q[:, :2]).sparse_distance_matrix(cKDTree(r[:, :2]), reach, output_type="ndarray")
    rows, cols = near["i"].astype(np.intp), near["j"].astype(np.intp)
    true = _pair_ground_truth(q, r, rows, cols, heading_tolerance_deg) <= tau
    return GroundTruth.of_pairs(tau, (len(q), len(r)), rows[true], cols[true],
                                lambda i, j: _pair_ground_truth(q, r, i, j, heading_tolerance_deg))


# --------------------------------------------------------------------------- decisions


def count_value(count: float) -> int | float:
    """A count as the summaries hold it: an int when whole (no tie split it), else the
    expected count as a float."""
    count = float(count)
    return int(count) if count.is_integer() else count


@dataclass(frozen=True)
class Decisions:
    """Per-query single-best-match decisions at one (tau, delta); tp, fp, fn, tn are each
    query's expected share of a TP, FP, FN, TN under the tie rule (module docstring): 0 or 1
    unless a tie splits the query."""

    best_match: np.ndarray  # int (Q,)  j* = argmin_j tme[i, j], the lowest index of a tie
    best_tme: np.ndarray  # float (Q,)
    best_gtm: np.ndarray  # float (Q,)  gtm[i, j*]
    has_revisit: np.ndarray  # bool (Q,)  min_j gtm[i, j] <= tau
    accepted: np.ndarray  # bool (Q,)  best_tme <= delta
    tp: np.ndarray  # float (Q,)
    fp: np.ndarray
    fn: np.ndarray
    tn: np.ndarray
    tau: float
    delta: float
    n_best: np.ndarray  # int (Q,)  references at the best distance (0: no answer)
    correct_share: np.ndarray  # float (Q,)  c / m: the share of them that are true matches

    @property
    def n_queries(self) -> int:
        return int(self.best_match.shape[0])

    @property
    def counts(self) -> dict[str, int | float]:
        """Counts (`count_value`: ints unless a tie splits one): tp, fp, fn, tn, n_queries,
        n_revisit, n_accepted."""
        return {
            "tp": count_value(self.tp.sum()),
            "fp": count_value(self.fp.sum()),
            "fn": count_value(self.fn.sum()),
            "tn": count_value(self.tn.sum()),
            "n_queries": self.n_queries,
            "n_revisit": int(self.has_revisit.sum()),
            "n_accepted": int(self.accepted.sum()),
        }

    @property
    def outcome(self) -> np.ndarray:
        """Per-query label: 'TP', 'FP', 'FP+FN' (accepted, wrong, a revisit existed), 'FN',
        'TN', and 'TP|FP' for an accepted query whose tied best matches are partly true
        matches (its share of each in ``tp`` and ``fp``)."""
        out = np.full(self.n_queries, "TN", dtype=object)
        out[self.fn == 1] = "FN"
        out[self.fp == 1] = "FP"
        out[(self.fp == 1) & (self.fn == 1)] = "FP+FN"
        out[self.tp == 1] = "TP"
        out[(self.tp > 0) & (self.tp < 1)] = "TP|FP"
        return out.astype(str)


def _stats(tme: np.ndarray, gtm: np.ndarray, tau: float, ks: Sequence[int] = ()) -> QueryStats:
    """`QueryStats` of whole (checked) matrices."""
    return scan(Rows.of(tme), GroundTruth.of_matrix(gtm, tau), ks)


def query_stats(tme: ArrayLike, gtm: ArrayLike, tau: float, ks: Sequence[int] = ()) -> QueryStats:
    """Each query's `QueryStats` of whole matrices (checked), with the recall@K chances of ``ks``."""
    tme_a, gtm_a = _check_matrices(tme, gtm)
    return _stats(tme_a, gtm_a, _check_tau(tau), check_ks(ks))


def _check_delta(delta: float) -> float:
    delta = float(delta)
    if np.isnan(delta):
        raise ValueError("delta must not be NaN")
    return delta


def decide(tme: ArrayLike, gtm: ArrayLike, tau: float, delta: float) -> Decisions:
    """Single-best-match decisions for acceptance threshold ``delta`` on the TME."""
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    delta = _check_delta(delta)
    return decisions_from(_stats(tme_a, gtm_a, tau), delta)


def decisions_from(stats: QueryStats, delta: float) -> Decisions:
    """`decide` from each query's `QueryStats`."""
    delta = _check_delta(delta)
    best_tme, correct_share, has_revisit = stats.best_tme, stats.correct_share, stats.has_revisit
    accepted = (best_tme <= delta) & np.isfinite(best_tme)
    tp = np.where(accepted, correct_share, 0.0)
    return Decisions(
        best_match=stats.best_match,
        best_tme=best_tme,
        best_gtm=stats.best_gtm,
        has_revisit=has_revisit,
        accepted=accepted,
        tp=tp,
        fp=np.where(accepted, 1.0 - correct_share, 0.0),
        fn=np.where(has_revisit, 1.0 - tp, 0.0),
        tn=(~has_revisit & ~accepted).astype(float),
        tau=stats.tau,
        delta=delta,
        n_best=stats.n_best,
        correct_share=correct_share,
    )


# --------------------------------------------------------------------------- PR curve


def _safe_div(num: np.ndarray, den: np.ndarray, fill: float) -> np.ndarray:
    num = np.asarray(num, dtype=float)
    den = np.asarray(den, dtype=float)
    out = np.full(np.broadcast(num, den).shape, fill, dtype=float)
    np.divide(num, den, out=out, where=den != 0)
    return out


@dataclass(frozen=True)
class PRCurve:
    """Precision/recall/F1 over a sweep of acceptance thresholds ``deltas``.

    Arrays are aligned with ``deltas`` (ascending when the default sweep is used).
    ``auc`` is step-wise average precision (see module docstring).
    """

    deltas: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    f1: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    n_revisit: int
    n_queries: int

    @property
    def _order(self) -> np.ndarray:
        return np.argsort(self.deltas, kind="stable")

    @property
    def max_f1(self) -> float:
        return float(self.f1.max()) if self.f1.size else 0.0

    @property
    def index_at_max_f1(self) -> int:
        """Index of the max F1; among ties, the one with the smallest delta."""
        f1_sorted = self.f1[self._order]
        return int(self._order[int(np.argmax(f1_sorted))])

    @property
    def delta_at_max_f1(self) -> float:
        return float(self.deltas[self.index_at_max_f1])

    @property
    def recall_at_full_precision(self) -> float:
        """The largest recall at a threshold where every accepted match is correct
        (VPR_Tutorial's recall at 100 % precision); 0 when no such threshold recalls anything."""
        full = self.precision >= 1.0
        return float(self.recall[full].max()) if full.any() else 0.0

    @property
    def auc(self) -> float:
        """Step-wise average precision ``sum_n (R_n - R_{n-1}) P_n`` (delta ascending, R_{-1} = 0)."""
        r = self.recall[self._order]
        p = self.precision[self._order]
        dr = np.diff(np.concatenate(([0.0], r)))
        return float(np.sum(dr * p))


def pr_curve(tme: ArrayLike, gtm: ArrayLike, tau: float, deltas: Iterable[float] | None = None) -> PRCurve:
    """PR curve of single-best-match place recognition.

    ``deltas=None`` sweeps every distinct best-match TME value plus ``-inf`` (nothing accepted),
    ascending; otherwise the given thresholds (kept in the given order).
    precision is 1.0 when nothing is accepted (VPR_Tutorial's / scikit-learn's end point),
    recall is 0.0 when no query has a true revisit, F1 is 0.0 when P + R == 0.
    """
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    d = _check_deltas(deltas)
    return curve_from(_stats(tme_a, gtm_a, tau), d)


def _check_deltas(deltas: Iterable[float] | None) -> np.ndarray | None:
    if deltas is None:
        return None
    d = np.asarray(deltas if isinstance(deltas, np.ndarray) else list(deltas), dtype=float).ravel()
    if d.size == 0:
        raise ValueError("deltas must contain at least one threshold")
    if np.isnan(d).any():
        raise ValueError("deltas must not contain NaN")
    return d


def curve_from(stats: QueryStats | Decisions, deltas: Iterable[float] | None = None) -> PRCurve:
    """`pr_curve` from each query's `QueryStats`, or from `Decisions` at any threshold (they
    keep every query's best distance, the share of its tie that is true and its revisit)."""
    best_tme, correct_share, has_revisit = stats.best_tme, stats.correct_share, stats.has_revisit
    d = _check_deltas(deltas)
    if d is None:
        d = np.concatenate(([-np.inf], np.unique(best_tme[np.isfinite(best_tme)])))
    # TP(delta) = the correct shares of the best matches with best_tme <= delta, FP the rest
    # of them; a query without an answer (best_tme +inf) is never accepted.
    answered = np.isfinite(best_tme)
    order = np.argsort(best_tme[answered], kind="stable")
    share = correct_share[answered][order]
    accepted = np.searchsorted(best_tme[answered][order], d, side="right")
    tp = np.concatenate(([0.0], np.cumsum(share)))[accepted]
    fp = np.concatenate(([0.0], np.cumsum(1.0 - share)))[accepted]
    n_revisit = int(has_revisit.sum())
    fn = n_revisit - tp
    precision = _safe_div(tp, tp + fp, 1.0)
    recall = _safe_div(tp, np.full_like(tp, n_revisit), 0.0)
    f1 = _safe_div(2.0 * precision * recall, precision + recall, 0.0)
    return PRCurve(
        deltas=d,
        precision=precision,
        recall=recall,
        f1=f1,
        tp=tp,
        fp=fp,
        fn=fn,
        n_revisit=n_revisit,
        n_queries=len(best_tme),
    )


# --------------------------------------------------------------------------- recall@K


def recall_at_k(tme: ArrayLike, gtm: ArrayLike, tau: float, ks: Sequence[int] = (1, 5, 10)) -> dict[int, float]:
    """Fraction of queries with a true revisit for which one of the K lowest-TME references
    lies within ``tau``, in expectation over a uniformly random order of tied distances (module
    docstring): with ``L`` references strictly nearer than the K-th nearest distance ``v`` and
    ``m`` at ``v``, ``c`` of them true matches, a query without a true match among the ``L``
    counts ``1 - C(m - c, K - L) / C(m, K - L)`` (the hypergeometric chance that the ``K - L``
    drawn from the tie include one); an entry at +inf is never a hit.

    K larger than the number of references is clamped to it; 0.0 when no query has a revisit.
    """
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    ks_list = check_ks(ks)
    return recall_from(_stats(tme_a, gtm_a, tau, ks_list), ks_list)


def recall_from(stats: QueryStats, ks: Sequence[int]) -> dict[int, float]:
    """`recall_at_k` from each query's `QueryStats` (scanned with these ``ks``)."""
    ks_list = check_ks(ks)
    if not stats.has_revisit.any():
        return {k: 0.0 for k in ks_list}
    return {k: float(stats.hits[k].mean()) for k in ks_list}


# --------------------------------------------------------------------------- summary


def _json_float(x: float) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def evaluate(
    tme: ArrayLike, gtm: ArrayLike, tau: float, delta: float | None = None, ks: Sequence[int] = (1, 5, 10),
    curve: PRCurve | None = None,
) -> dict:
    """JSON-serialisable summary (plain floats/ints; non-finite thresholds reported as None).

    Keys: n_queries, n_references, n_revisit, tau, max_f1, precision_at_max_f1,
    recall_at_max_f1, delta_at_max_f1, auc,
    auc_method, recall_at_100_precision, recall_at_k ({"1": ..., ...}, string keys so JSON round-trips),
    tied_share (the share of queries whose best distance is finite and shared: the tie rule
    decided them), and when ``delta`` is given: delta, precision, recall, f1, tp, fp, fn, tn
    (`count_value`s), n_accepted.
    ``curve``: the default-sweep `pr_curve` of the same matrices, when already computed.
    """
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    ks_list = check_ks(ks)
    return summary_from(_stats(tme_a, gtm_a, tau, ks_list), delta, ks_list, curve)


def summary_from(stats: QueryStats, delta: float | None = None, ks: Sequence[int] = (1, 5, 10),
                 curve: PRCurve | None = None) -> dict:
    """`evaluate` from each query's `QueryStats` (scanned with these ``ks``)."""
    tau = stats.tau
    if curve is None:
        curve = curve_from(stats)
    rk = recall_from(stats, ks)
    out: dict = {
        "n_queries": len(stats.best_tme),
        "n_references": stats.n_references,
        "n_revisit": int(curve.n_revisit),
        "tau": float(tau),
        "max_f1": float(curve.max_f1),
        "precision_at_max_f1": float(curve.precision[curve.index_at_max_f1]),
        "recall_at_max_f1": float(curve.recall[curve.index_at_max_f1]),
        "delta_at_max_f1": _json_float(curve.delta_at_max_f1),
        "auc": float(curve.auc),
        "auc_method": "average_precision_stepwise",
        "recall_at_100_precision": curve.recall_at_full_precision,
        "recall_at_k": {str(k): float(v) for k, v in rk.items()},
        "tied_share": float(np.mean(stats.n_best > 1)),
    }
    if delta is not None:
        dec = decisions_from(stats, delta)
        c = dec.counts
        p = 1.0 if c["tp"] + c["fp"] == 0 else c["tp"] / (c["tp"] + c["fp"])
        r = 0.0 if c["n_revisit"] == 0 else c["tp"] / c["n_revisit"]
        f = 0.0 if p + r == 0 else 2 * p * r / (p + r)
        out.update(
            {
                "delta": _json_float(delta),
                "precision": float(p),
                "recall": float(r),
                "f1": float(f),
                "tp": c["tp"],
                "fp": c["fp"],
                "fn": c["fn"],
                "tn": c["tn"],
                "n_accepted": c["n_accepted"],
            }
        )
    return out


def f1_at_threshold_of(source: PRCurve, tme: ArrayLike, gtm: ArrayLike, tau: float) -> float:
    """F1 of ``(tme, gtm)`` at the threshold that maximised F1 on ``source`` (another
    evaluation's PR curve: the training world's), applied unchanged. The threshold is
    ``source.delta_at_max_f1`` (the smallest among tied maxima); ``-inf`` (the source's best
    was to accept nothing) accepts nothing here either, F1 0."""
    return float(pr_curve(tme, gtm, tau, [source.delta_at_max_f1]).f1[0])


def f1_at_threshold_from(source: PRCurve, decisions: Decisions) -> float:
    """`f1_at_threshold_of` from the pair's `Decisions` (taken at any threshold) instead of
    its matrices."""
    return float(curve_from(decisions, [source.delta_at_max_f1]).f1[0])
