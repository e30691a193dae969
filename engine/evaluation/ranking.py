"""What each query's row of a scored matrix says, read a chunk of queries at a time: the
evaluation in memory linear in the number of samples.

Every single-best-match measure (`vitaplace.engine.evaluation.evaluate`) needs, per query,
only its best distance, the references tied at it and how many of those are true matches,
and for recall@K the K nearest with the tie that straddles rank K: never the whole queries x
references matrix. `scan` reads the matrix (`Rows`: the method's distances, or the sequence
scores) in chunks of queries against every reference, at most `CHUNK_BYTES` of distances
per chunk, and keeps those per-query numbers (`QueryStats`); the ground truth comes as each
query's set of true matches (`GroundTruth`). Each query's numbers are computed from its own
row by the same operations whatever the chunk, so a chunked scan equals the whole-matrix one
bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["CHUNK_BYTES", "GroundTruth", "QueryStats", "Rows", "check_ks", "scan"]

#: the distances one chunk of queries holds (rows x references x 8 bytes); the scan's other
#: per-chunk arrays are a few times this
CHUNK_BYTES = 16 * 2**20


def chunk_rows(n_references: int, bytes_per_entry: int = 8) -> int:
    """Queries per chunk: as many rows of ``n_references`` entries as `CHUNK_BYTES` holds, at least 1."""
    return max(1, CHUNK_BYTES // (bytes_per_entry * max(n_references, 1)))


@dataclass(frozen=True)
class Rows:
    """A queries x references matrix read a block of rows at a time: ``read(start, stop)``
    returns rows ``start .. stop - 1``, shape ``(stop - start, n_references)``."""

    shape: tuple[int, int]
    read: Callable[[int, int], np.ndarray]

    @classmethod
    def of(cls, matrix: np.ndarray) -> Rows:
        """The rows of a matrix held whole."""
        m = np.asarray(matrix, dtype=float)
        return cls((int(m.shape[0]), int(m.shape[1])), lambda start, stop: m[start:stop])

    def chunks(self, rows: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """(first query, block) over the whole matrix, ``rows`` queries a block (default `chunk_rows`)."""
        n_q, n_r = self.shape
        step = rows or chunk_rows(n_r)
        for start in range(0, n_q, step):
            stop = min(start + step, n_q)
            block = np.asarray(self.read(start, stop), dtype=float)
            if block.shape != (stop - start, n_r):
                raise ValueError(f"rows {start}..{stop - 1} of the scored matrix have shape {block.shape}, "
                                 f"expected {(stop - start, n_r)}")
            yield start, block

    def whole(self) -> np.ndarray:
        """The matrix itself (every row at once)."""
        return np.asarray(self.read(0, self.shape[0]), dtype=float)


@dataclass(frozen=True)
class GroundTruth:
    """Each query's true matches (the references ``j`` with ``gtm[i, j] <= tau``), row by
    row in compressed form: query ``i``'s are ``indices[indptr[i]:indptr[i + 1]]``,
    ascending; ``at(rows, cols)`` is the ground-truth distance ``gtm[rows, cols]`` of any
    pairs (elementwise), for the best matches' ``best_gtm``."""

    tau: float
    n_references: int
    indptr: np.ndarray  # int (Q + 1,)
    indices: np.ndarray  # int (number of true pairs,)
    at: Callable[[np.ndarray, np.ndarray], np.ndarray]

    @classmethod
    def of_pairs(cls, tau: float, shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray,
                 at: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> GroundTruth:
        """From the true pairs ``(rows[n], cols[n])`` in any order, of a ``shape`` (queries, references) problem."""
        order = np.lexsort((cols, rows))
        counts = np.bincount(rows, minlength=shape[0])
        return cls(float(tau), int(shape[1]), np.concatenate(([0], np.cumsum(counts))), cols[order], at)

    @classmethod
    def of_matrix(cls, gtm: np.ndarray, tau: float) -> GroundTruth:
        """From a whole ground-truth matrix."""
        rows, cols = np.nonzero(gtm <= tau)
        return cls.of_pairs(tau, gtm.shape, rows, cols, lambda r, c: gtm[r, c])

    @property
    def n_queries(self) -> int:
        return len(self.indptr) - 1

    @property
    def counts(self) -> np.ndarray:
        """Per query, how many true matches it has."""
        return np.diff(self.indptr)

    @property
    def has_revisit(self) -> np.ndarray:
        """Per query, whether it has a true match (``min_j gtm[i, j] <= tau``)."""
        return self.counts > 0

    def mask(self, queries: np.ndarray) -> np.ndarray:
        """``gtm[queries] <= tau`` as a boolean block (``queries``: indices)."""
        starts, counts = self.indptr[queries], self.counts[queries]
        out = np.zeros((len(queries), self.n_references), dtype=bool)
        rows = np.repeat(np.arange(len(queries)), counts)
        within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)  # position in its row
        out[rows, self.indices[np.repeat(starts, counts) + within]] = True
        return out


@dataclass(frozen=True)
class QueryStats:
    """Per query, everything the single-best-match measures need (arrays of shape (Q,))."""

    best_tme: np.ndarray  # float: the best distance (+inf: no answer)
    best_match: np.ndarray  # int: the lowest index at it
    best_gtm: np.ndarray  # float: gtm at best_match
    n_best: np.ndarray  # int: references at the best distance (0: no answer)
    correct_share: np.ndarray  # float: the share of them that are true matches
    has_revisit: np.ndarray  # bool: the query has a true match
    hits: dict[int, np.ndarray]  # per K: the chance a true match is among the K nearest (revisit queries only)
    n_references: int
    tau: float

    def take(self, rows: np.ndarray) -> QueryStats:
        """The stats of the queries ``rows`` (indices, repeats allowed), in that order: what
        `scan` gives for those rows of the matrices, since a query's stats depend on its own
        row alone (a block-bootstrap replicate, scored without scanning again)."""
        revisit = self.has_revisit[rows]
        among_revisits = (np.cumsum(self.has_revisit) - 1)[rows][revisit]  # each one's place in ``hits``
        return QueryStats(best_tme=self.best_tme[rows], best_match=self.best_match[rows],
                          best_gtm=self.best_gtm[rows], n_best=self.n_best[rows],
                          correct_share=self.correct_share[rows], has_revisit=revisit,
                          hits={k: chance[among_revisits] for k, chance in self.hits.items()},
                          n_references=self.n_references, tau=self.tau)


def check_ks(ks: Sequence[int]) -> list[int]:
    """The K of recall@K as ints, each >= 1."""
    ks_list = [int(k) for k in ks]
    if any(k < 1 for k in ks_list):
        raise ValueError(f"every K must be >= 1, got {ks_list}")
    return ks_list


def _check_block(tme: np.ndarray, first: int) -> None:
    if np.isnan(tme).any():
        bad = np.argwhere(np.isnan(tme))
        raise ValueError(f"tme contains NaN (first at query {first + bad[0][0]}, reference {bad[0][1]})")
    if np.isneginf(tme).any():
        raise ValueError("tme contains -inf; TME entries must be distances (finite or +inf)")


def ties(tme: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: the best distance, how many references share it (0 where it is +inf: no
    answer) and the share of those that are true matches (``true``: ``gtm <= tau``; 0 without
    an answer: a query whose every distance is +inf, a method that cannot compare it, is
    never right)."""
    best_tme = tme.min(axis=1)
    at_best = tme == best_tme[:, None]
    answered = np.isfinite(best_tme)
    n_best = np.where(answered, at_best.sum(axis=1), 0)
    true_at_best = (at_best & true).sum(axis=1)
    correct_share = np.divide(true_at_best, n_best, out=np.zeros(len(tme)), where=n_best > 0)
    return best_tme, n_best, correct_share


def hits(tme: np.ndarray, true: np.ndarray, k: int) -> np.ndarray:
    """Per row, the chance that a true match is among the ``k`` nearest when ties are drawn at
    random (`vitaplace.engine.evaluation.evaluate.recall_at_k`): with ``L`` references strictly
    nearer than the k-th nearest distance ``v`` and ``m`` at ``v``, ``c`` of them true, 1 if
    a true match is among the ``L``, else ``1 - C(m - c, k - L) / C(m, k - L)``; an entry at
    +inf is never a hit."""
    true = true & np.isfinite(tme)
    kk = min(k, tme.shape[1])
    v = np.partition(tme, kk - 1, axis=1)[:, kk - 1 : kk]
    nearer, at_v = tme < v, tme == v
    drawn = kk - nearer.sum(axis=1)  # K - L, at least 1
    m, c = at_v.sum(axis=1), (at_v & true).sum(axis=1)
    miss = np.ones(len(tme))  # C(m - c, drawn) / C(m, drawn) as a product of drawn factors
    for i in range(int(drawn.max(initial=0))):
        miss *= np.where(i < drawn, np.maximum(m - c - i, 0) / np.maximum(m - i, 1), 1.0)
    return np.where((nearer & true).any(axis=1), 1.0, 1.0 - miss)


def scan(scored: Rows, truth: GroundTruth, ks: Sequence[int] = (), rows: int | None = None) -> QueryStats:
    """Each query's `QueryStats` from the scored matrix read ``rows`` queries at a time
    (default `chunk_rows`) against the ground truth ``truth``; the recall@K chances for each
    K of ``ks``. Raises on NaN or -inf in the scored matrix (naming the first entry)."""
    n_q, n_r = scored.shape
    if truth.n_queries != n_q or truth.n_references != n_r:
        raise ValueError(f"the ground truth is of {truth.n_queries} queries x {truth.n_references} references, "
                         f"the scored matrix {n_q} x {n_r}")
    ks_list = check_ks(ks)
    best_tme, correct_share = np.empty(n_q), np.empty(n_q)
    best_match, n_best = np.empty(n_q, dtype=np.intp), np.empty(n_q, dtype=np.intp)
    has_revisit = truth.has_revisit
    hit = {k: np.empty(int(has_revisit.sum())) for k in ks_list}
    done = 0  # revisit queries before the chunk
    for start, block in scored.chunks(rows):
        _check_block(block, start)
        stop = start + len(block)
        true = truth.mask(np.arange(start, stop))
        best_tme[start:stop], n_best[start:stop], correct_share[start:stop] = ties(block, true)
        best_match[start:stop] = np.argmin(block, axis=1)
        revisit = has_revisit[start:stop]
        n = int(revisit.sum())
        for k in ks_list:
            if n:
                hit[k][done : done + n] = hits(block[revisit], true[revisit], k)
        done += n
    return QueryStats(best_tme=best_tme, best_match=best_match, best_gtm=truth.at(np.arange(n_q), best_match),
                      n_best=n_best, correct_share=correct_share, has_revisit=has_revisit, hits=hit,
                      n_references=n_r, tau=truth.tau)
