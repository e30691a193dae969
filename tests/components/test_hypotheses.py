"""The studies' pre-registered tests (docs/RESULTS.md) by hand: Holm's step-down adjustment on
worked families, the TOST's interval from a printed t quantile, every branch of the decision
rules and its edges, the endpoints against the per-seed better comparator, the
decomposition's interaction, and a family's sign-flip p values against a plain loop over
all 2**n sign patterns, Holm over the secondaries only."""

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.study import hypotheses

#: t(0.95, 3) from a printed table of Student's t quantiles
T_95_3 = 2.353363


def brute_force_sign_flip_p(d: list[float]) -> float:
    observed = abs(sum(d))
    patterns = list(itertools.product((1, -1), repeat=len(d)))
    hits = sum(abs(sum(s * x for s, x in zip(signs, d, strict=True))) >= observed - 1e-12 for signs in patterns)
    return hits / len(patterns)


@pytest.mark.parametrize("p, expected", [
    # sorted 0.01, 0.03, 0.04: 3 x 0.01 = 0.03; 2 x 0.03 = 0.06; 1 x 0.04 = 0.04, raised to 0.06
    ([0.01, 0.04, 0.03], [0.03, 0.06, 0.06]),
    # 2 x 0.01 = 0.02 first; 1 x 0.4 = 0.4: already above it, kept
    ([0.4, 0.01], [0.4, 0.02]),
    # 3 x 0.05 = 0.15; 2 x 0.6 = 1.2, capped at 1; 1 x 0.7 = 0.7, raised to 1
    ([0.6, 0.7, 0.05], [1.0, 1.0, 0.15]),
    ([0.5, 0.9], [1.0, 1.0]),  # 2 x 0.5 = 1; 0.9 raised to 1
    ([0.03], [0.03]),  # a family of one is not adjusted
])
def test_holm_adjusts_hand_worked_families(p, expected):
    assert hypotheses.holm(p) == pytest.approx(expected, abs=1e-15)


@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8))
def test_holm_never_lowers_a_p_keeps_their_order_and_stays_at_most_1(p):
    adjusted = hypotheses.holm(p)
    assert all(raw <= adj <= 1.0 for raw, adj in zip(p, adjusted, strict=True))
    assert all(adjusted[i] <= adjusted[j] for i in range(len(p)) for j in range(len(p)) if p[i] <= p[j])


def test_the_tost_interval_is_the_90_percent_t_interval():
    # 0.01, 0.03, -0.02, 0.04: mean 0.015, deviations -0.005, 0.015, -0.035, 0.025, squares
    # summing to 0.0021: s = sqrt(0.0021 / 3); half-width t(0.95, 3) s / sqrt(4) = 0.031132
    half = T_95_3 * math.sqrt(0.0021 / 3) / 2
    low, high = hypotheses.tost_interval([0.01, 0.03, -0.02, 0.04])
    assert (low, high) == pytest.approx((0.015 - half, 0.015 + half), abs=1e-6)
    assert hypotheses.equivalence((low, high))  # [-1.6, 4.6] points inside (-5, 5)


@pytest.mark.parametrize("boot, p, tost, expected", [
    ((0.01, 0.09), 0.01, (0.02, 0.08), "L better"),
    ((0.01, 0.04), 0.01, (0.005, 0.045), "L better, by < 5 points"),
    ((-0.09, -0.01), 0.01, (-0.08, -0.02), "L worse"),
    ((-0.04, -0.01), 0.01, (-0.045, -0.005), "L worse, by < 5 points"),
    ((-0.01, 0.03), 0.30, (-0.02, 0.04), "equivalent (±5 points)"),
    ((0.01, 0.09), 0.06, (0.0, 0.1), "neither shown"),  # p over 0.05 (e.g. after Holm)
    ((0.01, 0.09), 0.05, (0.0, 0.1), "neither shown"),  # p must be under 0.05, not at it
    ((-0.01, 0.09), 0.01, (-0.02, 0.1), "neither shown"),  # bootstrap interval holds 0
    ((0.0, 0.09), 0.01, (-0.02, 0.1), "neither shown"),  # ... or touches it
    ((-0.01, 0.03), 0.30, (-0.05, 0.04), "neither shown"),  # the TOST interval must lie inside the margin
    ((-0.01, 0.03), 0.30, (-0.02, 0.05), "neither shown"),
])
def test_the_decision_rules_are_the_pre_registered_ones(boot, p, tost, expected):
    stats = {"mean": (boot[0] + boot[1]) / 2, "boot_low": boot[0], "boot_high": boot[1]}
    assert hypotheses.decision(stats, p, tost) == expected


def test_the_endpoint_is_l_minus_the_better_comparator_in_each_seed():
    # seed 0: L 0.8, best of L-V 0.7 and L-F 0.75 is 0.75: +0.05; seed 1: L 0.6, best 0.65 (L-V): -0.05
    l_value, l_v, l_f = {1: 0.6, 0: 0.8}, {0: 0.7, 1: 0.65}, {0: 0.75, 1: 0.5}
    assert hypotheses.versus_best(l_value, [l_v, l_f]) == pytest.approx({0: 0.05, 1: -0.05}, abs=1e-15)
    assert list(hypotheses.versus_best(l_value, [l_v, l_f])) == [0, 1]  # in seed order
    assert hypotheses.versus_best(l_value, [l_f]) == pytest.approx({0: 0.05, 1: 0.1}, abs=1e-15)


def test_the_interaction_is_what_touch_adds_to_l_minus_what_it_adds_to_h():
    # seed 0: (0.9 - 0.8) - (0.7 - 0.4) = -0.2; seed 3: (0.5 - 0.6) - (0.3 - 0.3) = -0.1
    found = hypotheses.interaction({0: 0.9, 3: 0.5}, {0: 0.8, 3: 0.6}, {0: 0.7, 3: 0.3}, {0: 0.4, 3: 0.3})
    assert found == pytest.approx({0: -0.2, 3: -0.1}, abs=1e-15)
    # a difference of two differences of proportions lies in [-2, 2]: 1.5 and 1.9 (mean 1.7,
    # s = 0.2 sqrt(2)) have the t interval 1.7 -+ t(0.975, 1) x 0.2 = [-0.841, 4.241], cut to 2
    assert hypotheses.INTERACTION_LIMITS == (-2.0, 2.0) and hypotheses.DIFFERENCE_LIMITS == (-1.0, 1.0)
    stats, p = hypotheses.paired([1.5, 1.9], hypotheses.INTERACTION_LIMITS)
    assert stats["t_low"] == pytest.approx(1.7 - 12.706205 * 0.2, abs=1e-5) and stats["t_high"] == 2.0
    assert p == pytest.approx(2 / 4)  # ++ and -- of four patterns


@pytest.mark.parametrize("comparator", [{0: 0.7}, {0: 0.7, 1: 0.6, 2: 0.5}])
def test_methods_with_different_seeds_are_refused_in_one_line(comparator):
    with pytest.raises(UserError) as error:
        hypotheses.versus_best({0: 0.8, 1: 0.6}, [comparator])
    assert "expected the same seeds for every method" in str(error.value) and "\n" not in str(error.value)


def test_a_family_is_decided_on_exact_sign_flip_p_with_holm_over_the_secondaries_only():
    six = [0.10, 0.12, 0.14, 0.16, 0.18, 0.20]  # all positive: p = 2/64
    mixed = [0.1, 0.2, -0.05]  # sums 0.35, 0.25, -0.05, -0.15, 0.15, 0.05, -0.25, -0.35: 4 of 8 at |0.25| or more
    even = [0.1, 0.1, -0.1]  # every pattern's |sum| is at least 0.1: p = 1
    tested = hypotheses.endpoint_tests(six, [six, mixed, even])
    assert [e.p for e in tested] == pytest.approx([2 / 64, 2 / 64, 4 / 8, 1.0], abs=1e-12)
    assert [e.p for e in tested] == pytest.approx([brute_force_sign_flip_p(v) for v in (six, six, mixed, even)],
                                                  abs=1e-12)
    # Holm over the three secondaries: 3 x 2/64 = 0.09375, 2 x 0.5 = 1, 1 x 1 = 1; the primary keeps 2/64
    assert [e.p_holm for e in tested] == pytest.approx([2 / 64, 0.09375, 1.0, 1.0], abs=1e-12)
    primary, first = tested[0], tested[1]
    assert primary.values == tuple(six) and primary.stats["n"] == 6 and primary.stats["mean"] == pytest.approx(0.15)
    assert primary.stats["boot_low"] >= 0.10 and primary.tost[1] > 0.05  # all positive; not within 5 points
    # the same values: L better as the primary, not shown as a secondary once Holm has adjusted its p
    assert (primary.decision, first.decision) == ("L better", "neither shown")
