"""Point feature histogram (Rusu et al.) over one whisk cycle's contact points.

For every unordered pair of contacts (i, j) one point is chosen as the *source* s and the
other as the *target* t. As in Rusu's PFH (and PCL's ``computePairFeatures``) the source is
the point whose normal makes the smaller angle with the line joining the two points, i.e.
the larger ``|n . d| / |d|``; on an exact tie the lower-index point is the source. With
``d = p_t - p_s`` the Darboux frame is ``u = n_s``, ``v = d x u / |d x u|``, ``w = u x v`` and

    alpha = v . n_t                       in [-1, 1]
    phi   = u . d / |d|                   in [-1, 1]
    theta = atan2(w . n_t, u . n_t)       in [-pi, pi]

Each feature is cut into ``bins`` equal-width bins over its range (values on the upper edge
go into the last bin); the bin of a pair is ``(i_alpha * bins + i_phi) * bins + i_theta``.
The histogram counts the valid pairs and is scaled to sum to 100. Pairs are skipped when
the points coincide (``|d| <= EPS_DISTANCE``) or ``d`` is parallel to the source normal
(``|d x u| <= EPS_PARALLEL * |d|``), where the frame is undefined. Fewer than two contacts
(or no valid pair) gives all zeros. Normals are rescaled to unit length; contacts with a
zero normal are ignored. Everything is computed in float64 and vectorised over
the pairs; cycles with more than ``max_points`` contacts are subsampled deterministically
(evenly spaced indices), which bounds the cost at ``max_points * (max_points - 1) / 2`` pairs.

The ViTa-SLAM C++ code histograms only the normals' x, y, z components into a 3-D grid and
writes the result shifted by one slot (losing a bin); this module implements the PFH the
paper describes.
"""

from __future__ import annotations

import numpy as np

from vitaplace.plugin import Run

#: Pairs whose points are closer than this [m] are skipped (coincident contacts).
EPS_DISTANCE = 1e-9
#: Pairs with |d x n_s| <= EPS_PARALLEL * |d| (d parallel to the source normal) are skipped.
EPS_PARALLEL = 1e-9


def subsample(n: int, max_points: int) -> np.ndarray:
    """Deterministic evenly spaced indices selecting at most ``max_points`` of ``n``."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def pair_features(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(alpha, phi, theta) of every valid unordered pair, each (n_valid,) float64."""
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    n_len = np.linalg.norm(n, axis=1)
    usable = n_len > 0  # a contact without a normal cannot be a pair member
    p, n = p[usable], n[usable] / n_len[usable, None]
    i, j = np.triu_indices(len(p), k=1)
    d = p[j] - p[i]
    dist = np.linalg.norm(d, axis=1)
    ok = dist > EPS_DISTANCE
    i, j, d, dist = i[ok], j[ok], d[ok], dist[ok]
    cos_i = np.einsum("kd,kd->k", n[i], d) / dist
    cos_j = np.einsum("kd,kd->k", n[j], d) / dist
    # Source = the point whose normal is closer to the connecting line (larger |cos|).
    swap = np.abs(cos_j) > np.abs(cos_i)
    src = np.where(swap, j, i)
    tgt = np.where(swap, i, j)
    d = np.where(swap[:, None], -d, d)
    u = n[src]
    nt = n[tgt]
    v = np.cross(d, u)
    v_norm = np.linalg.norm(v, axis=1)
    ok = v_norm > EPS_PARALLEL * dist
    u, nt, d, dist, v, v_norm = u[ok], nt[ok], d[ok], dist[ok], v[ok], v_norm[ok]
    v = v / v_norm[:, None]
    w = np.cross(u, v)
    alpha = np.einsum("kd,kd->k", v, nt)
    phi = np.einsum("kd,kd->k", u, d) / dist
    theta = np.arctan2(np.einsum("kd,kd->k", w, nt), np.einsum("kd,kd->k", u, nt))
    return alpha, phi, theta


def _bin(values: np.ndarray, lo: float, hi: float, bins: int) -> np.ndarray:
    idx = np.floor((values - lo) * (bins / (hi - lo))).astype(np.int64)
    return np.clip(idx, 0, bins - 1)


def pfh(points: np.ndarray, normals: np.ndarray, bins: int = 3, max_points: int = 64) -> np.ndarray:
    """PFH of one contact set: (bins**3,) float32 summing to 100 (zeros without a valid pair)."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    out = np.zeros(bins**3, dtype=np.float32)
    points = np.asarray(points)
    normals = np.asarray(normals)
    if len(points) < 2:
        return out
    keep = subsample(len(points), max_points)
    alpha, phi, theta = pair_features(points[keep], normals[keep])
    if len(alpha) == 0:
        return out
    index = (_bin(alpha, -1.0, 1.0, bins) * bins + _bin(phi, -1.0, 1.0, bins)) * bins + _bin(
        theta, -np.pi, np.pi, bins
    )
    counts = np.bincount(index, minlength=bins**3).astype(np.float64)
    return (counts * (100.0 / counts.sum())).astype(np.float32)


def pfh_batch(run: Run, bins: int = 3, max_points: int = 64) -> np.ndarray:
    """PFH of every sample's whisk cycle: (N, bins**3) float32."""
    out = np.zeros((len(run), bins**3), dtype=np.float32)
    for k in range(len(run)):
        points, normals = run.contacts(k)
        if len(points) >= 2:
            out[k] = pfh(points, normals, bins, max_points)
    return out
