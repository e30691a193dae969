"""Tests of vitaplace.engine.evaluation.evaluate and vitaplace.engine.report.figures.

Expected values come from hand derivations (comments), scikit-learn, an independent
per-query loop of the definition (docs/RESULTS.md, evaluation), and an independent re-implementation of
VPR_Tutorial's createPR(..., matching='single') — never from the code under test.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from sklearn.metrics import average_precision_score, precision_recall_curve

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation.difficulty import difficulty, longest_stay
from vitaplace.engine.evaluation.pairfiles import (
    evaluate_pair,
    export_decisions_csv,
    export_matrices_npz,
    load_curve,
    load_decisions,
    save_curve_and_decisions,
)

# --------------------------------------------------------------------------- hand case
# 5 queries x 4 references, tau = 1.0.
#
# GTM (ground truth):             min   revisit?
#   q0: 0.2  2.0  3.0  4.0        0.2   yes
#   q1: 2.0  0.5  3.0  4.0        0.5   yes
#   q2: 3.0  3.0  3.0  3.0        3.0   no
#   q3: 0.9  5.0  5.0  5.0        0.9   yes
#   q4: 5.0  5.0  5.0  5.0        5.0   no
# TME (feature distance):         j*  best_tme  gtm[i,j*]  correct?
#   q0: 0.1  0.9  0.8  0.7        0   0.1       0.2        yes
#   q1: 0.3  0.6  0.9  0.9        0   0.3       2.0        no
#   q2: 0.9  0.4  0.8  0.8        1   0.4       3.0        no
#   q3: 0.7  0.8  0.9  0.75       0   0.7       0.9        yes
#   q4: 0.6  0.6  0.9  0.9        0   0.6 (tie j=0/j=1, both wrong)  5.0  no
# (No tie decides anything here: q4's tie is of two wrong references, so every number is
# that of the lowest-index rule too; TIED_* below is the case where ties decide.)
# At delta = 0.5: accepted q0, q1, q2.
#   q0 TP; q1 FP and FN (accepted, wrong, a revisit existed); q2 FP (no revisit);
#   q3 FN (rejected, revisit); q4 TN.  => TP 1, FP 2, FN 2, TN 1; TP + FN = 3 = #revisit.
#   precision 1/3, recall 1/3, F1 1/3.
HAND_GTM = np.array(
    [
        [0.2, 2.0, 3.0, 4.0],
        [2.0, 0.5, 3.0, 4.0],
        [3.0, 3.0, 3.0, 3.0],
        [0.9, 5.0, 5.0, 5.0],
        [5.0, 5.0, 5.0, 5.0],
    ]
)
HAND_TME = np.array(
    [
        [0.1, 0.9, 0.8, 0.7],
        [0.3, 0.6, 0.9, 0.9],
        [0.9, 0.4, 0.8, 0.8],
        [0.7, 0.8, 0.9, 0.75],
        [0.6, 0.6, 0.9, 0.9],
    ]
)
HAND_TAU = 1.0

# PR sweep, deltas = -inf + distinct best_tme values (0.1 c, 0.3 w, 0.4 w, 0.6 w, 0.7 c):
#   delta  TP FP FN  P     R     F1
#   -inf   0  0  3   1     0     0
#   0.1    1  0  2   1     1/3   2(1/3)/(4/3) = 1/2
#   0.3    1  1  2   1/2   1/3   2(1/6)/(5/6) = 2/5
#   0.4    1  2  2   1/3   1/3   1/3
#   0.6    1  3  2   1/4   1/3   2(1/12)/(7/12) = 2/7
#   0.7    2  3  1   2/5   2/3   2(4/15)/(16/15) = 1/2
# max F1 = 1/2, reached at 0.1 and 0.7 -> smallest delta 0.1.
# AUC (step-wise AP) = (1/3 - 0)*1 + (2/3 - 1/3)*(2/5) = 1/3 + 2/15 = 7/15.
HAND_DELTAS = [-np.inf, 0.1, 0.3, 0.4, 0.6, 0.7]
HAND_TP = [0, 1, 1, 1, 1, 2]
HAND_FP = [0, 0, 1, 2, 3, 3]
HAND_FN = [3, 2, 2, 2, 2, 1]
HAND_P = [1.0, 1.0, 1 / 2, 1 / 3, 1 / 4, 2 / 5]
HAND_R = [0.0, 1 / 3, 1 / 3, 1 / 3, 1 / 3, 2 / 3]
HAND_F1 = [0.0, 1 / 2, 2 / 5, 1 / 3, 2 / 7, 1 / 2]


def test_decide_hand_case():
    d = ev.decide(HAND_TME, HAND_GTM, HAND_TAU, 0.5)
    np.testing.assert_array_equal(d.best_match, [0, 0, 1, 0, 0])
    np.testing.assert_allclose(d.best_tme, [0.1, 0.3, 0.4, 0.7, 0.6])
    np.testing.assert_allclose(d.best_gtm, [0.2, 2.0, 3.0, 0.9, 5.0])
    np.testing.assert_array_equal(d.has_revisit, [True, True, False, True, False])
    np.testing.assert_array_equal(d.tp, [True, False, False, False, False])
    np.testing.assert_array_equal(d.fp, [False, True, True, False, False])
    np.testing.assert_array_equal(d.fn, [False, True, False, True, False])
    np.testing.assert_array_equal(d.tn, [False, False, False, False, True])
    c = d.counts
    assert (c["tp"], c["fp"], c["fn"], c["tn"]) == (1, 2, 2, 1)
    assert c["n_revisit"] == 3 and c["n_queries"] == 5
    assert list(d.outcome) == ["TP", "FP+FN", "FP", "FN", "TN"]


# --------------------------------------------------------------------------- ties
# 4 queries x 4 references, tau = 1.0; every measure is the expected value under a uniformly
# random choice among tied distances (true match: gtm <= 1).
#   TIED_TME                 TIED_GTM            best  tie (m)  true in it (c)  correct share
#   q0: .5  .5  .5  .5       .2  5   5   5       .5    4        1 (r0)          1/4
#   q1: .2  .1  .2  .2       .5  5   5   5       .1    1        0               0
#   q2: .9  .3  .8  .8       5   .4  5   5       .3    1        1               1
#   q3: .6  .6  .7  .7       5   5   5   5       .6    2        0 (no revisit)  0
# Revisits q0, q1, q2 (3); tied best matches q0 and q3: tied_share 1/2.
# PR sweep (-inf and the best distances .1 q1, .3 q2, .5 q0, .6 q3):
#   delta  TP   FP    FN    P     R     F1
#   -inf   0    0     3     1     0     0
#   .1     0    1     3     0     0     0
#   .3     1    1     2     1/2   1/3   2/5
#   .5     5/4  7/4   7/4   5/12  5/12  5/12
#   .6     5/4  11/4  7/4   5/16  5/12  5/14
# max F1 5/12 at .5 (the lowest-index rule: q0 right, 2/3); AUC = (1/3)(1/2) + (1/12)(5/12) = 29/144.
# recall@K: q0's four tied references hold one true match: the first K of a random order hold it
# with 1 - C(3, K)/C(4, K) = 1/4, 1/2, 3/4, 1; q1's true match r0 shares .2 with r2 and r3 behind
# the wrong r1: K = 1 nothing, K = 2 one of three drawn: 1/3, K = 3: 1 - (2/3)(1/2) = 2/3; q2 always.
#   R@1 = (1/4 + 0 + 1)/3 = 5/12, R@2 = (1/2 + 1/3 + 1)/3 = 11/18, R@3 = (3/4 + 2/3 + 1)/3 = 29/36, R@4 = 1.
TIED_TME = np.array([[0.5, 0.5, 0.5, 0.5], [0.2, 0.1, 0.2, 0.2], [0.9, 0.3, 0.8, 0.8], [0.6, 0.6, 0.7, 0.7]])
TIED_GTM = np.array([[0.2, 5, 5, 5], [0.5, 5, 5, 5], [5, 0.4, 5, 5], [5, 5, 5, 5]], dtype=float)


def test_a_tied_best_match_counts_as_correct_in_proportion():
    d = ev.decide(TIED_TME, TIED_GTM, 1.0, 0.5)  # accepts q0, q1, q2
    np.testing.assert_array_equal(d.best_match, [0, 1, 1, 0])  # drawn at the lowest index of the tie
    np.testing.assert_array_equal(d.n_best, [4, 1, 1, 2])
    np.testing.assert_allclose(d.correct_share, [1 / 4, 0, 1, 0])
    np.testing.assert_allclose(d.tp, [1 / 4, 0, 1, 0])
    np.testing.assert_allclose(d.fp, [3 / 4, 1, 0, 0])
    np.testing.assert_allclose(d.fn, [3 / 4, 1, 0, 0])
    np.testing.assert_allclose(d.tn, [0, 0, 0, 1])
    assert d.counts == {"tp": 1.25, "fp": 1.75, "fn": 1.75, "tn": 1, "n_queries": 4, "n_revisit": 3, "n_accepted": 3}
    assert type(d.counts["tn"]) is int  # whole counts stay ints
    assert list(d.outcome) == ["TP|FP", "FP+FN", "TP", "TN"]


def test_pr_curve_with_ties_hand_case():
    c = ev.pr_curve(TIED_TME, TIED_GTM, 1.0)
    np.testing.assert_allclose(c.deltas, [-np.inf, 0.1, 0.3, 0.5, 0.6])
    np.testing.assert_allclose(c.tp, [0, 0, 1, 5 / 4, 5 / 4])
    np.testing.assert_allclose(c.fp, [0, 1, 1, 7 / 4, 11 / 4])
    np.testing.assert_allclose(c.fn, [3, 3, 2, 7 / 4, 7 / 4])
    np.testing.assert_allclose(c.precision, [1, 0, 1 / 2, 5 / 12, 5 / 16])
    np.testing.assert_allclose(c.recall, [0, 0, 1 / 3, 5 / 12, 5 / 12])
    np.testing.assert_allclose(c.f1, [0, 0, 2 / 5, 5 / 12, 5 / 14])
    assert (c.max_f1, c.delta_at_max_f1) == (pytest.approx(5 / 12), pytest.approx(0.5))
    assert c.auc == pytest.approx(29 / 144)
    assert c.recall_at_full_precision == 0.0


def test_recall_at_k_with_a_tie_straddling_rank_k_hand_case():
    r = ev.recall_at_k(TIED_TME, TIED_GTM, 1.0, ks=(1, 2, 3, 4, 9))
    assert r == {1: pytest.approx(5 / 12), 2: pytest.approx(11 / 18), 3: pytest.approx(29 / 36),
                 4: pytest.approx(1.0), 9: pytest.approx(1.0)}


def test_the_summary_reports_the_share_of_tied_best_matches_and_expected_counts():
    s = ev.evaluate(TIED_TME, TIED_GTM, 1.0, delta=0.5, ks=(1,))
    assert s["tied_share"] == 0.5
    assert (s["tp"], s["fp"], s["fn"], s["tn"], s["n_accepted"]) == (1.25, 1.75, 1.75, 1, 3)
    assert (s["precision"], s["recall"], s["f1"]) == (pytest.approx(5 / 12),) * 3
    assert (s["max_f1"], s["auc"]) == (pytest.approx(5 / 12), pytest.approx(29 / 144))
    assert s["recall_at_k"] == {"1": pytest.approx(5 / 12)}
    assert ev.evaluate(HAND_TME, HAND_GTM, HAND_TAU)["tied_share"] == 0.2  # q4's two wrong references
    # a tie at +inf is no answer, not a tie; a tie of distances that differ in the last bit is none
    apart = np.array([[np.inf, np.inf], [0.3, np.nextafter(0.3, 1)]])
    assert ev.evaluate(apart, np.ones((2, 2)), 1.0)["tied_share"] == 0


def test_pr_curve_hand_case():
    c = ev.pr_curve(HAND_TME, HAND_GTM, HAND_TAU)
    np.testing.assert_allclose(c.deltas, HAND_DELTAS)
    np.testing.assert_array_equal(c.tp, HAND_TP)
    np.testing.assert_array_equal(c.fp, HAND_FP)
    np.testing.assert_array_equal(c.fn, HAND_FN)
    np.testing.assert_allclose(c.precision, HAND_P)
    np.testing.assert_allclose(c.recall, HAND_R)
    np.testing.assert_allclose(c.f1, HAND_F1)
    assert c.max_f1 == pytest.approx(0.5)
    assert c.delta_at_max_f1 == pytest.approx(0.1)
    assert c.auc == pytest.approx(7 / 15)
    # precision is 1 up to delta 0.1, where recall is 1/3; beyond it a wrong match is accepted
    assert c.recall_at_full_precision == pytest.approx(1 / 3)
    assert ev.evaluate(HAND_TME, HAND_GTM, HAND_TAU)["recall_at_100_precision"] == pytest.approx(1 / 3)


def test_recall_at_full_precision_is_zero_when_the_most_confident_match_is_wrong():
    # one revisit query whose best match is wrong and more confident than the correct one
    tme = np.array([[0.1, 0.5], [0.9, 0.2]])
    gtm = np.array([[5.0, 0.1], [5.0, 0.1]])  # both queries revisit reference 1 only
    c = ev.pr_curve(tme, gtm, tau=0.3)
    assert c.precision[1] == 0.0  # delta 0.1: q0's wrong match accepted first
    assert c.recall_at_full_precision == 0.0
    # precision 0.95 is not full precision: the recall there does not count
    almost = ev.PRCurve(np.arange(3.0), np.array([1.0, 1.0, 0.95]), np.array([0.0, 0.3, 0.6]),
                        np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 10, 10)
    assert almost.recall_at_full_precision == pytest.approx(0.3)


def test_pr_curve_given_deltas_hand_case():
    # delta 0.5 -> same as the decide() hand case; delta 0.05 -> nothing accepted (P = 1, R = 0);
    # delta 10 -> all accepted: TP 2, FP 3.
    c = ev.pr_curve(HAND_TME, HAND_GTM, HAND_TAU, deltas=[0.5, 0.05, 10.0])
    np.testing.assert_array_equal(c.tp, [1, 0, 2])
    np.testing.assert_array_equal(c.fp, [2, 0, 3])
    np.testing.assert_allclose(c.precision, [1 / 3, 1.0, 2 / 5])
    np.testing.assert_allclose(c.recall, [1 / 3, 0.0, 2 / 3])


def test_recall_at_k_hand_case():
    # Revisit queries q0, q1, q3.  Candidates by ascending TME (stable ties):
    #   q0: j0 (gtm 0.2 hit)                      -> hit at K=1
    #   q1: j0 (2.0), j1 (0.5 hit)                -> hit at K=2
    #   q3: j0 (0.9 hit; tie with j3 -> j0 first) -> hit at K=1
    # R@1 = 2/3, R@2 = 1, R@10 (clamped to 4 references) = 1.
    r = ev.recall_at_k(HAND_TME, HAND_GTM, HAND_TAU, ks=(1, 2, 10))
    assert r == {1: pytest.approx(2 / 3), 2: pytest.approx(1.0), 10: pytest.approx(1.0)}


def test_recall_at_k_no_revisit_is_zero():
    r = ev.recall_at_k(HAND_TME, HAND_GTM, tau=0.1, ks=(1, 5))
    assert r == {1: 0.0, 5: 0.0}


def test_ground_truth_matrix_heading_hand_case():
    q = np.array([[0.0, 0.0, 0.1], [1.0, 1.0, 3.1]])
    r = np.array([[3.0, 4.0, -0.1], [1.0, 1.0, -3.1]])
    # xy distances: q0-r0 = 5, q0-r1 = sqrt 2, q1-r0 = sqrt(4 + 9) = sqrt 13, q1-r1 = 0.
    xy = np.array([[5.0, math.sqrt(2)], [math.sqrt(13), 0.0]])
    np.testing.assert_allclose(ev.ground_truth_matrix(q, r), xy)
    np.testing.assert_allclose(ev.ground_truth_matrix(q[:, :2], r[:, :2]), xy)  # (N, 2) accepted
    # yaw differences: q0-r0 0.2 rad = 11.5 deg; q0-r1 and q1-r0 3.2 rad -> wrapped 2 pi - 3.2 =
    # 176.6 deg; q1-r1 6.2 rad -> wrapped 2 pi - 6.2 = 4.8 deg (unwrapped it would be 355 deg).
    inf = np.inf
    np.testing.assert_array_equal(ev.ground_truth_matrix(q, r, heading_tolerance_deg=30), [[5.0, inf], [inf, 0.0]])
    np.testing.assert_array_equal(ev.ground_truth_matrix(q, r, heading_tolerance_deg=10), [[inf, inf], [inf, 0.0]])
    np.testing.assert_allclose(ev.ground_truth_matrix(q, r, heading_tolerance_deg=180), xy)
    np.testing.assert_allclose(ev.ground_truth_matrix(q, r, heading_tolerance_deg=None), xy)


def test_heading_tolerance_includes_its_bound():
    q = np.array([[0.0, 0.0, 0.0]])
    r = np.array([[0.1, 0.0, math.pi / 2], [0.1, 0.0, -math.pi / 2]])  # 90 deg either way
    np.testing.assert_allclose(ev.ground_truth_matrix(q, r, heading_tolerance_deg=90), [[0.1, 0.1]])
    np.testing.assert_array_equal(ev.ground_truth_matrix(q, r, heading_tolerance_deg=89.9), [[np.inf, np.inf]])


def test_a_reference_facing_away_is_no_true_match_for_every_metric():
    """At the same place but facing the other way: a miss without the tolerance, no revisit
    (so no FN) with it: runs that face differently are not scored as vision failures."""
    q = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    r = np.array([[0.0, 0.0, math.pi], [2.0, 0.0, 0.1]])
    # best matches: q0 -> r1 at 0.1 (2 m away: wrong), q1 -> r1 at 0.2 (correct)
    tme = np.array([[0.5, 0.1], [0.9, 0.2]])
    # position only, 2 revisits: delta 0.1 TP 0 FP 1 -> F1 0; delta 0.2 TP 1 FP 1 -> P 1/2, R 1/2
    position_only = ev.evaluate(tme, ev.ground_truth_matrix(q, r), 0.3)
    assert (position_only["n_revisit"], position_only["max_f1"]) == (2, pytest.approx(1 / 2))
    # with the tolerance q0 has no revisit: delta 0.2 TP 1 FP 1 -> P 1/2, R 1 -> F1 2/3
    with_heading = ev.evaluate(tme, ev.ground_truth_matrix(q, r, heading_tolerance_deg=30), 0.3)
    assert (with_heading["n_revisit"], with_heading["max_f1"]) == (1, pytest.approx(2 / 3))


# --------------------------------------------------------------------------- difficulty
# References (x, y, yaw deg): r0 (0, 0, 0), r1 (0.1, 0, 0), r2 (0, 0.2, 90), r3 (5, 0, 0).
# tau 0.3 m, heading tolerance 30 deg. Queries:
#   q0 (0.02, 0, 0):     r0 0.02, r1 0.08, r2 0.201 (faces 90 deg off), r3 far -> true r0, r1
#                        (2 of 4); nearest r0: 0.02 m, 0 deg
#   q1 (0, 0.08, 100):   r0 0.08 and r1 0.128 (100 deg off), r2 0.12 (10 deg off) -> true r2
#                        (1 of 4); nearest by position r0 (not the true match): 0.08 m, 100 deg
#   q2 (0.1, -0.1, 20):  r0 0.141, r1 0.1 (both 20 deg off), r2 0.316 > tau -> true r0, r1
#                        (2 of 4); nearest r1: 0.1 m, 20 deg
#   q3 (3, 3, 0):        nothing within tau -> left out
#   q4 (0, 0, 180):      on r0 but facing back, r1 likewise, r2 90 deg off -> left out
# Over q0-q2: distances 0.02, 0.08, 0.1 -> median 0.08, 90th percentile (linear: position
# 0.9 * 2 = 1.8) 0.08 + 0.8 * 0.02 = 0.096; headings 0, 100, 20 -> median 20;
# chance_r1 = mean(2/4, 1/4, 2/4) = 5/12. Touch: queries 2 of 5, references 1 of 4.
# Longest stay (within 0.25 m of its first sample): queries q0-q2 (q1 0.082 m, q2 0.128 m
# from q0; q3 far), 3 of 5; references r0-r2 (0.1 m, 0.2 m; r3 far), 3 of 4.
# True-match pairs (each query with a true match, with its nearest true match by position):
# q0-r0 (0.02 < r1 0.08), q1-r2 (its only one; r0 is nearer but faces 100 deg off),
# q2-r1 (0.1 < r0 0.141). Touched: q0 and q4 (no true match), r3 (no pair): q0-r0 is touched
# on one side only -> both 0/3, one side 1/3; of the touched queries with a pair (q0) none
# has a touched partner -> correspondence 0/1.
DEG = math.pi / 180
DIFF_REF = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.2, 90 * DEG], [5.0, 0.0, 0.0]])
DIFF_QRY = np.array(
    [[0.02, 0.0, 0.0], [0.0, 0.08, 100 * DEG], [0.1, -0.1, 20 * DEG], [3.0, 3.0, 0.0], [0.0, 0.0, 180 * DEG]]
)
DIFF_QTOUCH = np.array([True, False, False, False, True])
DIFF_RTOUCH = np.array([False, False, False, True])


def test_difficulty_hand_case():
    gtm = ev.ground_truth_matrix(DIFF_QRY, DIFF_REF, heading_tolerance_deg=30)
    d = difficulty(DIFF_QRY, DIFF_REF, gtm, 0.3, DIFF_QTOUCH, DIFF_RTOUCH)
    assert list(d) == [
        "nearest_ref_median_m", "nearest_ref_p90_m", "nearest_ref_heading_median_deg", "chance_r1",
        "query_touch_share", "reference_touch_share", "query_longest_stay_share", "reference_longest_stay_share",
        "touch_both_share", "touch_one_side_share", "touch_correspondence",
    ]
    assert d == {
        "nearest_ref_median_m": pytest.approx(0.08),
        "nearest_ref_p90_m": pytest.approx(0.096),
        "nearest_ref_heading_median_deg": pytest.approx(20.0),
        "chance_r1": pytest.approx(5 / 12),
        "query_touch_share": pytest.approx(0.4),
        "reference_touch_share": pytest.approx(0.25),
        "query_longest_stay_share": pytest.approx(0.6),
        "reference_longest_stay_share": pytest.approx(0.75),
        "touch_both_share": 0.0,
        "touch_one_side_share": pytest.approx(1 / 3),
        "touch_correspondence": 0.0,
    }
    assert all(type(v) is float for v in d.values())  # JSON-ready


@pytest.mark.parametrize("query_touch, reference_touch, expected", [
    # pairs q0-r0, q1-r2, q2-r1 (the hand case above). q0, q1, q4 touched; r1, r2 touched:
    # q0-r0 one side, q1-r2 both, q2-r1 one side -> both 1/3, one side 2/3; touched queries
    # with a pair q0, q1 (q4 has none): r2 touched, r0 not -> correspondence 1/2. (Pairing
    # q1 with its nearest reference r0 instead would give both 0, one side 3/3.)
    ([1, 1, 0, 0, 1], [0, 1, 1, 0], (1 / 3, 2 / 3, 1 / 2)),
    # only q3 and q4 touched, neither has a true match: correspondence None; the pairs'
    # references r0, r2, r1 -> r2, r1 touched: one side 2/3, both 0
    ([0, 0, 0, 1, 1], [0, 1, 1, 0], (0.0, 2 / 3, None)),
    # everything touched: every pair both sides, every touched query's partner touched
    ([1, 1, 1, 1, 1], [1, 1, 1, 1], (1.0, 0.0, 1.0)),
])
def test_touch_at_true_matches_hand_cases(query_touch, reference_touch, expected):
    gtm = ev.ground_truth_matrix(DIFF_QRY, DIFF_REF, heading_tolerance_deg=30)
    d = difficulty(DIFF_QRY, DIFF_REF, gtm, 0.3, np.array(query_touch, bool), np.array(reference_touch, bool))
    got = (d["touch_both_share"], d["touch_one_side_share"], d["touch_correspondence"])
    assert got == tuple(pytest.approx(v) if v is not None else None for v in expected)


def test_touch_at_true_matches_needs_both_masks_and_a_true_match():
    gtm = ev.ground_truth_matrix(DIFF_QRY, DIFF_REF, heading_tolerance_deg=30)
    keys = ("touch_both_share", "touch_one_side_share", "touch_correspondence")
    for masks in ((None, None), (DIFF_QTOUCH, None), (None, DIFF_RTOUCH)):
        d = difficulty(DIFF_QRY, DIFF_REF, gtm, 0.3, *masks)
        assert [d[k] for k in keys] == [None] * 3


@pytest.mark.parametrize("xs, expected", [
    # a slow drift (0.1 m per sample) stays 3 samples at most; the stay at 1.0 (with a 0.1 m
    # wobble) lasts 4: measured from the stretch's first sample, not step by step
    ([0.0, 0.1, 0.2, 0.3, 0.4, 1.0, 1.0, 1.1, 1.0, 2.0], (4, 5)),
    ([0.0, 0.1, 0.2, 0.3, 0.4], (3, 0)),  # ties: the earliest
    ([0.0, 0.25, 0.5], (2, 0)),  # exactly the radius is within it
    ([7.0] * 6, (6, 0)),  # never moves: the whole run
    ([], (0, 0)),
])
def test_longest_stay_hand_cases(xs, expected):
    xy = np.stack([np.array(xs), np.zeros(len(xs))], axis=1)
    assert longest_stay(xy, 0.25) == expected


def test_difficulty_position_only_counts_the_query_that_faces_back():
    # Without a heading tolerance q4 (on r0, facing back) has a true match: nearest r0 at 0 m,
    # 180 deg; r0, r1 (0.1 m), r2 (0.2 m) within tau (3 of 4); q0 gains r2 (0.201 m, 3 of 4),
    # q1 gains r0 and r1 (3 of 4), q2 unchanged (2 of 4).
    # Distances 0.02, 0.08, 0.1, 0 -> median 0.05; headings 0, 100, 20, 180 -> median 60;
    # chance mean(3/4, 3/4, 2/4, 3/4) = 11/16.
    gtm = ev.ground_truth_matrix(DIFF_QRY, DIFF_REF)
    d = difficulty(DIFF_QRY, DIFF_REF, gtm, 0.3, DIFF_QTOUCH, DIFF_RTOUCH)
    assert d["nearest_ref_median_m"] == pytest.approx(0.05)
    assert d["nearest_ref_heading_median_deg"] == pytest.approx(60.0)
    assert d["chance_r1"] == pytest.approx(11 / 16)


def test_difficulty_without_any_true_match_is_none_but_touch_is_measured():
    gtm = ev.ground_truth_matrix(DIFF_QRY, DIFF_REF, heading_tolerance_deg=30)
    d = difficulty(DIFF_QRY, DIFF_REF, gtm, 0.01, DIFF_QTOUCH, DIFF_RTOUCH)
    assert d == {
        "nearest_ref_median_m": None, "nearest_ref_p90_m": None, "nearest_ref_heading_median_deg": None,
        "chance_r1": None, "query_touch_share": pytest.approx(0.4), "reference_touch_share": pytest.approx(0.25),
        "query_longest_stay_share": pytest.approx(0.6), "reference_longest_stay_share": pytest.approx(0.75),
        "touch_both_share": None, "touch_one_side_share": None, "touch_correspondence": None,
    }


def test_evaluate_pair_writes_difficulty_and_tolerance_into_the_summary(tmp_path):
    tme = np.ones((len(DIFF_QRY), len(DIFF_REF)))
    summary = evaluate_pair(tmp_path, tme, DIFF_QRY, DIFF_REF, 0.3, query_touch=DIFF_QTOUCH,
                            reference_touch=DIFF_RTOUCH, heading_tolerance_deg=30)
    assert summary["heading_tolerance_deg"] == 30
    assert summary["n_revisit"] == 3  # q0, q1, q2 (see the hand case above)
    assert summary["difficulty"]["chance_r1"] == pytest.approx(5 / 12)
    assert summary["difficulty"]["query_touch_share"] == pytest.approx(0.4)
    json.dumps(summary)
    # without touch masks (and without a tolerance: q4 counts, see the position-only case) touch is not measured
    summary = evaluate_pair(tmp_path, tme, DIFF_QRY, DIFF_REF, 0.3)
    assert summary["heading_tolerance_deg"] is None and summary["n_revisit"] == 4
    assert summary["difficulty"]["query_touch_share"] is None and summary["difficulty"]["reference_touch_share"] is None
    # positions only, (N, 2): no heading to measure
    summary = evaluate_pair(tmp_path, tme, DIFF_QRY[:, :2], DIFF_REF[:, :2], 0.3)
    assert summary["difficulty"]["nearest_ref_median_m"] == pytest.approx(0.05)  # as the position-only case
    assert summary["difficulty"]["nearest_ref_heading_median_deg"] is None


# --------------------------------------------------------------------------- transferred threshold
# Training world: 4 queries x 3 references, tau 1; GTM 0 on the diagonal, 5 elsewhere (q3 has
# no true match). Best matches: q0 -> r0 at 0.1 (correct), q1 -> r1 at 0.3 (correct),
# q2 -> r0 at 0.2 (wrong), q3 -> r1 at 0.6 (wrong); 3 revisits.
#   delta 0.1: TP 1 FP 0 -> P 1, R 1/3, F1 1/2;   delta 0.2: TP 1 FP 1 -> F1 2/5
#   delta 0.3: TP 2 FP 1 -> P 2/3, R 2/3, F1 2/3 (the max);  delta 0.6: TP 2 FP 2 -> F1 4/7
TRAIN_GTM = np.array([[0, 5, 5], [5, 0, 5], [5, 5, 0], [5, 5, 5]], dtype=float)
TRAIN_TME = np.array([[0.1, 0.9, 0.9], [0.8, 0.3, 0.9], [0.2, 0.9, 0.5], [0.9, 0.6, 0.9]])
# Other world: 3 queries x 2 references; q0 -> r0 at 0.25 (correct), q1 -> r1 at 0.35
# (correct), q2 -> r0 at 0.28 (wrong, no revisit); 2 revisits.
#   its own max: delta 0.35: TP 2 FP 1 -> P 2/3, R 1, F1 4/5
#   at the training delta 0.3: q0 and q2 accepted: TP 1 FP 1 FN 1 -> P 1/2, R 1/2, F1 1/2
OTHER_GTM = np.array([[0, 5], [5, 0], [5, 5]], dtype=float)
OTHER_TME = np.array([[0.25, 0.7], [0.9, 0.35], [0.28, 0.8]])


def test_f1_at_the_training_threshold_hand_case():
    train = ev.pr_curve(TRAIN_TME, TRAIN_GTM, 1.0)
    assert train.delta_at_max_f1 == pytest.approx(0.3) and train.max_f1 == pytest.approx(2 / 3)
    assert ev.f1_at_threshold_of(train, OTHER_TME, OTHER_GTM, 1.0) == pytest.approx(1 / 2)
    assert ev.pr_curve(OTHER_TME, OTHER_GTM, 1.0).max_f1 == pytest.approx(4 / 5)
    # in the training world itself it is the max F1
    assert ev.f1_at_threshold_of(train, TRAIN_TME, TRAIN_GTM, 1.0) == pytest.approx(2 / 3)
    # from the pair's decisions, whatever threshold they were taken at, as from its matrices
    for delta in (-np.inf, 0.0, 0.3, 0.9):
        decisions = ev.decide(OTHER_TME, OTHER_GTM, 1.0, delta)
        assert ev.f1_at_threshold_from(train, decisions) == pytest.approx(1 / 2)


def test_f1_at_the_training_threshold_when_the_training_world_accepts_nothing():
    # q0-q2's true match is r2, never their best match (r0 or r1); q3 has none: every best
    # match is wrong, the max F1 is 0, first reached at delta -inf (accept nothing)
    gtm = np.array([[5, 5, 0], [5, 5, 0], [5, 5, 0], [5, 5, 5]], dtype=float)
    train = ev.pr_curve(TRAIN_TME, gtm, 1.0)
    assert train.max_f1 == 0.0 and train.delta_at_max_f1 == -np.inf
    assert ev.f1_at_threshold_of(train, OTHER_TME, OTHER_GTM, 1.0) == 0.0


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: ev.decide(np.zeros((3, 4)), np.zeros((4, 3)), 1.0, 0.5), "same shape"),
        (lambda: ev.pr_curve(np.zeros((3, 4)), np.zeros((3, 5)), 1.0), "same shape"),
        (lambda: ev.decide(np.array([[0.1, np.nan]]), np.zeros((1, 2)), 1.0, 0.5), "NaN"),
        (lambda: ev.pr_curve(np.array([[0.1, np.nan]]), np.zeros((1, 2)), 1.0), "NaN"),
        (lambda: ev.recall_at_k(np.array([[np.nan]]), np.zeros((1, 1)), 1.0), "NaN"),
        (lambda: ev.decide(np.zeros((2, 2)), np.zeros((2, 2)), -0.5, 0.5), "tau"),
        (lambda: ev.pr_curve(np.zeros((2, 2)), np.zeros((2, 2)), -1.0), "tau"),
        (lambda: ev.evaluate(np.zeros((2, 2)), np.zeros((2, 2)), -1.0), "tau"),
        (lambda: ev.decide(np.zeros(4), np.zeros(4), 1.0, 0.5), "2-D"),
        (lambda: ev.recall_at_k(np.zeros((2, 2)), np.zeros((2, 2)), 1.0, ks=(0,)), "K"),
        (lambda: ev.ground_truth_matrix(np.zeros((2, 2)), np.zeros((2, 2)), heading_tolerance_deg=30), "yaw"),
        (lambda: ev.ground_truth_matrix(np.zeros((2, 3)), np.zeros((2, 3)), heading_tolerance_deg=-1), "heading_tol"),
        (lambda: difficulty(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 2)), 1.0, [True], [True, True]),
         "query_touch"),
        (lambda: difficulty(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), 1.0, [1, 1], [1, 1]), "gtm"),
    ],
)
def test_bad_inputs(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# --------------------------------------------------------------------------- edge cases


def test_all_rejected_and_no_revisit_no_warnings():
    tme = np.array([[0.5, 0.5], [0.2, 0.9]])
    gtm = np.array([[3.0, 4.0], [5.0, 6.0]])  # nobody has a revisit at tau = 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = ev.pr_curve(tme, gtm, 1.0)
        s = ev.evaluate(tme, gtm, 1.0, delta=-1.0)
        ev.recall_at_k(tme, gtm, 1.0)
    # -inf: nothing accepted -> P 1 by convention, R 0; afterwards only FPs -> P 0; R always 0.
    np.testing.assert_allclose(c.precision, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(c.recall, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(c.f1, [0.0, 0.0, 0.0])
    assert c.auc == 0.0 and c.max_f1 == 0.0
    # delta = -1 rejects everything, no revisit anywhere: 2 TN.
    assert (s["precision"], s["recall"], s["f1"]) == (1.0, 0.0, 0.0)
    assert (s["tp"], s["fp"], s["fn"], s["tn"]) == (0, 0, 0, 2)
    assert s["delta_at_max_f1"] is None  # max F1 = 0 first reached at -inf -> None in JSON
    json.dumps(s, allow_nan=False)


def test_evaluate_summary_hand_case_is_json():
    s = ev.evaluate(HAND_TME, HAND_GTM, HAND_TAU, delta=0.5, ks=(1, 2))
    back = json.loads(json.dumps(s, allow_nan=False))
    assert back == s
    assert s["max_f1"] == pytest.approx(0.5)
    assert s["delta_at_max_f1"] == pytest.approx(0.1)
    assert s["auc"] == pytest.approx(7 / 15)
    assert s["n_revisit"] == 3 and s["n_queries"] == 5 and s["n_references"] == 4
    assert (s["tp"], s["fp"], s["fn"], s["tn"]) == (1, 2, 2, 1)
    assert s["precision"] == pytest.approx(1 / 3) and s["recall"] == pytest.approx(1 / 3)
    assert s["recall_at_k"] == {"1": pytest.approx(2 / 3), "2": pytest.approx(1.0)}
    assert s["tied_share"] == 0.2
    for v in s.values():
        assert type(v) in (int, float, str, dict, type(None))


# --------------------------------------------------------------------------- exports


def test_export_decisions_csv(tmp_path):
    d = ev.decide(HAND_TME, HAND_GTM, HAND_TAU, 0.5)
    path = tmp_path / "sub" / "decisions.csv"
    export_decisions_csv(path, d, extra_columns={"label": list("abcde")})
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["outcome"] for r in rows] == ["TP", "FP+FN", "FP", "FN", "TN"]
    assert [int(r["best_match"]) for r in rows] == [0, 0, 1, 0, 0]
    assert [float(r["best_tme"]) for r in rows] == [0.1, 0.3, 0.4, 0.7, 0.6]
    assert [float(r["best_gtm"]) for r in rows] == [0.2, 2.0, 3.0, 0.9, 5.0]
    assert [r["has_revisit"] for r in rows] == ["1", "1", "0", "1", "0"]
    assert [r["query"] for r in rows] == ["0", "1", "2", "3", "4"]
    assert [r["label"] for r in rows] == list("abcde")
    assert [int(r["n_best"]) for r in rows] == [1, 1, 1, 1, 2]
    assert [float(r["correct_share"]) for r in rows] == [1.0, 0.0, 0.0, 1.0, 0.0]
    assert sorted(p.name for p in path.parent.iterdir()) == ["decisions.csv"]  # no temp left


def test_export_matrices_npz(tmp_path):
    path = tmp_path / "m.npz"
    export_matrices_npz(path, HAND_TME, HAND_GTM)
    with np.load(path) as z:
        np.testing.assert_array_equal(z["tme"], HAND_TME)
        np.testing.assert_array_equal(z["gtm"], HAND_GTM)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


# --------------------------------------------------------------------------- independent references


def loop_decisions(tme, gtm, tau, delta):
    """Per-query loop straight from the definition (independent of the vectorised code)."""
    out = []
    for i in range(len(tme)):
        best = 0
        for j in range(1, len(tme[i])):
            if tme[i][j] < tme[i][best]:  # strict: ties keep the lowest j
                best = j
        revisit = any(g <= tau for g in gtm[i])
        accepted = tme[i][best] <= delta
        tp = accepted and gtm[i][best] <= tau
        fp = accepted and gtm[i][best] > tau
        fn = revisit and not tp
        tn = (not revisit) and (not accepted)
        out.append((best, revisit, tp, fp, fn, tn))
    return out


def loop_prf(tme, gtm, tau, delta):
    rows = loop_decisions(tme, gtm, tau, delta)
    tp = sum(r[2] for r in rows)
    fp = sum(r[3] for r in rows)
    fn = sum(r[4] for r in rows)
    p = 1.0 if tp + fp == 0 else tp / (tp + fp)
    r = 0.0 if tp + fn == 0 else tp / (tp + fn)
    f = 0.0 if p + r == 0 else 2 * p * r / (p + r)
    return tp, fp, fn, p, r, f


def vpr_tutorial_create_pr_single(similarity, gt_hard, n_thresh):
    """VPR_Tutorial's createPR(S, GThard, matching='single'), re-written from its definition:
    S is (references x queries) similarity, GThard boolean; best match = first argmax per
    column; GTP = #columns with any true; n_thresh thresholds evenly from max to min of the
    best similarities; accepted = best similarity >= threshold; curves start with (R 0, P 1)."""
    n_ref, n_q = len(similarity), len(similarity[0])
    gtp = sum(1 for q in range(n_q) if any(gt_hard[r][q] for r in range(n_ref)))
    best_s, best_ok = [], []
    for q in range(n_q):
        b = 0
        for r in range(1, n_ref):
            if similarity[r][q] > similarity[b][q]:
                b = r
        best_s.append(similarity[b][q])
        best_ok.append(bool(gt_hard[b][q]))
    thresholds = np.linspace(max(best_s), min(best_s), n_thresh)
    precision, recall = [1.0], [0.0]
    for t in thresholds:
        tp = sum(1 for s, ok in zip(best_s, best_ok, strict=True) if s >= t and ok)
        fp = sum(1 for s, ok in zip(best_s, best_ok, strict=True) if s >= t and not ok)
        precision.append(tp / (tp + fp))
        recall.append(tp / gtp)
    return np.array(precision), np.array(recall), thresholds


def over_tie_orders(tme, gtm, measure):
    """The mean of ``measure(tme, gtm)``, a lowest-index-rule reference, over every order of
    the references: the expected value under a uniformly random order of tied distances, by
    enumeration (the loops above break ties to the lowest index; permuting the columns first
    makes that a random choice)."""
    orders = list(itertools.permutations(range(tme.shape[1])))
    return np.mean([np.asarray(measure(tme[:, list(o)], gtm[:, list(o)]), dtype=float) for o in orders], axis=0)


def untied(tme):
    """Whether no query's best distance is shared (the lowest-index rule decides nothing)."""
    return all((row == row.min()).sum() == 1 for row in tme)


@st.composite
def matrices(draw, allow_float=False, max_refs=7):
    n_q = draw(st.integers(1, 9))
    n_r = draw(st.integers(1, max_refs))
    if allow_float and draw(st.booleans()):
        elem = st.floats(0.0, 10.0, allow_nan=False, allow_infinity=False)
    else:
        elem = st.integers(0, 4).map(float)  # few levels -> plenty of ties in TME
    tme = np.array(draw(st.lists(st.lists(elem, min_size=n_r, max_size=n_r), min_size=n_q, max_size=n_q)))
    gtm = np.array(
        draw(st.lists(st.lists(st.integers(0, 5).map(float), min_size=n_r, max_size=n_r), min_size=n_q, max_size=n_q))
    )
    tau = float(draw(st.integers(0, 5))) + draw(st.sampled_from([0.0, 0.5]))
    return tme, gtm, tau


SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(matrices(allow_float=True, max_refs=4), st.sampled_from([-1.0, 0.0, 1.0, 2.0, 2.5, 4.0, 20.0]))
def test_decide_is_the_expected_lowest_index_decision_over_tie_orders(m, delta):
    tme, gtm, tau = m
    d = ev.decide(tme, gtm, tau, delta)
    ref = loop_decisions(tme.tolist(), gtm.tolist(), tau, delta)
    np.testing.assert_array_equal(d.best_match, [r[0] for r in ref])  # drawn: the lowest index
    np.testing.assert_array_equal(d.has_revisit, [r[1] for r in ref])
    expected = over_tie_orders(tme, gtm, lambda t, g: [r[2:] for r in loop_decisions(t.tolist(), g.tolist(), tau,
                                                                                         delta)])
    np.testing.assert_allclose(np.c_[d.tp, d.fp, d.fn, d.tn], expected, atol=1e-12)
    assert d.counts["tp"] + d.counts["fn"] == pytest.approx(d.counts["n_revisit"])


@SETTINGS
@given(matrices(allow_float=True, max_refs=4))
def test_pr_curve_counts_are_the_expected_lowest_index_counts_over_tie_orders(m):
    tme, gtm, tau = m
    c = ev.pr_curve(tme, gtm, tau)
    # the default sweep: -inf and every distinct best-match TME (from the loop), ascending
    best = [tme[i][r[0]] for i, r in enumerate(loop_decisions(tme.tolist(), gtm.tolist(), tau, 0.0))]
    np.testing.assert_array_equal(c.deltas, [-np.inf, *sorted(set(best))])
    for k, delta in enumerate(c.deltas):
        tp, fp, fn = over_tie_orders(tme, gtm, lambda t, g, d=delta: loop_prf(t.tolist(), g.tolist(), tau, d)[:3])
        assert (c.tp[k], c.fp[k], c.fn[k]) == (pytest.approx(tp), pytest.approx(fp), pytest.approx(fn))
        p = 1.0 if tp + fp == 0 else tp / (tp + fp)
        r = 0.0 if tp + fn == 0 else tp / (tp + fn)
        assert (c.precision[k], c.recall[k]) == (pytest.approx(p), pytest.approx(r))
        assert c.f1[k] == pytest.approx(0.0 if p + r == 0 else 2 * p * r / (p + r))


@SETTINGS
@given(matrices(allow_float=True))
def test_untied_matrices_score_exactly_as_the_lowest_index_rule(m):
    tme, gtm, tau = m
    assume(untied(tme))
    c = ev.pr_curve(tme, gtm, tau)
    for k, delta in enumerate(c.deltas):
        tp, fp, fn, p, r, f = loop_prf(tme.tolist(), gtm.tolist(), tau, delta)
        assert (c.tp[k], c.fp[k], c.fn[k], c.precision[k], c.recall[k], c.f1[k]) == (tp, fp, fn, p, r, f)
    if any(len(set(row)) < len(row) for row in tme.tolist()):
        return  # recall@K: a tie anywhere in a row may straddle some rank K
    revisit = [i for i in range(len(tme)) if gtm[i].min() <= tau]
    for k, recall in ev.recall_at_k(tme, gtm, tau, ks=(1, 2, 3)).items():
        hits = sum(any(gtm[i, j] <= tau for j in sorted(range(tme.shape[1]), key=lambda j: (tme[i, j], j))[:k])
                   for i in revisit)
        assert recall == (hits / len(revisit) if revisit else 0.0)


@SETTINGS
@given(matrices(allow_float=True))
def test_pr_curve_matches_sklearn_with_tied_queries_split_by_weight(m):
    tme, gtm, tau = m
    # per query, computed independently: score = -best TME; a query whose best distance m
    # references share, c of them true matches, is two samples: label 1 of weight c/m, label 0 of weight 1 - c/m
    best_tme = tme.min(axis=1)
    share = np.array([sum(gtm[i, j] <= tau for j in range(tme.shape[1]) if tme[i, j] == best_tme[i])
                      / sum(tme[i] == best_tme[i]) for i in range(len(tme))])
    n_revisit = int((gtm.min(axis=1) <= tau).sum())
    n_correct = share.sum()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division-by-zero or other warnings from our code
        c = ev.pr_curve(tme, gtm, tau)
    if n_correct == 0:
        # no correct best match anywhere: recall stays 0, AUC 0; P 1 at -inf then 0.
        assert np.all(c.recall == 0.0) and c.auc == 0.0 and c.max_f1 == 0.0
        np.testing.assert_allclose(c.precision, [1.0] + [0.0] * (len(c.deltas) - 1))
        return
    labels, scores, weights = np.r_[np.ones(len(tme)), np.zeros(len(tme))], np.r_[-best_tme, -best_tme], np.r_[
        share, 1 - share]
    scale = n_correct / n_revisit  # sklearn's recall denominator is the (weighted) correct, ours #revisit
    p_sk, r_sk, thr_sk = precision_recall_curve(labels, scores, sample_weight=weights)
    # sklearn's thresholds t accept score >= t  <=>  best_tme <= -t
    c_at = ev.pr_curve(tme, gtm, tau, deltas=-thr_sk)
    np.testing.assert_allclose(c_at.precision, p_sk[:-1])
    np.testing.assert_allclose(c_at.recall, r_sk[:-1] * scale)
    # sklearn's final point (P 1, R 0) is our -inf point
    assert (c.precision[0], c.recall[0]) == (p_sk[-1], r_sk[-1]) == (1.0, 0.0)
    # AUC = step-wise average precision, scaled to our recall denominator
    assert c.auc == pytest.approx(average_precision_score(labels, scores, sample_weight=weights) * scale, abs=1e-12)


@SETTINGS
@given(matrices(allow_float=True), st.integers(2, 40))
def test_pr_curve_matches_vpr_tutorial_single_where_nothing_is_tied(m, n_thresh):
    tme, gtm, tau = m
    gt_hard = (gtm <= tau).T  # VPR_Tutorial: references x queries, boolean
    assume(gt_hard.any() and untied(tme))  # createPR divides by GTP; its argmax takes the first of a tie
    similarity = -tme.T  # higher = better
    p_ref, r_ref, thresholds = vpr_tutorial_create_pr_single(similarity.tolist(), gt_hard.tolist(), n_thresh)
    c = ev.pr_curve(tme, gtm, tau, deltas=np.concatenate(([-np.inf], -thresholds)))
    np.testing.assert_allclose(c.precision, p_ref)
    np.testing.assert_allclose(c.recall, r_ref)


@SETTINGS
@given(matrices(allow_float=True, max_refs=5), st.lists(st.integers(1, 9), min_size=1, max_size=4))
def test_recall_at_k_is_the_expected_lowest_index_recall_over_tie_orders(m, ks):
    tme, gtm, tau = m
    r = ev.recall_at_k(tme, gtm, tau, ks=ks)
    revisit = [i for i in range(len(tme)) if gtm[i].min() <= tau]

    def lowest_index_hits(t, g, k):
        return [any(g[i, j] <= tau for j in sorted(range(t.shape[1]), key=lambda j: (t[i, j], j))[:k])
                for i in revisit]

    for k in ks:
        if not revisit:
            assert r[k] == 0.0
            continue
        expected = over_tie_orders(tme, gtm, lambda t, g, k=k: lowest_index_hits(t, g, k))
        assert r[k] == pytest.approx(float(np.mean(expected)))


# --------------------------------------------------------------------------- figures


@pytest.fixture(scope="module")
def small_case():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ref = np.c_[2 * np.cos(t), 2 * np.sin(t), t]
    qry = ref + rng.normal(0, 0.15, ref.shape)
    gtm = ev.ground_truth_matrix(qry, ref)
    tme = gtm + rng.random(gtm.shape)
    return qry, ref, tme, gtm


def _assert_written(paths, tmp_path, stem):
    from pathlib import Path

    assert [Path(p) for p in paths] == [tmp_path / f"{stem}.png", tmp_path / f"{stem}.pdf"]
    png, pdf = (Path(p).read_bytes() for p in paths)
    assert png.startswith(b"\x89PNG") and len(png) > 1000
    assert pdf.startswith(b"%PDF") and len(pdf) > 1000


def test_plot_matrices(tmp_path, small_case):
    from vitaplace.engine.report import figures
    qry, ref, tme, gtm = small_case
    d = ev.decide(tme, gtm, 0.3, 0.5)
    _assert_written(figures.plot_matrices(tmp_path / "mat", tme, gtm, d, "E1"), tmp_path, "mat")


@pytest.mark.parametrize("kind", ["huge", "tiny", "all-inf"])
def test_plot_matrices_draws_any_matrix_the_contract_allows(tmp_path, small_case, kind):
    """Finite distances near the largest (or smallest) float, with +inf, or +inf alone, are
    drawn without a warning: the colour scale of the raw values would overflow."""
    import warnings

    from vitaplace.engine.report import figures
    _, _, tme, gtm = small_case
    tme = {"huge": np.minimum(tme, 1.7) * 1e308, "tiny": np.where(tme < 1, 5e-324, 1e-320),
           "all-inf": np.full(tme.shape, np.inf)}[kind]
    tme[0, :3] = np.inf
    d = ev.decide(tme, gtm, 0.3, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _assert_written(figures.plot_matrices(tmp_path / "mat", tme, gtm, d, "E1"), tmp_path, "mat")


def test_plot_pr_curves(tmp_path, small_case):
    from vitaplace.engine.report import figures
    _, _, tme, gtm = small_case
    curves = {"mupnet": ev.pr_curve(tme, gtm, 0.3), "oracle": ev.pr_curve(gtm, gtm, 0.3)}
    _assert_written(figures.plot_pr_curves(tmp_path / "pr", curves, "E1"), tmp_path, "pr")


def test_plot_trajectories(tmp_path, small_case):
    from vitaplace.engine.report import figures
    qry, ref, tme, gtm = small_case
    d = ev.decide(tme, gtm, 0.3, 0.8)
    arena = {
        "width": 6.0,
        "depth": 6.0,
        "landmarks": [
            {"type": "box", "pos": [1.0, 1.0], "size": [1.0, 1.0], "yaw": 20.0},
            {"type": "cylinder", "pos": [-1.0, 1.0], "radius": 0.5},
            {"type": "rock", "pos": [0.0, 0.0], "size": [0.8, 0.5], "polygon": [[0, 0], [0.4, 0.1], [0.1, 0.5]]},
        ],
    }
    _assert_written(figures.plot_trajectories(tmp_path / "traj", qry, ref, d, arena, "E2"), tmp_path, "traj")
    _assert_written(figures.plot_trajectories(tmp_path / "traj2", qry, ref, d), tmp_path, "traj2")


def test_plot_energy(tmp_path):
    from vitaplace.engine.report import figures
    energy = {"visual/1": [100.0, 40.0, 20.0, 15.0], "tactile/1": [50.0, 30.0, 0.0, 9.0], "joint": []}
    _assert_written(figures.plot_energy(tmp_path / "energy", energy), tmp_path, "energy")
    _assert_written(figures.plot_energy(tmp_path / "empty", {}), tmp_path, "empty")


def test_curve_and_decisions_round_trip_through_files(tmp_path):
    curve = ev.pr_curve(HAND_TME, HAND_GTM, HAND_TAU)
    decisions = ev.decide(HAND_TME, HAND_GTM, HAND_TAU, curve.delta_at_max_f1)
    save_curve_and_decisions(tmp_path, curve, decisions)
    back, back_d = load_curve(tmp_path / "pr_curve.npz"), load_decisions(tmp_path / "decisions.npz")
    np.testing.assert_allclose(back.precision, HAND_P)
    assert (back.max_f1, back.delta_at_max_f1, back.auc, back.n_revisit) == (curve.max_f1, curve.delta_at_max_f1,
                                                                            curve.auc, 3)
    assert list(back_d.outcome) == list(decisions.outcome) and back_d.tau == HAND_TAU



ENVIRONMENTS = Path(__file__).resolve().parents[2] / "scenarios" / "environments"


def _scenario(train: dict, evaluations: list[tuple[str, str]]):
    """A scenario training as ``train`` with (name, shipped environment or file) evaluations."""
    from vitaplace.engine.config.scenario import Scenario

    return Scenario.model_validate({
        "name": "t",
        "train": train,
        "evaluations": [{"name": name, "environment": str(ENVIRONMENTS / f"{env}.yaml") if "/" not in env else env,
                         "run": {"kind": "route", "n_samples": 5}} for name, env in evaluations],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
    })


def _train_in(env: str) -> dict:
    return {"environment": str(ENVIRONMENTS / f"{env}.yaml"), "run": {"kind": "foraging", "n_samples": 5}}


def test_the_training_world_is_the_one_evaluation_in_the_training_environment(tmp_path):
    from vitaplace.engine.config.scenario import training_world_evaluation

    # the one in e1, wherever it is listed and whatever its name
    assert training_world_evaluation(_scenario(_train_in("e1"), [("X", "e2"), ("Mine", "e1")]))[0] == "Mine"
    # a file of another name holding e1 is the same world; e1-coloured is another one
    copy = tmp_path / "copy.yaml"
    copy.write_text(f"extends: {ENVIRONMENTS / 'e1.yaml'}\n")
    assert training_world_evaluation(_scenario(_train_in("e1"), [("C", str(copy)), ("E1c", "e1-coloured")]))[0] == "C"
    none, why = training_world_evaluation(_scenario(_train_in("e1"), [("E2", "e2"), ("E3", "e3")]))
    assert none is None and "no evaluation is in the training run's environment" in why
    none, why = training_world_evaluation(_scenario(_train_in("e1"), [("A", "e1"), ("B", "e1"), ("E2", "e2")]))
    assert none is None and "several evaluations" in why and "A, B" in why
    none, why = training_world_evaluation(_scenario({"dataset": "train.h5"}, [("E1", "e1")]))
    assert none is None and "recorded" in why


def test_the_runner_scores_every_evaluation_at_the_training_worlds_threshold(tmp_path):
    """E1 (in the training run's world, e1) holds the training matrices above, E2 the other
    ones: every row of a method gets the F1 at E1's max-F1 threshold (0.3), per direction."""
    from types import SimpleNamespace

    from vitaplace.engine.outputs.outdir import evaluation_dir
    from vitaplace.engine.outputs.rows import ResultRow
    from vitaplace.engine.pipeline.stages.compare import f1_at_training_threshold

    scenario = _scenario(_train_in("e1"), [("E2", "e2"), ("E1", "e1")])
    rows = []
    for env, tme, gtm in (("E2", OTHER_TME, OTHER_GTM), ("E1", TRAIN_TME, TRAIN_GTM)):
        folder = evaluation_dir(tmp_path, env, "H", "query-to-reference")
        folder.mkdir(parents=True)
        curve = ev.pr_curve(tme, gtm, 1.0)
        save_curve_and_decisions(folder, curve, ev.decide(tme, gtm, 1.0, curve.delta_at_max_f1))
        export_matrices_npz(folder / "matrices.npz", tme, gtm)
        rows.append(ResultRow(environment=env, method="H", direction="query-to-reference", tau=1.0, n_queries=2,
                              n_revisit=2, max_f1=curve.max_f1, auc=0.5))
    rows = f1_at_training_threshold(SimpleNamespace(out=tmp_path), scenario, rows)
    assert [row.f1_at_e1_threshold for row in rows] == [pytest.approx(1 / 2), pytest.approx(2 / 3)]
    assert [row.e1_threshold for row in rows] == [pytest.approx(0.3)] * 2


def test_a_query_that_no_reference_can_be_compared_with_has_no_answer():
    """Query 1's row is all +inf (a vision-only method and a query without its camera). Its
    argmin is reference 0, a true match - yet it must count neither as accepted nor as correct.

        query 0: best ref 1 (0.2), gtm 0.1 <= tau 0.3: correct;  query 1: no answer
        thresholds: -inf (nothing), 0.2 (query 0 accepted): TP 1, FP 0, n_revisit 2
        -> max F1 at 0.2: P 1, R 1/2, F1 2/3;  recall@1 = recall@2 = 1/2
    """
    tme = np.array([[0.5, 0.2], [np.inf, np.inf]])
    gtm = np.array([[1.0, 0.1], [0.0, 1.0]])
    curve = ev.pr_curve(tme, gtm, tau=0.3)
    np.testing.assert_array_equal(curve.deltas, [-np.inf, 0.2])
    assert curve.tp.tolist() == [0, 1] and curve.fp.tolist() == [0, 0]
    assert curve.max_f1 == pytest.approx(2 / 3)
    assert ev.pr_curve(tme, gtm, tau=0.3, deltas=[np.inf]).tp.tolist() == [1]  # even accepting everything
    assert ev.recall_at_k(tme, gtm, 0.3, ks=(1, 2)) == {1: 0.5, 2: 0.5}
    d = ev.decide(tme, gtm, tau=0.3, delta=np.inf)
    assert d.accepted.tolist() == [True, False] and d.tp.tolist() == [1, 0] and d.fn.tolist() == [0, 1]
    assert d.correct_share.tolist() == [1, 0] and d.n_best.tolist() == [1, 0]  # all +inf: no answer, no tie
