"""How hard an evaluation pair is, whatever the method: the nearest reference pose of each
query with a true match, the chance level of recall@1, the share of samples with touch, and
the longest stretch a run stayed in one place (`longest_stay`: a stuck drive).

The pose and threshold conventions are `vitaplace.engine.evaluation.evaluate`'s.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

from vitaplace.engine.evaluation.evaluate import _check_poses, _check_tau, _heading_difference_deg

__all__ = ["DIFFICULTY_KEYS", "STAY_RADIUS", "difficulty", "longest_stay"]


#: the keys of `difficulty`'s result, in order
DIFFICULTY_KEYS = (
    "nearest_ref_median_m", "nearest_ref_p90_m", "nearest_ref_heading_median_deg", "chance_r1",
    "query_touch_share", "reference_touch_share", "query_longest_stay_share", "reference_longest_stay_share",
)
#: a run "stays" in one place while its samples remain this close to the stay's first one [m]
STAY_RADIUS = 0.25


def longest_stay(xy, radius: float = STAY_RADIUS) -> tuple[int, int]:
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


def difficulty(
    query_poses, reference_poses, gtm, tau: float, query_touch=None, reference_touch=None
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
    """
    tau = _check_tau(tau)
    q = _check_poses(query_poses, "query_poses", need_yaw=False)
    r = _check_poses(reference_poses, "reference_poses", need_yaw=False)
    gtm_a = np.asarray(gtm, dtype=float)
    if gtm_a.shape != (len(q), len(r)) or np.isnan(gtm_a).any():
        raise ValueError(f"gtm must be a NaN-free queries x references ({len(q)}, {len(r)}) matrix, got shape {gtm_a.shape}")
    per_run = {}
    for role, mask, n in (("query", query_touch, len(q)), ("reference", reference_touch, len(r))):
        if mask is None:
            per_run[f"{role}_touch_share"] = None
            continue
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"{role}_touch must hold one value per {role} sample ({n}), got shape {mask.shape}")
        per_run[f"{role}_touch_share"] = float(mask.mean())
    for role, poses in (("query", q), ("reference", r)):
        per_run[f"{role}_longest_stay_share"] = longest_stay(poses[:, :2])[0] / len(poses)
    true_match = gtm_a <= tau
    matched = true_match.any(axis=1)
    if not matched.any():
        return {**dict.fromkeys(DIFFICULTY_KEYS[:4]), **per_run}
    position = cdist(q[matched, :2], r[:, :2], metric="euclidean")
    nearest = np.argmin(position, axis=1)
    distance = position[np.arange(len(nearest)), nearest]
    with_yaw = min(q.shape[1], r.shape[1]) >= 3
    heading = _heading_difference_deg(q[matched, 2], r[nearest, 2]) if with_yaw else None
    return {
        "nearest_ref_median_m": float(np.median(distance)),
        "nearest_ref_p90_m": float(np.percentile(distance, 90)),
        "nearest_ref_heading_median_deg": None if heading is None else float(np.median(heading)),
        "chance_r1": float(true_match[matched].mean(axis=1).mean()),
        **per_run,
    }
