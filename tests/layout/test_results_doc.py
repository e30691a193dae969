"""docs/RESULTS.md against the study's committed summaries (docs/results/): every table in
the text is what docs/results/tables.py computes from them (docs/BENCHMARK.md's what
docs/results/benchmark.py computes from the committed `vitaplace difficulty` run), and the
summaries hold what the study promises (six methods, at least five seeds, three worlds, both touch models, bounded
intervals, the sign-flip p, recall at 100 % precision, the F1 at E1's threshold)."""

import csv
import importlib.util
import math
import re
from pathlib import Path

import pytest

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


def test_every_table_in_results_md_is_computed_from_the_committed_summaries():
    tables = tables_module()
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    found = dict(re.findall(r"<!-- table ([\w-]+) -->\n(.*?)\n<!-- /table -->", text, re.S))
    assert set(found) == set(tables.TABLES), "tables in RESULTS.md vs docs/results/tables.py"
    for name, table in found.items():
        assert table == tables.TABLES[name](), f"RESULTS.md table {name} differs from `python docs/results/tables.py {name}`"


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
    for name, low, high in (("sweep.csv", 0.0, 1.0), ("sweep-diff.csv", -1.0, 1.0)):
        for row in rows(study, name):
            if row.get("kind", "metric") != "metric":
                continue
            for interval in ("t", "boot", "block"):
                a, b = float(row[f"{interval}_low"]), float(row[f"{interval}_high"])
                assert not math.isnan(a) and not math.isnan(b), (name, row)
                assert low <= a <= b <= high, (name, interval, row)
    assert all(0 < float(row["p_sign_flip"]) <= 1 for row in rows(study, "sweep-diff.csv"))


def test_the_decomposition_of_l_minus_h_adds_up_and_its_touch_term_matches_the_paired_differences():
    """The decomposition table's third term, computed per seed in tables.py, is the
    difference of the summaries' L - L-V and H - H-V, and the terms add up to L - H."""
    tables = tables_module()
    for study in tables.STUDIES:
        for direction in tables.DIRECTIONS:
            for world in tables.WORLDS:
                def mean(a: str, b: str) -> float:
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
        assert table == benchmark.TABLES[name](), f"BENCHMARK.md table {name} differs from `python docs/results/benchmark.py`"
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
    for row, evaluation in zip(run, evaluations):
        assert {k: g["gate"] for k, g in row["gates"].items() if g["gate"] is not None} == evaluation["gates"]
        for name, gate in row["gates"].items():
            if gate["gate"] is None:
                assert gate["met"] is None
            elif gate["value"] is None:  # nothing to measure (vision never wrong) is not a gate met
                assert gate["met"] is False
            else:
                assert gate["met"] == (gate["value"] >= gate["gate"] if minimum[name] else gate["value"] <= gate["gate"])
