"""docs/RESULTS.md against the study's committed summaries (docs/results/): every table in
the text is what docs/results/tables.py computes from them (docs/BENCHMARK.md's what
docs/results/benchmark.py computes from the committed `vitaplace difficulty` run), and the
summaries hold what the studies promise (the first: six methods, at least five seeds, three worlds, both touch
models, bounded intervals, the sign-flip p, recall at 100 % precision, the F1 at E1's threshold; the second: every
method and condition at eight seeds, bounded intervals, the pre-registered endpoints as decided by
`vitaplace.engine.study.hypotheses` (whose rules tests/components/test_hypotheses.py checks by hand), the gates, the
budget trend)."""

import csv
import importlib.util
import math
import re
import statistics
from pathlib import Path

import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
SIX = {"L", "L-V", "L-T", "H", "H-V", "H-T"}


def tables_module():
    spec = importlib.util.spec_from_file_location("results_tables", RESULTS / "tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rows(study: str, name: str) -> list[dict[str, str]]:
    with open(RESULTS / study / name, newline="") as handle:
        return list(csv.DictReader(handle))


def assert_bounded_intervals(study: str | Path, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    """Every metric row's ``required`` intervals exist and, like the ``optional`` ones where
    present, lie inside the metric's range ([0, 1], a difference's [-1, 1]); every sign-flip p
    in (0, 1]."""
    for name, low, high in (("sweep.csv", 0.0, 1.0), ("sweep-diff.csv", -1.0, 1.0)):
        for row in rows(study, name):
            if row.get("kind", "metric") != "metric":
                continue
            for interval in (*required, *optional):
                a, b = float(row[f"{interval}_low"]), float(row[f"{interval}_high"])
                if interval in optional and math.isnan(a) and math.isnan(b):
                    continue
                assert not math.isnan(a) and not math.isnan(b), (name, row)
                assert low <= a <= b <= high, (name, interval, row)
    assert all(0 < float(row["p_sign_flip"]) <= 1 for row in rows(study, "sweep-diff.csv"))


def test_every_table_in_results_md_is_computed_from_the_committed_summaries():
    tables = tables_module()
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    found = dict(re.findall(r"<!-- table ([\w-]+) -->\n(.*?)\n<!-- /table -->", text, re.S))
    assert set(found) == set(tables.TABLES), "tables in RESULTS.md vs docs/results/tables.py"
    for name, table in found.items():
        assert table == tables.TABLES[name](), (
            f"RESULTS.md table {name} differs from `python docs/results/tables.py {name}`")


@pytest.mark.parametrize("study", ["paper-cpu-sweep", "paper-cpu-physical-sweep"])
def test_the_committed_study_holds_six_methods_five_seeds_and_bounded_intervals(study):
    seeds = rows(study, "sweep-seeds.csv")
    per_cell: dict[tuple[str, str], set[str]] = {}
    for row in seeds:
        per_cell.setdefault((row["environment"], row["method"]), set()).add(row["seed"])
    assert {env for env, _ in per_cell} == {"E1", "E2", "E3"}
    assert {method for _, method in per_cell} == SIX
    assert all(len(s) >= 5 for s in per_cell.values()), {k: len(v) for k, v in per_cell.items()}
    metrics = {row["metric"] for row in rows(study, "sweep.csv")}
    assert {"max_f1", "recall_at_100_precision", "f1_at_e1_threshold"} <= metrics
    assert_bounded_intervals(study, required=("t", "boot", "block"))


def test_the_decomposition_of_l_minus_h_adds_up_and_its_touch_term_matches_the_paired_differences():
    """The decomposition table's third term, computed per seed in tables.py, is the
    difference of the summaries' L - L-V and H - H-V, and the terms add up to L - H."""
    tables = tables_module()
    for study in tables.STUDIES:
        for direction in tables.DIRECTIONS:
            for world in tables.WORLDS:
                def mean(a: str, b: str, study: str = study, world: str = world, direction: str = direction) -> float:
                    return float(tables._difference(study, world, direction, a, b)["mean"])
                per_seed, stats, p = tables.interaction(study, world, direction)
                assert len(per_seed) >= 5 and stats["n"] == len(per_seed)
                assert stats["mean"] == pytest.approx(mean("L", "L-V") - mean("H", "H-V"), abs=1e-12)
                assert mean("L", "H") == pytest.approx(mean("L-V", "H-V") + stats["mean"], abs=1e-12)
                assert stats["t_low"] <= stats["mean"] <= stats["t_high"] and 0 < p <= 1


def test_every_table_in_benchmark_md_is_computed_from_the_committed_difficulty_run():
    spec = importlib.util.spec_from_file_location("benchmark_tables", RESULTS / "benchmark.py")
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    text = (ROOT / "docs" / "BENCHMARK.md").read_text()
    found = dict(re.findall(r"<!-- table ([\w-]+) -->\n(.*?)\n<!-- /table -->", text, re.S))
    assert set(found) == set(benchmark.TABLES), "tables in BENCHMARK.md vs docs/results/benchmark.py"
    for name, table in found.items():
        assert table == benchmark.TABLES[name](), (
            f"BENCHMARK.md table {name} differs from `python docs/results/benchmark.py`")
    assert benchmark.written(text) == text


def test_the_committed_difficulty_run_checks_every_evaluation_of_the_touch_benchmark_against_its_gates():
    import json

    import yaml

    scenario = yaml.safe_load((ROOT / "scenarios" / "touch-benchmark.yaml").read_text())
    run = json.loads((RESULTS / "touch-benchmark-difficulty" / "difficulty.json").read_text())
    evaluations = [e for e in scenario["evaluations"] for _ in ("query-to-reference", "reference-to-query")]
    assert [(r["environment"], r["direction"]) for r in run] == [
        (e["name"], d) for e in scenario["evaluations"] for d in ("query-to-reference", "reference-to-query")]
    minimum = {"touch_correspondence_min": True, "rescue_min": True, "hv_max_f1_max": False}
    for row, evaluation in zip(run, evaluations, strict=True):
        assert {k: g["gate"] for k, g in row["gates"].items() if g["gate"] is not None} == evaluation["gates"]
        for name, gate in row["gates"].items():
            if gate["gate"] is None:
                assert gate["met"] is None
            elif gate["value"] is None:  # nothing to measure (vision never wrong) is not a gate met
                assert gate["met"] is False
            else:
                assert gate["met"] == (gate["value"] >= gate["gate"] if minimum[name]
                                       else gate["value"] <= gate["gate"])


# The second study (RESULTS.md, "Second study"): three arms, one summaries' folder per grid point.
SECOND = ["touch/length=1", "touch/length=16", "drop-out/length=1", "drop-out/length=16", "faithful/length=1"]


@pytest.mark.parametrize("key", SECOND)
def test_the_second_study_holds_every_method_and_evaluation_at_eight_seeds_with_bounded_intervals(key):
    tables = tables_module()
    arm = key.split("/")[0]
    folder = tables.POINTS[key]
    seeds = rows(folder.relative_to(RESULTS), "sweep-seeds.csv")
    per_cell: dict[tuple[str, str], set[str]] = {}
    for row in seeds:
        if row["metric"] == "max_f1":
            per_cell.setdefault((row["environment"], row["method"]), set()).add(row["seed"])
    expected_methods = ({"L", "L-V", "L-T", "L-cycle", "H", "H-V", "H-T", "L-F", "H-F"}
                        | ({"A"} if arm != "drop-out" else set()))
    assert {env for env, _ in per_cell} == set(tables.ARMS[arm][2])
    assert {method for _, method in per_cell} == expected_methods
    assert all(s == {str(i) for i in range(8)} for s in per_cell.values()), {k: len(v) for k, v in per_cell.items()}
    # the drop-out condition's rows have no block interval (its camera-less queries: distance +inf)
    assert_bounded_intervals(folder.relative_to(RESULTS), required=("t", "boot"), optional=("block",))


def test_the_primary_endpoint_is_l_minus_the_better_comparator_in_every_seed():
    """Recomputed from sweep-seeds.csv: per seed L - max(L-V, L-F), never above either
    difference; where L-F >= L-V in every seed (as w = 0 on the grid promises) it is the
    summaries' L - L-F row."""
    tables = tables_module()
    seeds = rows("study2-sweep/length=1", "sweep-seeds.csv")
    value = {(r["seed"], r["method"]): float(r["value"]) for r in seeds
             if (r["environment"], r["direction"], r["metric"]) == ("alike-shapes", tables.Q2R, "max_f1")}
    primary = tables.endpoints()[0]
    assert (primary["key"], primary["world"], primary["direction"]) == ("touch/length=1", "alike-shapes", tables.Q2R)
    expected = [value[(s, "L")] - max(value[(s, "L-V")], value[(s, "L-F")]) for s in map(str, range(8))]
    assert primary["values"] == pytest.approx(expected, abs=1e-15)
    for s, d in zip(map(str, range(8)), primary["values"], strict=True):
        assert d <= value[(s, "L")] - value[(s, "L-V")] + 1e-15 and d <= value[(s, "L")] - value[(s, "L-F")] + 1e-15
    if all(value[(s, "L-F")] >= value[(s, "L-V")] for s in map(str, range(8))):
        diff = tables._difference("touch/length=1", "alike-shapes", tables.Q2R, "L", "L-F")
        assert primary["stats"]["mean"] == pytest.approx(float(diff["mean"]), abs=1e-12)
        assert primary["p"] == pytest.approx(float(diff["p_sign_flip"]), abs=1e-12)
    low, high = primary["stats"]["boot_low"], primary["stats"]["boot_high"]
    assert -1 <= low <= primary["stats"]["mean"] <= high <= 1
    endpoints = tables.endpoints()
    assert len(endpoints) == 7 and all(e["stats"]["n"] == 8 for e in endpoints)
    # the TOST's interval: mean -+ t(0.95, 7) sd / sqrt(8), two one-sided tests at 0.05
    half = stats.t.ppf(0.95, 7) * statistics.stdev(expected) / math.sqrt(8)
    assert primary["tost"] == pytest.approx((statistics.fmean(expected) - half, statistics.fmean(expected) + half))
    # Holm over the six secondaries only; the primary keeps its own p
    assert primary["p_holm"] == primary["p"]
    ps = sorted(e["p"] for e in endpoints[1:])
    assert min(e["p_holm"] for e in endpoints[1:]) == pytest.approx(min(1.0, 6 * ps[0]))


@pytest.mark.parametrize("arm", ["touch", "drop-out"])
def test_seed_0s_gates_read_from_the_sweep_are_the_committed_difficulty_runs(arm):
    """The gates of seeds 1-7 are read from the sweeps' H-family evaluations: for seed 0 that
    reading gives exactly what `vitaplace difficulty` measured."""
    import json

    from vitaplace.engine.cli.difficulty import difficulty_rows
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.outputs.rows import parse_row

    tables = tables_module()
    folder, scenario_file = tables.ARMS[arm][:2]
    scenario, _ = load_scenario(ROOT / "scenarios" / scenario_file)
    seed0 = folder / "length=1" / "seeds" / "seed-0"
    rows = [parse_row(row, "seed-0/results.json") for row in json.loads((seed0 / "results.json").read_text())]
    from_sweep = difficulty_rows(scenario, rows, json.loads((seed0 / "complementarity.json").read_text()))
    committed = json.loads((tables.DIFFICULTY2 / f"{scenario_file.removesuffix('.yaml')}-seed-0.json").read_text())
    assert json.dumps(from_sweep, sort_keys=True) == json.dumps(committed, sort_keys=True)
    assert len(tables._gate_rows(arm)) == 8


def test_the_second_studys_decomposition_adds_up_in_every_cell():
    tables = tables_module()
    cells = tables.cells2()
    # both directions: touch and drop-out at two matchings, faithful at one
    assert len(cells) == 2 * (5 * 2 + 2 * 2 + 3)
    for key, world, direction in cells:
        def mean(a: str, b: str, key: str = key, world: str = world, direction: str = direction) -> float:
            return float(tables._difference(key, world, direction, a, b)["mean"])
        per_seed, stats, p = tables.interaction(key, world, direction)
        assert len(per_seed) == 8 and stats["mean"] == pytest.approx(mean("L", "L-V") - mean("H", "H-V"), abs=1e-12)
        assert mean("L", "H") == pytest.approx(mean("L-V", "H-V") + stats["mean"], abs=1e-12)


@pytest.mark.parametrize("epochs", [30, 70, 270])
def test_the_budget_trend_trained_l_and_l_v_at_its_epoch_cap_on_seed_0(epochs):
    import json

    tables = tables_module()
    manifest = json.loads((tables.BUDGET2 / f"epochs={epochs}" / "seeds" / "seed-0" / "manifest.json").read_text())
    for method in ("L", "L-V"):
        trained = manifest["training"][method]
        assert trained["max_epochs"] == epochs and 1 <= trained["epochs"] <= epochs
    values, _ = tables._budget_values(epochs)
    assert {(w, m) for w, m, _ in values} == {(w, m) for w in tables.ARMS["touch"][2] for m in ("L", "L-V")}
