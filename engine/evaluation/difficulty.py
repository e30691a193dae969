"""How hard an evaluation pair is, whatever the method: the nearest reference pose of each
query with a true match, the chance level of recall@1, the share of samples with touch,
whether touch is shared by a query and its true match (`touch_at_true_matches`: whether
touch *can* matter), and the longest stretch a run stayed in one place (`longest_stay`: a
stuck drive).

The pose and threshold conventions are `vitaplace.engine.evaluation.evaluate`'s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.distance import cdist

from vitaplace.engine.evaluation.evaluate import _check_poses, _check_tau, _heading_difference_deg
from vitaplace.engine.evaluation.ranking import GroundTruth, chunk_rows

__all__ = ["DIFFICULTY_KEYS", "STAY_RADIUS", "TOUCH_PAIR_KEYS", "difficulty", "difficulty_from", "longest_stay",
           "nearest_references", "touch_at_true_matches"]


#: the keys of `difficulty`'s result, in order
DIFFICULTY_KEYS = (
    "nearest_ref_median_m", "nearest_ref_p90_m", "nearest_ref_heading_median_deg", "chance_r1",
    "query_touch_share", "reference_touch_share", "query_longest_stay_share", "reference_longest_stay_share",
    "touch_both_share", "touch_one_side_share", "touch_correspondence",
)
#: the keys of `touch_at_true_matches`'s result (the last three of `DIFFICULTY_KEYS`)
TOUCH_PAIR_KEYS = DIFFICULTY_KEYS[-3:]
#: a run "stays" in one place while its samples remain this close to the stay's first one [m]
STAY_RADIUS = 0.25


def longest_stay(xy: ArrayLike, radius: float = STAY_RADIUS) -> tuple[int, int]:
    """(length, first index) of the longest stretch of consecutive samples of the (N, 2)
    positions ``xy`` that stay within ``radius`` of the stretch's first sample (ties: the
    earliest). A drive that stops to whisk a landmark stays a few samples; one that got stuck
    stays for the rest of its run."""
    xy = np.asarray(xy, dtype=float)
    best = (0, 0)
    for i in range(len(xy)):
        away = np.flatnonzero(np.hypot(*(xy[i:] - xy[i]).T) > radius)
        best = max(best, (int(away[0]) if len(away) else len(xy) - i, -i))
    return best[0], -best[1]


def nearest_references(
    query_xy: np.ndarray, reference_xy: np.ndarray, truth: GroundTruth,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(matched, nearest, distance, partner): the queries with a true match (ascending), each
    one's nearest reference by position (ties -> lowest index) and that distance, and its
    *pose-nearest true match* (the reference nearest by position among its true matches,
    ties -> lowest index); a chunk of queries against every reference at a time."""
    matched = np.flatnonzero(truth.has_revisit)
    nearest, partner = np.empty(len(matched), dtype=np.intp), np.empty(len(matched), dtype=np.intp)
    distance = np.empty(len(matched))
    step = chunk_rows(len(reference_xy))
    for lo in range(0, len(matched), step):
        rows = matched[lo : lo + step]
        here = slice(lo, lo + len(rows))
        position = cdist(query_xy[rows], reference_xy, metric="euclidean")
        nearest[here] = np.argmin(position, axis=1)
        distance[here] = position[np.arange(len(rows)), nearest[here]]
        partner[here] = np.argmin(np.where(truth.mask(rows), position, np.inf), axis=1)
    return matched, nearest, distance, partner


def touch_at_true_matches(
    matched: np.ndarray, partner: np.ndarray, query_touch: np.ndarray | None, reference_touch: np.ndarray | None,
) -> dict[str, float | None]:
    """Whether touch is shared by a query and its true match (`TOUCH_PAIR_KEYS`).

    A *true-match pair* is each query that has a true match (the indices ``matched``) with
    its pose-nearest true match (``partner``, `nearest_references`). Over those pairs,
    ``touch_both_share`` is the share touched on both sides and ``touch_one_side_share`` the
    share touched on exactly one side (both None when no query has a true match);
    ``touch_correspondence`` is, among the touched queries that have a true match, the share
    whose pose-nearest true match is touched (None when no touched query has one). The touch
    masks hold one bool per sample (`Run.touch_mask`); all three are None without them.
    """
    if query_touch is None or reference_touch is None or not len(matched):
        return dict.fromkeys(TOUCH_PAIR_KEYS)
    q_touch, r_touch = query_touch[matched], reference_touch[partner]
    return {
        "touch_both_share": float((q_touch & r_touch).mean()),
        "touch_one_side_share": float((q_touch ^ r_touch).mean()),
        "touch_correspondence": float(r_touch[q_touch].mean()) if q_touch.any() else None,
    }


def difficulty(
    query_poses: ArrayLike, reference_poses: ArrayLike, gtm: ArrayLike, tau: float,
    query_touch: ArrayLike | None = None, reference_touch: ArrayLike | None = None,
) -> dict[str, float | None]:
    """How hard an evaluation pair is, whatever the method (`DIFFICULTY_KEYS`, plain floats).

    Over the queries with a true match (``min_j gtm[i, j] <= tau``): each query's nearest
    reference *by position* (ties -> lowest index), its distance (median ``nearest_ref_median_m``
    and 90th percentile ``nearest_ref_p90_m``, numpy's linear interpolation) and its wrapped
    heading difference (median ``nearest_ref_heading_median_deg``); ``chance_r1`` the mean
    share of references that are true matches (recall@1 of a uniformly random guess).
    These four are None when no query has a true match (the heading median also when the
    poses are (N, 2), without yaw). ``query_touch_share`` and
    ``reference_touch_share``: the share of samples with touch (the boolean masks given, one
    value per sample, e.g. `Run.touch_mask`; None when no mask is given).
    ``query_longest_stay_share`` and ``reference_longest_stay_share``: the `longest_stay`
    of each run as a share of its samples (a stuck drive shows as a large share).
    ``touch_both_share``, ``touch_one_side_share`` and ``touch_correspondence``: whether
    touch is shared by a query and its true match (`touch_at_true_matches`).
    """
    tau = _check_tau(tau)
    q = _check_poses(query_poses, "query_poses", need_yaw=False)
    r = _check_poses(reference_poses, "reference_poses", need_yaw=False)
    gtm_a = np.asarray(gtm, dtype=float)
    if gtm_a.shape != (len(q), len(r)) or np.isnan(gtm_a).any():
        raise ValueError(
            f"gtm must be a NaN-free queries x references ({len(q)}, {len(r)}) matrix, got shape {gtm_a.shape}")
    return difficulty_from(q, r, GroundTruth.of_matrix(gtm_a, tau), query_touch, reference_touch)


def difficulty_from(
    query_poses: np.ndarray, reference_poses: np.ndarray, truth: GroundTruth,
    query_touch: ArrayLike | None = None, reference_touch: ArrayLike | None = None,
) -> dict[str, float | None]:
    """`difficulty` from each query's true matches (`GroundTruth`, e.g.
    `vitaplace.engine.evaluation.evaluate.true_matches`) instead of the matrix: memory linear
    in the number of samples."""
    q, r = np.asarray(query_poses, dtype=float), np.asarray(reference_poses, dtype=float)
    per_run: dict[str, float | None] = {}
    masks: dict[str, np.ndarray | None] = {}
    for role, mask, n in (("query", query_touch, len(q)), ("reference", reference_touch, len(r))):
        if mask is None:
            per_run[f"{role}_touch_share"] = masks[role] = None
            continue
        masks[role] = mask = np.asarray(mask, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"{role}_touch must hold one value per {role} sample ({n}), got shape {mask.shape}")
        per_run[f"{role}_touch_share"] = float(mask.mean())
    for role, poses in (("query", q), ("reference", r)):
        per_run[f"{role}_longest_stay_share"] = longest_stay(poses[:, :2])[0] / len(poses)
    matched, nearest, distance, partner = nearest_references(q[:, :2], r[:, :2], truth)
    per_run.update(touch_at_true_matches(matched, partner, masks["query"], masks["reference"]))
    if not len(matched):
        return {**dict.fromkeys(DIFFICULTY_KEYS[:4]), **per_run}
    with_yaw = min(q.shape[1], r.shape[1]) >= 3
    heading = _heading_difference_deg(q[matched, 2], r[nearest, 2]) if with_yaw else None
    return {
        "nearest_ref_median_m": float(np.median(distance)),
        "nearest_ref_p90_m": float(np.percentile(distance, 90)),
        "nearest_ref_heading_median_deg": None if heading is None else float(np.median(heading)),
        "chance_r1": float((truth.counts[matched] / len(r)).mean()),
        **per_run,
    }
