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
   ``round(j + v * (k - i))``; its score is the mean of ``D^`` over the line's terms that are
   inside the reference run and finite. ``S[i, j]`` is the best (lowest) score over the
   velocities; a line with no finite term is +inf. The first queries of a run have shorter
   lines (only the queries that exist).

``S`` replaces ``D`` for the best match, the PR curve and recall@K. ``length: 1`` is
single-sample matching: ``S`` is ``D`` itself, bit for bit (no contrast step either).

Both steps read only rows of ``D``: a block of queries' scores needs ``D``'s rows of those
queries and the ``length - 1`` before them, so `sequence_rows` computes ``S`` a chunk of
queries at a time (memory linear in the number of references), the same numbers as
`sequence_scores` computes for the whole matrix.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from vitaplace.engine.evaluation.ranking import Rows, chunk_rows

__all__ = ["local_contrast", "sequence_rows", "sequence_scores"]

#: a window's spread below this share of its mean is a flat window (rounding, not contrast)
FLAT = 1e-12


def local_contrast(distances: np.ndarray, window: int) -> np.ndarray:
    """Each row's entries minus the mean, divided by the standard deviation, of the finite
    entries of that row within ``window`` references on either side (step 1 above); a spread
    below `FLAT` of the window's mean counts as 0 (divided by 1)."""
    d = np.asarray(distances, dtype=float)
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


def sequence_scores(
    distances: np.ndarray, length: int, velocities: tuple[float, float] = (0.8, 1.25), velocity_steps: int = 5,
    window: int = 10,
) -> np.ndarray:
    """The sequence score ``S`` of every (query, reference) pair (module docstring); ``length``
    1 returns ``distances`` unchanged."""
    d = np.asarray(distances, dtype=float)
    if length == 1:
        return d
    return sequence_rows(Rows.of(d), length, velocities, velocity_steps, window).whole()


def sequence_rows(
    distances: Rows, length: int, velocities: tuple[float, float] = (0.8, 1.25), velocity_steps: int = 5,
    window: int = 10,
) -> Rows:
    """`sequence_scores` of a matrix read in blocks of rows: a block of queries' scores from
    the distance rows of those queries and the ``length - 1`` before them."""
    if length == 1:
        return distances

    def read(start: int, stop: int) -> np.ndarray:
        first = max(0, start - length + 1)
        contrast = local_contrast(distances.read(first, stop), window)
        return _line_scores(contrast, first, start, stop, length, velocities, velocity_steps)

    return Rows(distances.shape, read)


def _line_scores(contrast: np.ndarray, first: int, start: int, stop: int, length: int,
                 velocities: tuple[float, float], velocity_steps: int) -> np.ndarray:
    """Rows ``start .. stop - 1`` of ``S`` (step 2) from the contrast rows ``first .. stop - 1``."""
    n_ref = contrast.shape[1]
    shape = (stop - start, n_ref)
    offsets = np.arange(-(length - 1), 1)  # k - i for the queries of the line
    best = np.full(shape, np.inf)
    for v in np.linspace(velocities[0], velocities[1], velocity_steps):
        total = np.zeros(shape)
        terms = np.zeros(shape)
        for offset in offsets:
            rows = np.arange(start, stop) + offset
            cols = np.rint(np.arange(n_ref) + v * offset).astype(int)
            row_ok, col_ok = (rows >= 0), (cols >= 0) & (cols < n_ref)
            term = np.full(shape, np.inf)
            term[np.ix_(row_ok, col_ok)] = contrast[np.ix_(rows[row_ok] - first, cols[col_ok])]
            finite = np.isfinite(term)
            total += np.where(finite, term, 0.0)
            terms += finite
        score = np.divide(total, terms, out=np.full(shape, np.inf), where=terms > 0)
        best = np.minimum(best, score)
    return best
