"""Evaluation in linear memory (vitaplace.engine.evaluation.ranking and its users): scoring a
pair a chunk of queries at a time gives exactly, bit for bit, what the whole matrices give.

The reference is the whole-matrix computation written out in numpy below (the evaluation as
it was before it was chunked, with the tie rule of docs/DESIGN.md "Ties"), and
`ground_truth_matrix` for the ground truth; chunks of 1, 7 and every query; matrices with
ties at the best distance and at rank K, +inf entries and rows with no answer.
"""

from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation import pairfiles, ranking
from vitaplace.engine.evaluation.difficulty import difficulty, difficulty_from
from vitaplace.engine.evaluation.ranking import GroundTruth, Rows, scan
from vitaplace.engine.evaluation.sequence import sequence_rows, sequence_scores

# --------------------------------------------------------------------------- the reference


def reference(tme: np.ndarray, gtm: np.ndarray, tau: float, delta: float, ks: tuple[int, ...]) -> dict:
    """Every per-query and summary number from the whole matrices, as plainly as defined."""
    true = gtm <= tau
    has_revisit = gtm.min(axis=1) <= tau
    best_tme = tme.min(axis=1)
    at_best = tme == best_tme[:, None]
    n_best = np.where(np.isfinite(best_tme), at_best.sum(axis=1), 0)
    share = np.divide((at_best & true).sum(axis=1), n_best, out=np.zeros(len(tme)), where=n_best > 0)
    best_match = np.argmin(tme, axis=1)
    accepted = (best_tme <= delta) & np.isfinite(best_tme)
    recall = {}
    for k in ks:
        hits = []
        for i in np.flatnonzero(has_revisit):
            row, row_true = tme[i], true[i] & np.isfinite(tme[i])
            kk = min(k, len(row))
            v = np.sort(row)[kk - 1]
            nearer, at_v = row < v, row == v
            drawn, m, c = kk - nearer.sum(), at_v.sum(), (at_v & row_true).sum()
            hits.append(1.0 if (nearer & row_true).any() else 1.0 - math.comb(m - c, drawn) / math.comb(m, drawn))
        recall[k] = float(np.mean(hits)) if hits else 0.0
    return {"best_tme": best_tme, "best_match": best_match, "best_gtm": gtm[np.arange(len(gtm)), best_match],
            "n_best": n_best, "correct_share": share, "has_revisit": has_revisit, "accepted": accepted,
            "tp": np.where(accepted, share, 0.0), "recall": recall}


def random_pair(seed: int, n_q: int, n_r: int, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances on ``levels`` values (few: many ties), some +inf, one row all +inf; ground
    truth with some +inf (facing apart) and every fifth query without a true match at tau 1."""
    rng = np.random.default_rng(seed)
    tme = rng.integers(0, levels, (n_q, n_r)).astype(float)
    tme[rng.random((n_q, n_r)) < 0.1] = np.inf
    tme[n_q // 2] = np.inf
    gtm = rng.random((n_q, n_r)) * 3
    gtm[rng.random((n_q, n_r)) < 0.2] = np.inf
    gtm[::5] += 2.0  # queries without a true match
    return tme, gtm


PAIRS = [(seed, n_q, n_r, levels) for seed, (n_q, n_r, levels) in
         enumerate([(23, 17, 3), (23, 17, 40), (40, 9, 2), (12, 30, 1000)])]


@pytest.mark.parametrize("chunk", [1, 7, None])
@pytest.mark.parametrize("seed, n_q, n_r, levels", PAIRS)
def test_a_chunked_scan_equals_the_whole_matrix_reference(seed, n_q, n_r, levels, chunk):
    tme, gtm = random_pair(seed, n_q, n_r, levels)
    tau, ks = 1.0, (1, 2, 5, 10, 100)
    want = reference(tme, gtm, tau, 1.0, ks)
    assert (want["n_best"] > 1).any() == (levels < 1000) and 0 < want["has_revisit"].sum() < n_q  # revisits and not
    stats = scan(Rows.of(tme), GroundTruth.of_matrix(gtm, tau), ks, rows=chunk or n_q)
    dec = ev.decisions_from(stats, 1.0)
    for name in ("best_tme", "best_match", "best_gtm", "n_best", "correct_share", "has_revisit", "accepted", "tp"):
        assert np.array_equal(getattr(dec, name), want[name]), name
    got_recall = ev.recall_from(stats, ks)
    assert got_recall == pytest.approx(want["recall"], rel=1e-12, abs=0)  # the reference uses math.comb


@pytest.mark.parametrize("seed, n_q, n_r, levels", PAIRS)
def test_every_measure_is_the_same_whatever_the_chunk(seed, n_q, n_r, levels):
    tme, gtm = random_pair(seed, n_q, n_r, levels)
    truth = GroundTruth.of_matrix(gtm, 1.0)
    whole = scan(Rows.of(tme), truth, (1, 5, 10), rows=n_q)
    for rows in (1, 7):
        part = scan(Rows.of(tme), truth, (1, 5, 10), rows=rows)
        assert ev.summary_from(part, 2.0) == ev.summary_from(whole, 2.0)
        for field in ("deltas", "precision", "recall", "f1", "tp", "fp", "fn"):
            assert np.array_equal(getattr(ev.curve_from(part), field), getattr(ev.curve_from(whole), field))
        assert all(np.array_equal(part.hits[k], whole.hits[k]) for k in (1, 5, 10))


@pytest.mark.parametrize("seed, n_q, n_r, levels", PAIRS)
def test_the_stats_of_drawn_queries_are_those_of_their_rows_scanned_again(seed, n_q, n_r, levels):
    """A block-bootstrap replicate takes its queries' stats (`QueryStats.take`, repeats and
    revisit-less queries included) instead of scanning its rows: the same stats, every field."""
    tme, gtm = random_pair(seed, n_q, n_r, levels)
    truth = GroundTruth.of_matrix(gtm, 1.0)
    whole = scan(Rows.of(tme), truth, (1, 5, 10))
    rows = np.random.default_rng(seed).integers(0, n_q, size=2 * n_q)
    drawn = whole.take(rows)
    again = scan(Rows.of(tme[rows]), GroundTruth.of_matrix(gtm[rows], 1.0), (1, 5, 10))
    for field in ("best_tme", "best_match", "best_gtm", "n_best", "correct_share", "has_revisit"):
        assert np.array_equal(getattr(drawn, field), getattr(again, field)), field
    assert drawn.hits.keys() == again.hits.keys()
    assert all(np.array_equal(drawn.hits[k], again.hits[k]) for k in (1, 5, 10))
    assert ev.summary_from(drawn, 2.0) == ev.summary_from(again, 2.0)


def poses(seed: int, n: int, grid: bool) -> np.ndarray:
    """Poses on a 0.1 m grid with yaws in 15 degree steps (pairs exactly at tau and exactly at
    the heading tolerance), or anywhere."""
    rng = np.random.default_rng(seed)
    if grid:
        return np.column_stack([rng.integers(0, 12, (n, 2)) * 0.1, rng.integers(-12, 12, n) * np.pi / 12])
    return np.column_stack([rng.random((n, 2)) * 3, rng.uniform(-np.pi, np.pi, n)])


@pytest.mark.parametrize("grid", [True, False])
@pytest.mark.parametrize("tolerance", [None, 30.0, 0.0])
@pytest.mark.parametrize("tau", [0.0, 0.2, 0.5])
def test_the_k_d_tree_ground_truth_is_the_matrix_s(grid, tolerance, tau):
    q, r = poses(1, 300, grid), poses(2, 250, grid)
    gtm = ev.ground_truth_matrix(q, r, tolerance)
    truth = ev.true_matches(q, r, tau, tolerance)
    assert np.array_equal(truth.mask(np.arange(len(q))), gtm <= tau)
    assert np.array_equal(truth.has_revisit, gtm.min(axis=1) <= tau)
    rows, cols = np.nonzero(np.ones(gtm.shape, dtype=bool))
    assert np.array_equal(truth.at(rows, cols), gtm[rows, cols])  # every pair, same arithmetic
    if grid and tau == 0.2:  # the grid puts pairs exactly at tau: at 0.2 m both ways of rounding occur
        assert (np.abs(gtm - 0.2) < 1e-12).any()


@pytest.mark.parametrize("chunk", [1, 7, 64])
@pytest.mark.parametrize("length, window", [(2, 3), (5, 10), (9, 1)])
def test_sequence_scores_in_chunks_equal_the_whole_matrix(chunk, length, window):
    rng = np.random.default_rng(length)
    d = rng.random((40, 33))
    d[rng.random(d.shape) < 0.05] = np.inf
    whole = sequence_scores(d, length, (0.8, 1.25), 5, window)
    rows = sequence_rows(Rows.of(d), length, (0.8, 1.25), 5, window)
    assert np.array_equal(np.vstack([block for _, block in rows.chunks(chunk)]), whole)


@pytest.mark.parametrize("tolerance", [None, 30.0])
def test_difficulty_from_the_true_matches_equals_the_matrix_s(tolerance, monkeypatch):
    q, r = poses(3, 200, False), poses(4, 150, False)
    rng = np.random.default_rng(5)
    touch = rng.random(200) < 0.4, rng.random(150) < 0.3
    want = difficulty(q, r, ev.ground_truth_matrix(q, r, tolerance), 0.3, *touch)
    monkeypatch.setattr(ranking, "CHUNK_BYTES", 8 * 150 * 7)  # chunks of 7 queries
    assert difficulty_from(q, r, ev.true_matches(q, r, 0.3, tolerance), *touch) == want
    assert want["touch_both_share"] is not None


def drive(n: int, seed: int) -> np.ndarray:
    """A loop of n samples around a 4 x 3 m rectangle (the quickstart's size) with jitter."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 2 * np.pi, n, endpoint=False) * 1.6
    xy = np.column_stack([2 * np.cos(s), 1.5 * np.sin(s)]) + rng.normal(0, 0.05, (n, 2))
    return np.column_stack([xy, s + np.pi / 2 + rng.normal(0, 0.2, n)])


@pytest.mark.parametrize("sequence", [None, {"length": 4, "velocities": (0.8, 1.25), "velocity_steps": 3,
                                              "window": 5}])
def test_a_quickstart_sized_pair_scored_in_chunks_writes_the_same_files(tmp_path, monkeypatch, caplog, sequence):
    """450 queries x 400 references as quickstart's E1: whole (today's path, matrices written)
    and in chunks of queries (the bound lowered below the pair: matrices.npz skipped)."""
    q, r = drive(450, 0), drive(400, 1)
    rng = np.random.default_rng(2)
    features_q, features_r = q[:, :2] + rng.normal(0, 0.3, (450, 2)), r[:, :2]
    distances = np.round(np.hypot(*(features_q[:, None] - features_r[None]).transpose(2, 0, 1)), 1)  # ties
    args = dict(tau=0.3, delta=0.2, ks=(1, 5, 10), heading_tolerance_deg=30.0,
                query_touch=rng.random(450) < 0.3, reference_touch=rng.random(400) < 0.3, sequence=sequence)
    whole = pairfiles.evaluate_pair(tmp_path / "whole", distances, q, r, **args)
    monkeypatch.setattr(pairfiles, "FULL_MATRIX_LIMIT", 450 * 400 - 1)
    monkeypatch.setattr(ranking, "CHUNK_BYTES", 8 * 400 * 64)  # chunks of 64 queries
    read = []

    def rows(start: int, stop: int) -> np.ndarray:
        read.append(stop - start)
        return distances[start:stop]

    with caplog.at_level(logging.WARNING, "vitaplace"):
        chunked = pairfiles.evaluate_pair(tmp_path / "chunked", Rows((450, 400), rows), q, r, **args)
    assert json.loads(json.dumps(chunked)) == json.loads(json.dumps(whole))
    assert (whole["tied_share"] > 0) == (sequence is None) and whole["n_revisit"] > 0  # sequences untie
    assert max(read) <= 64 + (sequence or {"length": 1})["length"] - 1  # a chunk (and the lines' queries before it)
    assert "matrices.npz not written" in caplog.text
    assert (tmp_path / "whole" / "matrices.npz").exists() and not (tmp_path / "chunked" / "matrices.npz").exists()
    for name in ("decisions.csv",):
        assert (tmp_path / "chunked" / name).read_text() == (tmp_path / "whole" / name).read_text()
    for name in ("decisions.npz", "pr_curve.npz"):
        with np.load(tmp_path / "whole" / name) as a, np.load(tmp_path / "chunked" / name) as b:
            assert sorted(a) == sorted(b) and all(np.array_equal(a[k], b[k]) for k in a)
    if sequence is None:  # today's evaluation of the whole matrices, function by function
        gtm = ev.ground_truth_matrix(q, r, 30.0)
        want = reference(distances, gtm, 0.3, 0.2, (1, 5, 10))
        assert whole["recall_at_k"] == pytest.approx({str(k): v for k, v in want["recall"].items()}, rel=1e-12)
        assert whole["tp"] == pytest.approx(want["tp"].sum(), rel=1e-12)
        assert whole["n_revisit"] == int(want["has_revisit"].sum())
