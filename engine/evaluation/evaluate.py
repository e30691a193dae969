"""Place-recognition evaluation: ground truth, decisions, PR curves, recall@K.

Conventions (single-best-match VPR, as VPR_Tutorial's ``createPR(..., matching='single')``):

* ``tme[i, j]`` is the extractor's *distance* between query ``i`` and reference ``j``
  (lower = more similar); ``gtm[i, j]`` the ground-truth distance (metres; ``+inf`` where
  the two headings differ by more than the heading tolerance, `ground_truth_matrix`).  Rows
  are queries, columns references.
* For query ``i``: best match ``j* = argmin_j tme[i, j]`` (ties -> lowest ``j``);
  a true revisit exists when ``min_j gtm[i, j] <= tau``; the match is accepted when
  ``tme[i, j*] <= delta``.
* TP = accepted and ``gtm[i, j*] <= tau``; FP = accepted and ``gtm[i, j*] > tau``;
  FN = true revisit and not TP (so an accepted-but-wrong match of a query with a true
  revisit is both FP and FN); TN = no true revisit and rejected.  TP + FN = number of queries
  with a true revisit.
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
  maximised F1 on another pair (the runner: the training world's evaluation), unchanged.
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
from scipy.spatial.distance import cdist

__all__ = [
    "Decisions",
    "PRCurve",
    "decide",
    "evaluate",
    "f1_at_threshold_of",
    "ground_truth_matrix",
    "pr_curve",
    "recall_at_k",
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


def ground_truth_matrix(query_poses: ArrayLike, reference_poses: ArrayLike,
                        heading_tolerance_deg: float | None = None) -> np.ndarray:
    """Ground-truth matrix ``GTM[i, j]`` between query and reference poses ``(N, 3)`` (x, y, yaw).

    ``GTM[i, j] = ||xy_i - xy_j||_2`` (metres) where the two headings differ by at most
    ``heading_tolerance_deg`` (the yaw difference wrapped to ``[-180, 180]`` degrees, bound
    included), and ``+inf`` where they differ by more: a reference facing elsewhere is no
    match at any distance, so ``GTM[i, j] <= tau`` is "position within tau and heading within
    the tolerance". ``None``: position only ((N, 2) poses accepted then).
    """
    need_yaw = heading_tolerance_deg is not None
    if heading_tolerance_deg is not None:
        heading_tolerance_deg = float(heading_tolerance_deg)
        if np.isnan(heading_tolerance_deg) or heading_tolerance_deg < 0:
            raise ValueError(f"heading_tolerance_deg must be >= 0 degrees or None, got {heading_tolerance_deg!r}")
    q = _check_poses(query_poses, "query_poses", need_yaw)
    r = _check_poses(reference_poses, "reference_poses", need_yaw)
    gtm = cdist(q[:, :2], r[:, :2], metric="euclidean")
    if need_yaw:
        gtm[_heading_difference_deg(q[:, 2][:, None], r[:, 2][None, :]) > heading_tolerance_deg] = np.inf
    return gtm


# --------------------------------------------------------------------------- decisions


@dataclass(frozen=True)
class Decisions:
    """Per-query single-best-match decisions at one (tau, delta)."""

    best_match: np.ndarray  # int (Q,)  j* = argmin_j tme[i, j]
    best_tme: np.ndarray  # float (Q,)
    best_gtm: np.ndarray  # float (Q,)  gtm[i, j*]
    has_revisit: np.ndarray  # bool (Q,)  min_j gtm[i, j] <= tau
    accepted: np.ndarray  # bool (Q,)  best_tme <= delta
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    tn: np.ndarray
    tau: float
    delta: float

    @property
    def n_queries(self) -> int:
        return int(self.best_match.shape[0])

    @property
    def counts(self) -> dict[str, int]:
        """Plain-int counts: tp, fp, fn, tn, n_queries, n_revisit, n_accepted."""
        return {
            "tp": int(self.tp.sum()),
            "fp": int(self.fp.sum()),
            "fn": int(self.fn.sum()),
            "tn": int(self.tn.sum()),
            "n_queries": self.n_queries,
            "n_revisit": int(self.has_revisit.sum()),
            "n_accepted": int(self.accepted.sum()),
        }

    @property
    def correct(self) -> np.ndarray:
        """Per query: its best match is a true match, and it has an answer (a finite best
        distance; a query no reference can be compared with is never right)."""
        return _correct(self.best_gtm, self.best_tme, self.tau)

    @property
    def outcome(self) -> np.ndarray:
        """Per-query label: 'TP', 'FP', 'FP+FN' (accepted, wrong, a revisit existed), 'FN', 'TN'."""
        out = np.full(self.n_queries, "TN", dtype=object)
        out[self.fn] = "FN"
        out[self.fp] = "FP"
        out[self.fp & self.fn] = "FP+FN"
        out[self.tp] = "TP"
        return out.astype(str)


def _correct(best_gtm: np.ndarray, best_tme: np.ndarray, tau: float) -> np.ndarray:
    """A best match is correct when it is a true match and the query has an answer: a query
    whose every distance is +inf (a method that cannot compare it, e.g. vision only without
    its camera) is never accepted, never correct."""
    return (best_gtm <= tau) & np.isfinite(best_tme)


def _best(
    tme: np.ndarray, gtm: np.ndarray, tau: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rows = np.arange(tme.shape[0])
    best_match = np.argmin(tme, axis=1)  # ties -> lowest reference index
    best_tme = tme[rows, best_match]
    best_gtm = gtm[rows, best_match]
    has_revisit = gtm.min(axis=1) <= tau
    correct = _correct(best_gtm, best_tme, tau)  # implies has_revisit
    return best_match, best_tme, best_gtm, has_revisit, correct


def decide(tme: ArrayLike, gtm: ArrayLike, tau: float, delta: float) -> Decisions:
    """Single-best-match decisions for acceptance threshold ``delta`` on the TME."""
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    delta = float(delta)
    if np.isnan(delta):
        raise ValueError("delta must not be NaN")
    best_match, best_tme, best_gtm, has_revisit, correct = _best(tme_a, gtm_a, tau)
    accepted = (best_tme <= delta) & np.isfinite(best_tme)
    tp = accepted & correct
    fp = accepted & ~correct
    fn = has_revisit & ~tp
    tn = ~has_revisit & ~accepted
    return Decisions(
        best_match=best_match,
        best_tme=best_tme,
        best_gtm=best_gtm,
        has_revisit=has_revisit,
        accepted=accepted,
        tp=tp,
        fp=fp,
        fn=fn,
        tn=tn,
        tau=tau,
        delta=delta,
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
    _, best_tme, _, has_revisit, correct = _best(tme_a, gtm_a, tau)
    if deltas is None:
        d = np.concatenate(([-np.inf], np.unique(best_tme[np.isfinite(best_tme)])))
    else:
        d = np.asarray(deltas if isinstance(deltas, np.ndarray) else list(deltas), dtype=float).ravel()
        if d.size == 0:
            raise ValueError("deltas must contain at least one threshold")
        if np.isnan(d).any():
            raise ValueError("deltas must not contain NaN")
    # TP(delta) = #correct best matches with best_tme <= delta, FP likewise for wrong ones.
    tme_correct = np.sort(best_tme[correct])
    tme_wrong = np.sort(best_tme[~correct & np.isfinite(best_tme)])  # no answer: never accepted
    tp = np.searchsorted(tme_correct, d, side="right").astype(np.int64)
    fp = np.searchsorted(tme_wrong, d, side="right").astype(np.int64)
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
        n_queries=int(tme_a.shape[0]),
    )


# --------------------------------------------------------------------------- recall@K


def recall_at_k(tme: ArrayLike, gtm: ArrayLike, tau: float, ks: Sequence[int] = (1, 5, 10)) -> dict[int, float]:
    """Fraction of queries with a true revisit for which one of the K lowest-TME references
    lies within ``tau`` (ties in TME broken towards the lower reference index).

    K larger than the number of references is clamped to it; 0.0 when no query has a revisit.
    """
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    ks_list = [int(k) for k in ks]
    if any(k < 1 for k in ks_list):
        raise ValueError(f"every K must be >= 1, got {ks_list}")
    has_revisit = gtm_a.min(axis=1) <= tau
    n_revisit = int(has_revisit.sum())
    if n_revisit == 0 or not ks_list:
        return {k: 0.0 for k in ks_list}
    n_ref = tme_a.shape[1]
    kmax = min(max(ks_list), n_ref)
    t = tme_a[has_revisit]
    g = gtm_a[has_revisit]
    order = np.argsort(t, axis=1, kind="stable")[:, :kmax]
    hit = (np.take_along_axis(g, order, axis=1) <= tau) & np.isfinite(np.take_along_axis(t, order, axis=1))
    hit_upto = np.logical_or.accumulate(hit, axis=1)  # hit within the first k candidates
    return {k: float(hit_upto[:, min(k, n_ref) - 1].mean()) for k in ks_list}


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
    auc_method, recall_at_100_precision, recall_at_k ({"1": ..., ...}, string keys so JSON round-trips), and when
    ``delta`` is given: delta, precision, recall, f1, tp, fp, fn, tn, n_accepted.
    ``curve``: the default-sweep `pr_curve` of the same matrices, when already computed.
    """
    tme_a, gtm_a = _check_matrices(tme, gtm)
    tau = _check_tau(tau)
    if curve is None:
        curve = pr_curve(tme_a, gtm_a, tau)
    rk = recall_at_k(tme_a, gtm_a, tau, ks)
    out: dict = {
        "n_queries": int(tme_a.shape[0]),
        "n_references": int(tme_a.shape[1]),
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
    }
    if delta is not None:
        dec = decide(tme_a, gtm_a, tau, delta)
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
