"""The sweep summary's statistics against independent references: Student's t from a
printed table, bootstrap intervals from hand cases and an exact enumeration, sign-flip
p-values from a plain loop over all 2**n sign patterns, the block bootstrap against
`evaluate` on the full matrices; intervals never leave a bounded metric's range; sample
counts, thresholds and difficulty are per method and never compared; recall at 100 %
precision and ``f1_at_e1_threshold`` reach every summary file."""

import csv
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation import resample
from vitaplace.engine.evaluation.difficulty import TOUCH_PAIR_KEYS
from vitaplace.engine.evaluation.pairfiles import evaluate_pair
from vitaplace.engine.study import summary

#: t(0.975, 2) and t(0.975, 1) from a printed table of Student's t quantiles
T_2, T_1 = 4.302653, 12.706205
INTERVALS = ("t", "boot", "block")


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def rows_for(values: dict[str, list[float]], seeds: list[int], **extra) -> list[dict]:
    return [
        {"seed": s, "environment": "E1", "method": m, "direction": "q", "max_f1": v[i], "tau": 0.3,
         "auc_method": "average_precision_stepwise", "recall_at_k": {"1": v[i] / 2}, "delta_at_max_f1": None,
         "n_queries": 300, **extra}
        for m, v in values.items() for i, s in enumerate(seeds)
    ]


# ---------------------------------------------------------------------- over seeds


def test_describe_matches_hand_computed_statistics():
    # 0.5, 0.7, 0.9: mean 0.7; deviations -0.2, 0, 0.2: s^2 = 0.08 / 2, s = 0.2;
    # half-width t(0.975, 2) * 0.2 / sqrt(3) = 0.497: [0.203, 1.197], cut to [0.203, 1] for a proportion
    stats = summary.describe([0.5, 0.7, 0.9])
    half = T_2 * 0.2 / math.sqrt(3)
    assert (stats["n"], stats["min"], stats["max"]) == (3, 0.5, 0.9)
    assert stats["mean"] == pytest.approx(0.7) and stats["std"] == pytest.approx(0.2)
    assert stats["t_low"] == pytest.approx(0.7 - half, abs=1e-6)
    assert stats["t_high"] == pytest.approx(0.7 + half, abs=1e-6)
    cut = summary.describe([0.5, 0.7, 0.9], (0.0, 1.0))
    assert cut["t_low"] == pytest.approx(0.7 - half, abs=1e-6) and cut["t_high"] == 1.0
    # two values 1 and 3, unbounded: mean 2, s = sqrt(2), half-width t(0.975, 1) * sqrt(2) / sqrt(2)
    two = summary.describe([1.0, 3.0])
    assert two["std"] == pytest.approx(math.sqrt(2)) and two["t_high"] == pytest.approx(2 + T_1, abs=1e-5)


def test_the_t_interval_is_cut_to_the_metric_s_range():
    # 0.99 and 1.0: mean 0.995, s = 0.01/sqrt(2), half-width T_1 * 0.005 = 0.0635: [0.9315, 1.0585] -> [0.9315, 1]
    stats = summary.describe([0.99, 1.0], (0.0, 1.0))
    assert stats["t_low"] == pytest.approx(0.995 - T_1 * 0.005, abs=1e-6) and stats["t_high"] == 1.0


def test_the_bootstrap_of_two_seeds_spans_them():
    # resampled means of (a, b): a w.p. 1/4, (a+b)/2 w.p. 1/2, b w.p. 1/4; the 2.5 and 97.5
    # percentiles are a and b
    stats = summary.describe([0.3, 0.9], (0.0, 1.0))
    assert (stats["boot_low"], stats["boot_high"]) == pytest.approx((0.3, 0.9))


def test_the_bootstrap_matches_the_exact_bootstrap_distribution():
    """Five seeds: all 5**5 equally likely resamples enumerated; the Monte Carlo percentile
    interval agrees within its sampling error."""
    x = np.array([0.62, 0.70, 0.71, 0.80, 0.95])
    means = np.array([x[list(idx)].mean() for idx in itertools.product(range(5), repeat=5)])
    exact = np.quantile(means, [0.025, 0.975])
    stats = summary.describe(x, (0.0, 1.0))
    assert (stats["boot_low"], stats["boot_high"]) == pytest.approx(tuple(exact), abs=0.006)


def test_one_seed_has_no_interval_over_seeds_and_says_so():
    stats = summary.describe([0.6], (0.0, 1.0))
    assert stats["n"] == 1 and stats["mean"] == 0.6
    assert all(math.isnan(stats[k]) for k in ("std", "t_low", "t_high", "boot_low", "boot_high", "block_low"))
    row = {"environment": "E1", "method": "L", "direction": "q", "metric": "max_f1", "kind": "metric", **stats}
    assert summary.cell(row) == "0.600 (n=1)"
    assert "0.600 (n=1)" in summary.markdown([row], [], "t") and "0.600 (n=1)" in summary.latex([row], [])


def finite_intervals(row: dict) -> list[tuple[float, float]]:
    return [(row[f"{k}_low"], row[f"{k}_high"]) for k in INTERVALS if not math.isnan(row[f"{k}_low"])]


@pytest.mark.parametrize("values", [[1.0, 1.0], [1.0] * 5, [0.0, 0.0, 0.0], [0.99, 1.0], [0.0, 0.02],
                                    [0.997, 0.999, 1.0, 1.0, 1.0], [0.607, 0.97],
                                    [0.16984068376742115] * 2])  # its resampled mean's float sum is 1 ulp above it
def test_no_interval_of_a_proportion_leaves_0_1(values):
    stats = summary.describe(values, summary.bounds("max_f1"), block=np.clip(np.array(values) + 0.01, 0, 1))
    intervals = finite_intervals(stats)
    assert len(intervals) == 3 and all(0.0 <= lo <= hi <= 1.0 for lo, hi in intervals), stats
    if len(set(values)) == 1:  # all equal: every interval is the value
        assert all(lo == hi == values[0] for lo, hi in intervals[:2])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=2, max_size=6), st.lists(st.floats(0.0, 1.0), min_size=2, max_size=6))
def test_intervals_of_proportions_and_of_their_differences_stay_in_range(a, b):
    assert all(0.0 <= lo <= hi <= 1.0 for lo, hi in finite_intervals(summary.describe(a, summary.bounds("recall@5"))))
    n = min(len(a), len(b))
    d = [x - y for x, y in zip(a[:n], b[:n], strict=True)]
    diff = summary.describe(d, summary.difference_bounds("auc"))
    assert all(-1.0 <= lo <= hi <= 1.0 for lo, hi in finite_intervals(diff))


def test_bounds_of_metrics():
    assert summary.bounds("recall_at_100_precision") == summary.bounds("recall@10") == (0.0, 1.0)
    assert summary.bounds("f1_at_e1_threshold") == (0.0, 1.0)
    assert summary.bounds("some_new_score") == (-math.inf, math.inf)
    assert summary.difference_bounds("max_f1") == (-1.0, 1.0)
    assert summary.difference_bounds("some_new_score") == (-math.inf, math.inf)


# ---------------------------------------------------------------------- paired differences


def brute_force_sign_flip_p(d: list[float]) -> float:
    """Share of the 2**n sign patterns whose mean is at least as far from 0 as the observed."""
    d = np.asarray(d, dtype=float)
    observed = abs(d.mean())
    flips = [abs((d * np.array(signs)).mean()) for signs in itertools.product((1, -1), repeat=len(d))]
    return sum(f >= observed * (1 - 1e-12) for f in flips) / 2 ** len(d)


def test_sign_flip_p_values_by_hand():
    # five positive differences: only "all +" and "all -" are as extreme: 2/32
    assert summary.sign_flip_p([0.1, 0.2, 0.05, 0.3, 0.01]) == pytest.approx(2 / 32, abs=1e-12)
    # +1 x4, -1: |sum| >= 3 for 0, 1, 4 or 5 minus signs: (1 + 5 + 5 + 1) / 32
    assert summary.sign_flip_p([1, 1, 1, 1, -1]) == pytest.approx(12 / 32, abs=1e-12)
    assert summary.sign_flip_p([0.2, 0.2]) == pytest.approx(2 / 4, abs=1e-12)  # ++ and --
    assert summary.sign_flip_p([0.0] * 4) == 1.0  # every pattern is as extreme as 0
    assert summary.sign_flip_p([0.3]) == 1.0


@pytest.mark.parametrize("n", [3, 6, 8])
def test_sign_flip_p_is_exact(n):
    """Equal to the full enumeration to 1e-12: no Monte Carlo sample."""
    d = list(np.random.default_rng(n).normal(0.2, 0.3, n))
    assert summary.sign_flip_p(d) == pytest.approx(brute_force_sign_flip_p(d), abs=1e-12)


def test_paired_differences_are_per_seed():
    # seeds 1, 2, 3: L = 0.8, 0.7, 0.9 and H = 0.6, 0.2, 0.5, so L - H = 0.2, 0.5, 0.4 (seed 4: L only)
    # mean 11/30, deviations -5/30, 4/30, 1/30: s^2 = (25 + 16 + 1) / 900 / 2 = 7/300; all
    # positive: p = 2/8
    rows = rows_for({"L": [0.9, 0.8, 0.7, 0.1]}, [3, 1, 2, 4]) + rows_for({"H": [0.6, 0.2, 0.5]}, [1, 2, 3])
    diffs = summary.paired_differences(summary.seed_rows(rows))
    (f1,) = [d for d in diffs if d["metric"] == "max_f1"]
    assert (f1["method_a"], f1["method_b"], f1["n"]) == ("L", "H", 3)
    std = math.sqrt(7 / 300)
    assert f1["mean"] == pytest.approx(11 / 30) and f1["std"] == pytest.approx(std)
    assert f1["t_low"] == pytest.approx(11 / 30 - T_2 * std / math.sqrt(3), abs=1e-6)
    assert f1["p_sign_flip"] == pytest.approx(2 / 8)
    assert (f1["min"], f1["max"]) == pytest.approx((0.2, 0.5))


# ---------------------------------------------------------------------- kinds of values


def test_counts_thresholds_and_difficulty_are_per_method_and_never_compared():
    rows = rows_for({"L": [0.9, 0.8], "H": [0.5, 0.6]}, [0, 1], n_revisit=217, tp=3)
    for i, row in enumerate(rows):
        row["delta_at_max_f1"] = 0.1 * (i + 1)
        row["tied_share"] = 0.25 * i  # how a method's distances tie: what its matrix was, not a score
        row["difficulty"] = {"overlap": 0.5 + i, "heading": {"median": 0.25, "name": "text"}, "list": [1, 2]}
    long = summary.seed_rows(rows)
    table = {(r["method"], r["metric"]): r for r in summary.summarise(long)}
    for name in ("n_queries", "n_revisit", "tp", "delta_at_max_f1", "tied_share", "difficulty.overlap",
                 "difficulty.heading.median"):
        assert table[("L", name)]["kind"] == "descriptor", name
        assert all(math.isnan(table[("L", name)][f"{k}_low"]) for k in INTERVALS)
    # L's thresholds on seeds 0 and 1 are 0.1 and 0.2 (rows in method order): its own mean, min, max
    assert (table[("L", "delta_at_max_f1")]["mean"], table[("L", "delta_at_max_f1")]["max"]) == pytest.approx(
        (0.15, 0.2))
    assert table[("H", "delta_at_max_f1")]["mean"] == pytest.approx(0.35)
    assert table[("L", "difficulty.overlap")]["mean"] == pytest.approx(1.0)
    assert ("L", "difficulty.heading.name") not in table and ("L", "difficulty.list") not in table
    diffs = summary.paired_differences(long)
    assert {d["metric"] for d in diffs} == {"max_f1", "recall@1"}
    md = summary.markdown(summary.summarise(long), diffs, "t")
    compared = md.split("## Paired differences")[1].split("## Per method")[0]
    assert "max_f1" in compared and "n_queries" not in compared and "delta_at_max_f1" not in compared
    assert "| E1 | H | q | delta_at_max_f1 | 2 | 0.35 | 0.3 | 0.4 |" in md


def test_the_touch_pair_measures_are_descriptors_and_seeds_of_older_runs_lack_them():
    # seed 0 an older run (no touch pairs), seed 1 no touched query with a true match
    # (correspondence null), seed 2 all three: n counts the seeds that have a value
    rows = rows_for({"H": [0.5, 0.6, 0.7]}, [0, 1, 2])
    rows[0]["difficulty"] = {"chance_r1": 0.1}
    rows[1]["difficulty"] = {"chance_r1": 0.1, "touch_both_share": 0.25, "touch_one_side_share": 0.5,
                             "touch_correspondence": None}
    rows[2]["difficulty"] = {"chance_r1": 0.1, "touch_both_share": 0.75, "touch_one_side_share": 0.0,
                             "touch_correspondence": 0.5}
    table = {r["metric"]: r for r in summary.summarise(summary.seed_rows(rows))}
    assert {k: table[f"difficulty.{k}"]["n"] for k in TOUCH_PAIR_KEYS} == {
        "touch_both_share": 2, "touch_one_side_share": 2, "touch_correspondence": 1}
    assert all(table[f"difficulty.{k}"]["kind"] == "descriptor" for k in TOUCH_PAIR_KEYS)
    assert table["difficulty.touch_both_share"]["mean"] == pytest.approx(0.5)


def test_every_numeric_value_is_summarised_and_settings_are_not():
    rows = rows_for({"L": [0.9, 0.8, 0.7]}, [0, 1, 2])
    rows[0]["delta_at_max_f1"] = 2.0  # finite on one seed only
    table = {r["metric"]: r for r in summary.summarise(summary.seed_rows(rows))}
    assert set(table) == {"max_f1", "recall@1", "delta_at_max_f1", "n_queries"}  # not tau, the text, the None
    assert table["recall@1"]["mean"] == pytest.approx(0.4) and table["recall@1"]["std"] == pytest.approx(0.05)
    assert table["delta_at_max_f1"]["n"] == 1


def test_recall_at_full_precision_and_f1_at_the_e1_threshold_reach_every_summary_file(tmp_path):
    rows = rows_for({"L": [0.9, 0.8], "H": [0.5, 0.6]}, [0, 1])
    for i, row in enumerate(rows):
        row["recall_at_100_precision"] = 0.1 * (i + 1)
        row["f1_at_e1_threshold"] = None if i == 0 else 0.5 + 0.1 * i  # null on L's seed 0
    summary.write_summary(tmp_path, rows, "t", {"scenario": "t"})
    for name in ("sweep-seeds.csv", "sweep.csv", "sweep-diff.csv", "sweep.md", "sweep.tex", "sweep.json"):
        text = (tmp_path / name).read_text()
        assert "recall_at_100_precision" in text.replace(r"\_", "_"), name
        assert "f1_at_e1_threshold" in text.replace(r"\_", "_"), name
    table = {(r["method"], r["metric"]): r for r in read_csv(tmp_path / "sweep.csv")}
    assert table[("L", "f1_at_e1_threshold")]["n"] == "1"
    assert float(table[("H", "f1_at_e1_threshold")]["mean"]) == pytest.approx(0.75)
    (diff,) = [r for r in read_csv(tmp_path / "sweep-diff.csv") if r["metric"] == "f1_at_e1_threshold"]
    assert diff["n"] == "1" and float(diff["mean"]) == pytest.approx(0.6 - 0.8)  # seed 1: L 0.6, H 0.8


def test_summary_files_are_written_with_nan_as_null(tmp_path):
    rows = rows_for({"L": [0.9], "H": [0.5]}, [7])
    summary.write_summary(tmp_path, rows, "t", {"scenario": "t"})
    record = json.loads((tmp_path / "sweep.json").read_text())  # strict JSON: no NaN
    assert record["summary"][0]["std"] is None and record["statistics"]["level"] == 0.95
    assert [r["value"] for r in read_csv(tmp_path / "sweep-seeds.csv") if r["metric"] == "max_f1"] == ["0.9", "0.5"]
    assert read_csv(tmp_path / "sweep-diff.csv")[0]["mean"] == str(0.9 - 0.5)


# ---------------------------------------------------------------------- drives without revisits


def rows_with_a_drive_without_revisits() -> list[dict]:
    """Seeds 0-3 of L and H; seed 1's drive has no revisit (its F1 0 is a convention), seed 3's
    has revisits that neither method found (its F1 0 is a score)."""
    rows = rows_for({"L": [0.9, 0.0, 0.6, 0.0], "H": [0.5, 0.0, 0.3, 0.1]}, [0, 1, 2, 3])
    for row in rows:
        row["n_revisit"] = 0 if row["seed"] == 1 else 10
    return rows


def test_a_drive_without_revisits_is_left_out_of_every_statistic_and_counted():
    long = summary.seed_rows(rows_with_a_drive_without_revisits())
    table = {(r["method"], r["metric"]): r for r in summary.summarise(long)}
    # L over seeds 0, 2, 3: 0.9, 0.6, 0.0: mean 0.5, deviations 0.4, 0.1, -0.5: s^2 = 0.42 / 2
    f1 = table[("L", "max_f1")]
    assert (f1["n"], f1["n_no_revisit"]) == (3, 1) and (f1["min"], f1["max"]) == (0.0, 0.9)
    assert f1["mean"] == pytest.approx(0.5) and f1["std"] == pytest.approx(math.sqrt(0.21))
    assert summary.cell(f1) == f"0.500 ± {math.sqrt(0.21):.3f} (3 of 4 seeds; 1 without revisits)"
    assert table[("H", "recall@1")]["mean"] == pytest.approx(0.15)  # (0.25 + 0.15 + 0.05) / 3
    # descriptors are what the drive was: every seed counts
    assert (table[("L", "n_revisit")]["n"], table[("L", "n_revisit")]["n_no_revisit"]) == (4, 0)
    assert table[("L", "n_revisit")]["mean"] == pytest.approx(7.5)
    # L - H on seeds 0, 2, 3: 0.4, 0.3, -0.1: mean 0.2, deviations 0.2, 0.1, -0.3: s^2 = 0.14 / 2;
    # |sum| >= 0.6 for 4 of the 8 sign patterns
    (diff,) = [d for d in summary.paired_differences(long) if d["metric"] == "max_f1"]
    assert (diff["n"], diff["n_no_revisit"]) == (3, 1)
    assert diff["mean"] == pytest.approx(0.2) and diff["std"] == pytest.approx(math.sqrt(0.07))
    assert diff["p_sign_flip"] == pytest.approx(4 / 8)


def test_a_zero_score_with_revisits_is_a_score_and_one_without_is_not():
    rows = rows_for({"L": [0.0, 0.0]}, [0, 1], n_revisit=4) + rows_for({"H": [0.0, 0.0]}, [0, 1], n_revisit=0)
    table = {(r["method"], r["metric"]): r for r in summary.summarise(summary.seed_rows(rows))}
    assert (table[("L", "max_f1")]["n"], table[("L", "max_f1")]["n_no_revisit"], table[("L", "max_f1")]["mean"]) == (
        2, 0, 0.0)
    none = table[("H", "max_f1")]
    assert (none["n"], none["n_no_revisit"]) == (0, 2) and math.isnan(none["mean"]) and math.isnan(none["t_low"])
    assert summary.cell(none) == "– (0 of 2 seeds; 2 without revisits)"
    assert summary.cell({**none, "n": 1, "mean": 0.25, "n_no_revisit": 1}) == "0.250 (1 of 2 seeds; 1 without revisits)"
    (diff,) = [d for d in summary.paired_differences(summary.seed_rows(rows)) if d["metric"] == "max_f1"]
    assert (diff["n"], diff["n_no_revisit"]) == (0, 2) and math.isnan(diff["p_sign_flip"])
    # rows of runs that lack n_revisit have their scores counted
    old = {(r["method"], r["metric"]): r for r in summary.summarise(summary.seed_rows(rows_for({"L": [0.0]}, [0])))}
    assert (old[("L", "max_f1")]["n"], old[("L", "max_f1")]["n_no_revisit"]) == (1, 0)


def test_the_block_interval_over_seeds_leaves_out_the_drives_without_revisits():
    # every replicate of a seed is its value: the mean over seeds 0, 2, 3 is 0.5 (0.375 with seed 1)
    rows = rows_with_a_drive_without_revisits()
    replicates = {(r["seed"], "E1", r["method"], "q"): {"max_f1": np.full(9, r["max_f1"])} for r in rows}
    long = summary.seed_rows(rows, replicates)
    table = {(r["method"], r["metric"]): r for r in summary.summarise(long, replicates)}
    assert (table[("L", "max_f1")]["block_low"], table[("L", "max_f1")]["block_high"]) == pytest.approx((0.5, 0.5))
    left = [r for r in long if r["seed"] == 1 and r["metric"] == "max_f1"]
    assert len(left) == 2 and all(r["no_revisit"] and math.isnan(r["block_low"]) for r in left)
    kept = [r for r in long if r["seed"] == 0 and r["metric"] == "max_f1"]
    assert all(not r["no_revisit"] and r["block_low"] == r["value"] for r in kept)


def test_the_drives_without_revisits_are_named_in_every_summary_file(tmp_path, caplog):
    with caplog.at_level("WARNING", logger="vitaplace"):
        record = summary.write_summary(tmp_path, rows_with_a_drive_without_revisits(), "t", {"scenario": "t"})
    assert record["without_revisits"] == [{"seed": 1, "environment": "E1", "direction": "q", "methods": ["L", "H"]}]
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "seed 1, E1 q: no revisit" in warned[0] and "left out" in warned[0]
    md = (tmp_path / "sweep.md").read_text()
    assert "## Seeds without revisits" in md and "| 1 | E1 | q | L, H |" in md
    assert "(3 of 4 seeds; 1 without revisits)" in md
    assert "(3 of 4 seeds; 1 without revisits)" in (tmp_path / "sweep.tex").read_text()
    table = {(r["method"], r["metric"]): r for r in read_csv(tmp_path / "sweep.csv")}
    assert (table[("L", "max_f1")]["n"], table[("L", "max_f1")]["n_no_revisit"]) == ("3", "1")
    assert {r["seed"] for r in read_csv(tmp_path / "sweep-seeds.csv") if r["no_revisit"] == "True"} == {"1"}
    assert read_csv(tmp_path / "sweep-diff.csv")[0]["n_no_revisit"] == "1"


# ---------------------------------------------------------------------- within a seed


def test_block_length_and_draws():
    assert [resample.block_length(q) for q in (1, 4, 5, 300)] == [1, 2, 3, 18]  # ceil(sqrt(Q))
    draws = resample.block_draws(10, seed=3, resamples=50)  # L = 4: segments [0,4), [4,8), [8,10)
    segments = {(0, 1, 2, 3), (4, 5, 6, 7), (8, 9)}
    for rows in draws:
        cut, parts = list(rows), []
        while cut:  # split back into segments: each starts at a multiple of 4
            start = cut[0]
            assert start % 4 == 0
            length = 4 if start < 8 else 2
            parts.append(tuple(cut[:length]))
            cut = cut[length:]
        assert len(parts) == 3 and set(parts) <= segments
    assert all((a == b).all() for a, b in zip(draws, resample.block_draws(10, seed=3, resamples=50), strict=True))
    assert any(len(a) != len(b) or (a != b).any()
               for a, b in zip(draws, resample.block_draws(10, seed=4, resamples=50), strict=True))


@pytest.mark.parametrize("kmax", [1, 3, 5, 9])
def test_compact_matrices_keep_every_metric(kmax):
    """Ties in the TME (integers) and in the ground truth; a true match often outside the K
    nearest in TME; K up to the number of references. Every metric of any set of rows equals
    that of the full matrices (``n_references`` counts columns and is not a metric)."""
    rng = np.random.default_rng(kmax)
    tme = rng.integers(0, 6, (40, 9)).astype(float)
    gtm = rng.integers(0, 8, (40, 9)) / 10.0
    tme[3] = np.inf
    small_tme, small_gtm = resample.compact_matrices(tme, gtm, kmax)
    ks = tuple(k for k in (1, 2, 3, 5, 9) if k <= kmax)
    for rows in [np.arange(40), *resample.block_draws(40, seed=kmax, resamples=20)]:
        full = ev.evaluate(tme[rows], gtm[rows], 0.3, delta=2.0, ks=ks)
        small = ev.evaluate(small_tme[rows], small_gtm[rows], 0.3, delta=2.0, ks=ks)
        assert ({k: v for k, v in small.items() if k != "n_references"}
                == {k: v for k, v in full.items() if k != "n_references"})


@pytest.fixture
def few_replicates(monkeypatch):
    """300 block replicates instead of the default (quicker; the same definitions)."""
    monkeypatch.setattr(resample, "RESAMPLES", 300)


#: a fixed acceptance threshold: the rows also have F1, precision and recall there
DELTA = 0.3


def evaluation(folder: Path, seed: int, method: str, noise: float, n: int = 40) -> dict:
    """A query run along the reference run, features = positions plus noise; the matrices
    saved where a run folder keeps them; its results row."""
    rng = np.random.default_rng([seed, int(noise * 100)])
    t = np.linspace(0.0, 6.0, n)
    ref = np.c_[np.cos(t), np.sin(t)]
    query = ref + rng.normal(0.0, 0.05, ref.shape)
    tme = ev.ground_truth_matrix(query, ref) + rng.normal(0.0, noise, (n, n)) ** 2
    path = folder / f"seed-{seed}" / "evaluations" / "E1" / method / "q"
    path.mkdir(parents=True)
    row = evaluate_pair(path, tme, query, ref, 0.3, delta=DELTA, ks=(1, 5))
    return {"seed": seed, "environment": "E1", "method": method, "direction": "q", **row}


def full_replicates(folder: Path, row: dict, metric: str) -> np.ndarray:
    """The metric of each block draw, recomputed by `evaluate` on the full saved matrices."""
    path = folder / f"seed-{row['seed']}" / "evaluations" / "E1" / row["method"] / "q" / "matrices.npz"
    with np.load(path) as m:
        tme, gtm = m["tme"], m["gtm"]
    return np.array([summary.row_values(ev.evaluate(tme[r], gtm[r], 0.3, DELTA, ks=(1, 5)))[metric]
                     for r in resample.block_draws(len(tme), row["seed"])])


def test_a_single_seed_gets_a_block_bootstrap_interval(tmp_path, few_replicates):
    rows = [evaluation(tmp_path, 5, "L", 0.6), evaluation(tmp_path, 5, "H", 0.9)]
    summary.write_summary(tmp_path, rows, "t", {}, {5: tmp_path / "seed-5"})
    table = {(r["method"], r["metric"]): r for r in read_csv(tmp_path / "sweep.csv")}
    seeds = {(r["method"], r["metric"]): r for r in read_csv(tmp_path / "sweep-seeds.csv")}
    for (method, row), metric in itertools.product((("L", rows[0]), ("H", rows[1])), ("max_f1", "f1")):
        expected = pytest.approx(tuple(np.quantile(full_replicates(tmp_path, row, metric), [0.025, 0.975])), abs=1e-12)
        got, seed = table[(method, metric)], seeds[(method, metric)]
        assert (float(got["block_low"]), float(got["block_high"])) == expected
        assert (float(seed["block_low"]), float(seed["block_high"])) == expected
        assert got["t_low"] == "nan" and got["n"] == "1"
    for metric in ("max_f1", "f1"):  # not degenerate
        assert float(table[("H", metric)]["block_low"]) < float(table[("H", metric)]["block_high"])
    assert seeds[("H", "auc")]["block_length"] == "7"  # ceil(sqrt(40))
    assert seeds[("H", "n_queries")]["block_low"] == "nan"  # descriptors get no interval
    # paired: the same segments for both methods, differenced replicate by replicate
    diff = read_csv(tmp_path / "sweep-diff.csv")[0]
    expected = np.quantile(full_replicates(tmp_path, rows[0], "max_f1") - full_replicates(tmp_path, rows[1], "max_f1"),
                           [0.025, 0.975])
    assert (float(diff["block_low"]), float(diff["block_high"])) == pytest.approx(tuple(expected), abs=1e-12)
    assert all(0.0 <= float(r[f"block_{s}"]) <= 1.0
               for r in table.values() if r["kind"] == "metric" for s in ("low", "high"))


def test_the_block_interval_over_seeds_is_that_of_the_mean_of_the_seeds_replicates(tmp_path, few_replicates):
    rows = [evaluation(tmp_path, seed, "H", 0.9) for seed in (0, 1)]
    summary.write_summary(tmp_path, rows, "t", {}, {0: tmp_path / "seed-0", 1: tmp_path / "seed-1"})
    (got,) = [r for r in read_csv(tmp_path / "sweep.csv") if r["metric"] == "auc"]
    mean = (full_replicates(tmp_path, rows[0], "auc") + full_replicates(tmp_path, rows[1], "auc")) / 2
    assert (float(got["block_low"]), float(got["block_high"])) == pytest.approx(
        tuple(np.quantile(mean, [0.025, 0.975])), abs=1e-12)


def test_rows_without_saved_matrices_have_no_block_interval(tmp_path, few_replicates):
    rows = [evaluation(tmp_path, 0, "H", 0.9), evaluation(tmp_path, 1, "H", 0.9)]
    (tmp_path / "seed-1" / "evaluations" / "E1" / "H" / "q" / "matrices.npz").unlink()
    summary.write_summary(tmp_path, rows, "t", {}, {0: tmp_path / "seed-0", 1: tmp_path / "seed-1"})
    (got,) = [r for r in read_csv(tmp_path / "sweep.csv") if r["metric"] == "auc"]
    assert got["block_low"] == "nan" and got["t_low"] != "nan"


def test_block_replicates_on_worker_processes_are_those_of_one_process(tmp_path):
    """One seed per task on two spawned workers: the same rows, in the same order, with the
    same replicates as in this process (the default resample count: workers do not see a
    patched one)."""
    rows = [evaluation(tmp_path, seed, method, noise)
            for seed in (0, 1, 2) for method, noise in (("H", 0.9), ("L", 0.3))]
    folders = {seed: tmp_path / f"seed-{seed}" for seed in (0, 1, 2)}
    here, spread = summary.block_replicates(rows, folders), summary.block_replicates(rows, folders, workers=2)
    assert list(spread) == list(here) == [tuple(r[k] for k in summary.IDENTITY) for r in rows]
    for identity, values in here.items():
        assert values.keys() == spread[identity].keys()
        for name, replicates in values.items():
            np.testing.assert_array_equal(spread[identity][name], replicates)


# ---------------------------------------------------------------------- the PR-band figure


def test_the_pr_band_figure_says_what_its_line_and_band_are(monkeypatch, tmp_path):
    from vitaplace.engine.report import figures
    legends = []
    monkeypatch.setattr(figures, "_save", lambda fig, stem: legends.append(fig.legends[0].get_title().get_text()) or [])
    curve = ev.pr_curve(np.array([[0.1, 0.9], [0.8, 0.2]]), np.array([[0.0, 1.0], [1.0, 0.0]]), 0.3)
    figures.plot_pr_bands(tmp_path / "a", {"L": [curve, curve]}, "E1: precision-recall over seeds")
    figures.plot_pr_bands(tmp_path / "b", {"L": [curve]})
    assert len(legends) == 2
    for legend in legends:
        assert "line: mean interpolated precision over seeds" in legend and "band: lowest to highest seed" in legend


@pytest.mark.parametrize("threshold", [0.4, None])
def test_block_replicates_carry_f1_at_the_training_world_s_threshold(threshold):
    """Each replicate's ``f1_at_e1_threshold`` is the F1 of its rows at the row's
    ``e1_threshold`` (None: nothing accepted, F1 0), as a direct pr_curve on the full matrices."""
    rng = np.random.default_rng(7)
    tme, gtm = rng.random((30, 12)), rng.random((30, 12))
    row = {"tau": 0.3, "delta": None, "recall_at_k": {"1": 0.0}, "f1_at_e1_threshold": 0.5, "e1_threshold": threshold}
    replicates = resample.replicate_rows(tme, gtm, row, seed=2, resamples=25)
    expected = [ev.pr_curve(tme[r], gtm[r], 0.3, [-math.inf if threshold is None else threshold]).f1[0]
                for r in resample.block_draws(30, 2, 25)]
    assert [r["f1_at_e1_threshold"] for r in replicates] == pytest.approx(expected)
    assert (threshold is None) == all(v == 0 for v in expected)
    assert "f1_at_e1_threshold" not in resample.replicate_rows(tme, gtm, {**row, "f1_at_e1_threshold": None}, 2, 5)[0]
