"""Sequence matching (SeqSLAM, Milford & Wyeth 2012): a query is matched by the sequence of
queries that ends at it, not by itself alone.

From a method's distance matrix ``D`` (queries x references, both in drive order):

1. **Local contrast** — each entry is normalised against the references around it in its
   query's row: ``D^[i, j] = (D[i, j] - mean) / std`` over the references ``j - window ..
   j + window`` (cut at the run's ends) of row ``i``; a window whose spread is 0 (below
   `FLAT` of its mean: rounding) is divided by 1. Only finite entries enter the window's
   statistics; a +inf entry (a pair the method cannot compare) stays +inf.
2. **Straight lines** — for query ``i``, reference ``j`` and each relative velocity ``v``
   (``velocity_steps`` values evenly spaced over ``velocities``, references per query), the
   line through the last ``length`` queries ``k = i - length + 1 .. i`` meets references
   ``round(j + v * (k - i))``; its score is the mean of ``D^`` over the line's finite terms.
   A line that leaves the reference run (a reference before its first sample) is no
   candidate (+inf), as in SeqSLAM: a mean over fewer terms is more extreme, and lines cut
   short at the run's start would win the lowest score by that alone. ``S[i, j]`` is the
   best (lowest) score over the velocities; a line with no finite term is +inf. The first
   queries of a run have shorter lines (only the queries that exist; every candidate of the
   query alike).

``S`` replaces ``D`` for the best match, the PR curve and recall@K. ``length: 1`` is
single-sample matching: ``S`` is ``D`` itself, bit for bit (no contrast step either).

**Over travelled distance** (``metres``: SeqSLAM with odometry, as in Pepperell et al.'s
SMART, 2014): step 2 follows the odometry instead of straight lines. Each run's travelled
distance ``t`` is its path length from its first sample (`travelled`: the sum of ``|delta
xy|`` of its poses). Query ``i``'s sequence is ``length`` points evenly spaced over the last
``metres`` of its drive, ``t_q[i] - m`` for ``m = 0, metres / (length - 1), .. metres``, each
the query sample nearest to it in travelled distance (`points_back`); reference ``j``'s
points are the reference samples at the same distances back from ``t_r[j]``. ``S[i, j]`` is
the mean of ``D^`` over the pairs of points (the ``k``-th query point with the ``k``-th
reference point) that are finite; a reference whose points run back before its run's start
where the query's do not is no candidate (+inf), as a line that leaves the reference run; no
velocities are searched, since both sequences advance in metres. A robot that stops adds samples, not points, so a stop
does not change a sequence. ``metres: 0`` (every point the query itself) or ``length: 1`` is
single-sample matching, ``S`` is ``D`` bit for bit.

Both steps read only rows of ``D``: a block of queries' scores needs ``D``'s rows of those
queries and the ``length - 1`` before them, so `sequence_rows` computes ``S`` a chunk of
queries at a time (memory linear in the number of references), the same numbers as
`sequence_scores` computes for the whole matrix (over travelled distance: the rows of the
block's query points, at most ``length`` per query).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from vitaplace.engine.evaluation.ranking import Rows, chunk_rows

__all__ = ["local_contrast", "points_back", "sequence_rows", "sequence_scores", "travelled"]

#: a window's spread below this share of its mean is a flat window (rounding, not contrast)
FLAT = 1e-12


def local_contrast(distances: np.ndarray, window: int) -> np.ndarray:
    """Each row's entries minus the mean, divided by the standard deviation, of the finite
    entries of that row within ``window`` references on either side (step 1 above); a spread
    below `FLAT` of the window's mean counts as 0 (divided by 1)."""
    d = np.asarray(distances, dtype=float)
    window = min(window, d.shape[1])  # a wider window covers the row all the same
    finite = np.isfinite(d)
    padded = np.pad(np.where(finite, d, np.nan), ((0, 0), (window, window)), constant_values=np.nan)
    out = np.empty_like(d)
    at_once = chunk_rows(d.shape[1] * (2 * window + 1))  # the windows: rows x references x window
    for start in range(0, len(d), at_once):
        rows = slice(start, start + at_once)
        near = sliding_window_view(padded[rows], 2 * window + 1, axis=1)  # (rows, references, window)
        ok = ~np.isnan(near)
        count = np.maximum(ok.sum(axis=2), 1)
        mean = np.where(ok, near, 0.0).sum(axis=2) / count
        # two passes: exact for flat windows
        spread = np.sqrt((np.where(ok, near - mean[..., None], 0.0) ** 2).sum(axis=2) / count)
        spread = np.where(spread > FLAT * np.abs(mean), spread, 1.0)
        out[rows] = np.where(finite[rows], (np.where(finite[rows], d[rows], 0.0) - mean) / spread, np.inf)
    return out


def travelled(poses: np.ndarray) -> np.ndarray:
    """Each sample's path length [m] from the run's first: the sum of ``|delta xy|`` along the
    drive up to it (turning on the spot travels nothing)."""
    xy = np.asarray(poses, dtype=float)[:, :2]
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def points_back(distance: np.ndarray, samples: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """For each of ``samples`` (indices into a run whose travelled distances are ``distance``,
    non-decreasing) and each of ``steps`` (metres back), the run's sample nearest in travelled
    distance to that point (of several equally near, as at a stop, the last), never after the
    sample itself; -1 where the point lies before the run's start. Shape
    ``(len(samples), len(steps))``."""
    at = distance[samples][:, None] - steps[None, :]
    before = np.searchsorted(distance, at, side="right") - 1  # the last sample at or before the point
    earlier = np.maximum(before, 0)
    after = distance[np.minimum(before + 1, len(distance) - 1)]  # the next distance the run reaches
    later = np.searchsorted(distance, after, side="right") - 1  # its last sample (a stop: several)
    nearest = np.where(distance[later] - at <= at - distance[earlier], later, earlier)
    return np.where(at < 0, -1, np.minimum(nearest, samples[:, None]))


def sequence_scores(
    distances: np.ndarray, length: int, velocities: tuple[float, float] = (0.8, 1.25), velocity_steps: int = 5,
    window: int = 10, metres: float | None = None, poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The sequence score ``S`` of every (query, reference) pair (module docstring); ``length``
    1 or ``metres`` 0 returns ``distances`` unchanged."""
    return sequence_rows(Rows.of(distances), length, velocities, velocity_steps, window, metres, poses).whole()


def sequence_rows(
    distances: Rows, length: int, velocities: tuple[float, float] = (0.8, 1.25), velocity_steps: int = 5,
    window: int = 10, metres: float | None = None, poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> Rows:
    """`sequence_scores` of a matrix read in blocks of rows: a block of queries' scores from
    the distance rows of those queries and the ``length - 1`` before them, or, with ``metres``
    (which needs ``poses``: the query and the reference run's), of their points."""
    if length == 1 or metres == 0:
        return distances
    if metres is not None:
        if poses is None:
            raise ValueError("sequence_rows: metres needs the query and reference poses")
        return _odometry_rows(distances, length, window, metres, poses)

    def read(start: int, stop: int) -> np.ndarray:
        first = max(0, start - length + 1)
        contrast = local_contrast(distances.read(first, stop), window)
        return _line_scores(contrast, first, start, stop, length, velocities, velocity_steps)

    return Rows(distances.shape, read)


def _odometry_rows(distances: Rows, length: int, window: int, metres: float,
                   poses: tuple[np.ndarray, np.ndarray]) -> Rows:
    """`sequence_rows` over travelled distance (module docstring, "Over travelled distance")."""
    steps = np.linspace(0.0, metres, length)
    query_t, reference_t = travelled(poses[0]), travelled(poses[1])
    references = points_back(reference_t, np.arange(len(reference_t)), steps)  # (references, length)

    def read(start: int, stop: int) -> np.ndarray:
        queries = points_back(query_t, np.arange(start, stop), steps)  # (queries, length)
        needed = np.unique(queries[queries >= 0])  # every query's own sample among them
        runs = np.split(needed, np.flatnonzero(np.diff(needed) > 1) + 1)  # contiguous stretches
        contrast = local_contrast(np.concatenate([distances.read(r[0], r[-1] + 1) for r in runs]), window)
        shape = (stop - start, distances.shape[1])
        total, terms, leaves = np.zeros(shape), np.zeros(shape), np.zeros(shape, dtype=bool)
        for k in range(length):
            rows, cols = np.searchsorted(needed, queries[:, k]), references[:, k]
            leaves |= (queries[:, k, None] >= 0) & (cols[None, :] < 0)
            term = np.where((queries[:, k, None] >= 0) & (cols[None, :] >= 0),
                            contrast[np.ix_(np.minimum(rows, len(needed) - 1), cols)], np.inf)
            finite = np.isfinite(term)
            total += np.where(finite, term, 0.0)
            terms += finite
        return np.divide(total, terms, out=np.full(shape, np.inf), where=(terms > 0) & ~leaves)

    return Rows(distances.shape, read)


def _line_scores(contrast: np.ndarray, first: int, start: int, stop: int, length: int,
                 velocities: tuple[float, float], velocity_steps: int) -> np.ndarray:
    """Rows ``start .. stop - 1`` of ``S`` (step 2) from the contrast rows ``first .. stop - 1``."""
    n_ref = contrast.shape[1]
    shape = (stop - start, n_ref)
    offsets = np.arange(-(length - 1), 1)  # k - i for the queries of the line
    best = np.full(shape, np.inf)
    for v in np.linspace(velocities[0], velocities[1], velocity_steps):
        total, terms, leaves = np.zeros(shape), np.zeros(shape), np.zeros(shape, dtype=bool)
        for offset in offsets:
            rows = np.arange(start, stop) + offset
            cols = np.rint(np.arange(n_ref) + v * offset).astype(int)
            row_ok, col_ok = (rows >= 0), (cols >= 0) & (cols < n_ref)
            leaves |= np.outer(row_ok, ~col_ok)
            term = np.full(shape, np.inf)
            term[np.ix_(row_ok, col_ok)] = contrast[np.ix_(rows[row_ok] - first, cols[col_ok])]
            finite = np.isfinite(term)
            total += np.where(finite, term, 0.0)
            terms += finite
        score = np.divide(total, terms, out=np.full(shape, np.inf), where=(terms > 0) & ~leaves)
        best = np.minimum(best, score)
    return best
