"""docs/RESULTS.md against the study's committed summaries (docs/results/): every table in
the text is what docs/results/tables.py computes from them (docs/BENCHMARK.md's what
docs/results/benchmark.py computes from the committed `vitaplace difficulty` run), and the
summaries hold what the studies promise (the first: six methods, at least five seeds, three worlds, both touch
models, bounded intervals, the sign-flip p, recall at 100 % precision, the F1 at E1's threshold; the second: every
method and condition at eight seeds, bounded intervals, the pre-registered endpoints as decided by
`vitaplace.engine.study.hypotheses` (whose rules tests/components/test_hypotheses.py checks by hand), the gates, the
budget trend)."""

import importlib.util
import json
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
    return tables_module().read_csv(RESULTS / study / name)


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


def marked_tables(text: str) -> dict[str, str]:
    """Name -> body of every ``<!-- table NAME -->`` ... ``<!-- /table -->`` block; each opening
    marker has exactly one closing marker (a stray one is a paste error)."""
    found = re.findall(r"<!-- table ([\w-]+) -->\n(.*?)\n<!-- /table -->", text, re.S)
    assert text.count("<!-- /table -->") == text.count("<!-- table ") == len(found), "unmatched table markers"
    assert len({name for name, _ in found}) == len(found), "a table is printed twice"
    return dict(found)


def test_every_table_in_results_md_is_computed_from_the_committed_summaries():
    tables = tables_module()
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    found = marked_tables(text)
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
    found = marked_tables(text)
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

    from vitaplace.engine.cli.difficulty import difficulty_rows, headroom
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.outputs.rows import parse_row

    tables = tables_module()
    folder, scenario_file = tables.ARMS[arm][:2]
    scenario, _ = load_scenario(ROOT / "scenarios" / scenario_file)
    seed0 = folder / "length=1" / "seeds" / "seed-0"
    rows = [parse_row(row, "seed-0/results.json") for row in json.loads((seed0 / "results.json").read_text())]
    from_sweep = difficulty_rows(scenario, rows, json.loads((seed0 / "complementarity.json").read_text()))
    committed = json.loads((tables.DIFFICULTY2 / f"{scenario_file.removesuffix('.yaml')}-seed-0.json").read_text())
    for row in from_sweep:  # the headroom gate came after these runs
        undeclared = {"gate": None, "value": headroom(row["complementarity"]), "met": None}
        assert row["gates"].pop("headroom_min") == undeclared
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


def test_rank_replicates_ranks_each_resample_of_the_seeds_paired_across_methods():
    """Closed forms: a method ahead in every seed is first in every resample; one ahead only
    when seed 0 is drawn at least twice of three is first with probability
    P(Binomial(3, 1/3) >= 2) = 7/27; a method 0.01 above another in every seed stays above it in
    every resample only if the seeds are drawn once for both (paired), although the seeds
    differ by far more."""
    import numpy as np

    tables = tables_module()
    n = 20000
    ranks = tables.rank_replicates({
        "a": {"X": np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0]]), "Y": np.full((3, 2), 0.25),
              "Z": np.full((3, 2), -1.0)},
        "b": {"P": np.array([[0.0], [0.5], [0.9]]), "Q": np.array([[0.01], [0.51], [0.91]])}}, resamples=n, seed=1)
    assert ranks["a"]["Z"].tolist() == [3] * n
    # X's mean over the drawn seeds and cells is (seed-0 draws) / 6: above Y's 0.25 when drawn >= 2 times
    assert np.mean(ranks["a"]["X"] == 1) == pytest.approx(7 / 27, abs=0.01)
    assert sorted(set(ranks["a"]["X"].tolist())) == [1, 2] and (ranks["a"]["X"] + ranks["a"]["Y"] == 3).all()
    assert ranks["b"]["Q"].tolist() == [1] * n and ranks["b"]["P"].tolist() == [2] * n


def test_mean_ranks_average_over_the_points_a_method_ran_in_and_share_ties():
    import numpy as np

    tables = tables_module()
    ranks = {"p1": {"X": np.array([1, 2]), "Y": np.array([2, 1]), "A": np.array([3, 3])},
             "p2": {"X": np.array([1, 1]), "Y": np.array([2, 2])}}
    mean, best = tables.mean_ranks(ranks, ["p1", "p2"])
    assert mean["X"].tolist() == [1.0, 1.5] and mean["Y"].tolist() == [2.0, 1.5] and mean["A"].tolist() == [3.0, 3.0]
    # resample 1: X alone lowest; resample 2: X and Y tie and share it
    assert best == {"X": 0.75, "Y": 0.25, "A": 0.0}


def test_the_rank_table_ranks_the_per_seed_values_of_every_cell():
    """The arrays ranked are the summaries' per-seed max F1: each method's mean over seeds and
    cells is the ranking's own average (`study2_rank`'s), for every arm and matching."""
    tables = tables_module()
    for key in tables.POINTS:
        values, averages = tables._point_values(key), tables._averages(key)
        assert set(values) == set(averages)
        for method, array in values.items():
            assert array.shape == (8, len(tables.cells2([key])))
            assert array.mean() == pytest.approx(averages[method], abs=1e-12)


def _complementarity_files(folder: str) -> list[list[dict]]:
    import json

    return [json.loads((RESULTS / folder / "length=1" / "seeds" / f"seed-{s}" / "complementarity.json").read_text())
            for s in range(8)]


def _percent_points(x: float) -> str:
    """A difference of proportions as the prose writes it: points, one decimal, a true minus."""
    return f"{100 * x:.1f}".replace("-", "−")


def second_study_numbers() -> dict[str, str]:
    """Every number the corrected text of the second study quotes, recomputed from the
    committed files (summaries, complementarity.json, manifests), formatted as written."""
    import json

    tables = tables_module()
    pts, p = _percent_points, tables.p_value
    touch, faithful, dropout = "touch/length=1", "faithful/length=1", "drop-out/length=1"

    def diff(key: str, world: str, direction: str, a: str, b: str) -> dict[str, str]:
        return tables._difference(key, world, direction, a, b)

    out: dict[str, str] = {}
    primary = tables.endpoints()[0]
    out["primary"] = pts(primary["stats"]["mean"])
    out["primary_low"], out["primary_high"] = pts(primary["stats"]["boot_low"]), pts(primary["stats"]["boot_high"])
    out["primary_p"] = p(primary["p"])
    out["primary_abs"] = out["primary"].removeprefix("−")
    lv = diff(touch, "alike-shapes", tables.Q2R, "L", "L-V")
    out["l_lv"], out["l_lv_low"], out["l_lv_high"] = pts(float(lv["mean"])), pts(float(lv["boot_low"])), pts(
        float(lv["boot_high"]))
    out["l_lv_p"] = p(lv["p_sign_flip"])
    out["lf_lv"] = pts(float(diff(touch, "alike-shapes", tables.Q2R, "L-F", "L-V")["mean"]))
    # the aliasing gate (H-V max F1 <= 85 %), seeds that fail it, each direction
    for direction, name in ((tables.Q2R, "q2r"), (tables.R2Q, "r2q")):
        gates = [next(r for r in seed if (r["environment"], r["direction"]) == ("alike-shapes", direction))["gates"]
                 for seed in tables._gate_rows("touch").values()]
        assert all(g["hv_max_f1_max"]["gate"] == 0.85 for g in gates) and len(gates) == 8
        out[f"gate_failed_{name}"] = str(sum(g["hv_max_f1_max"]["value"] > 0.85 for g in gates))
    # a fusion's headroom: mean over seeds of oracle recall@1 minus the better single modality (read here, not
    # through tables.py)
    def headroom(folder: str, world: str, direction: str, vision: str) -> float:
        cells = [next(c for c in seed if (c["environment"], c["direction"], c["vision"]) == (world, direction, vision))
                 for seed in _complementarity_files(folder)]
        return statistics.fmean(c["oracle_r1"] - max(c["vision_r1"], c["touch_r1"]) for c in cells)

    out["room_l"] = pts(headroom("study2-sweep", "alike-shapes", tables.Q2R, "L-V"))
    out["room_h"] = pts(headroom("study2-sweep", "alike-shapes", tables.Q2R, "H-V"))
    room = [headroom(folder, world, direction, vision)
            for folder, world, directions in (("study2-sweep", "distinct-shapes-dusk", (tables.Q2R, tables.R2Q)),
                                              ("study2-dropout-sweep", "distinct-shapes-dropout", (tables.Q2R,)))
            for direction in directions for vision in ("L-V", "H-V")]
    out["room_min"], out["room_max"] = pts(min(room)), pts(max(room))
    for key, world, direction, name in ((touch, "distinct-shapes-dusk", tables.Q2R, "dusk_q2r"),
                                        (touch, "distinct-shapes-dusk", tables.R2Q, "dusk_r2q"),
                                        (dropout, "distinct-shapes-dropout", tables.Q2R, "dropout")):
        out[f"l_h_{name}"] = pts(float(diff(key, world, direction, "L", "H")["mean"]))
    # E3: the endpoint, the other direction, and the hand-crafted fusion and vision against L
    e3 = tables.endpoints()[6]
    assert (e3["world"], e3["comparison"]) == ("E3", "L − H")
    out["e3"], out["e3_low"], out["e3_high"] = (pts(e3["stats"]["mean"]), pts(e3["stats"]["boot_low"]),
                                                pts(e3["stats"]["boot_high"]))
    out["e3_holm"] = p(e3["p_holm"])
    r2q = diff(faithful, "E3", tables.R2Q, "L", "H")
    out["e3_r2q"], out["e3_r2q_low"], out["e3_r2q_high"] = (pts(float(r2q["mean"])), pts(float(r2q["boot_low"])),
                                                            pts(float(r2q["boot_high"])))
    out["e3_r2q_p"] = p(r2q["p_sign_flip"])
    out["e3_hf"] = pts(float(diff(faithful, "E3", tables.Q2R, "H-F", "L")["mean"]))
    out["e3_hv"] = pts(float(diff(faithful, "E3", tables.Q2R, "H-V", "L")["mean"]))
    # the rank's uncertainty
    ranks = tables.rank_replicates({key: tables._point_values(key) for key in tables.POINTS})
    single, every = tables.RANK_GROUPS["single samples"], tables.RANK_GROUPS["all"]
    mean_single, best_single = tables.mean_ranks(ranks, single)
    _, best_all = tables.mean_ranks(ranks, every)
    assert (ranks[touch]["H-F"] >= 1).all() and len(ranks[touch]["H-F"]) == 2000
    rank = {k: {m: i + 1 for i, m in enumerate(sorted(a, key=lambda m: -a[m]))}
            for k, a in ((k, tables._averages(k)) for k in tables.POINTS)}
    out["hf_rank"] = f"{statistics.fmean(rank[k]['H-F'] for k in single):.1f}"
    out["hf_rank_interval"] = tables._interval(mean_single["H-F"], 1)
    for m in ("H-F", "H-V", "L-F"):
        out[f"best_{m}"] = f"{100 * best_single[m]:.1f}"
        out[f"best_all_{m}"] = f"{100 * best_all[m]:.1f}"
    # the weight chosen on the drop-out arm's second draw of alike-shapes against the primary cell's
    weights = [tables._per_seed(key, "fusion.weight")[("alike-shapes", "L-F", tables.Q2R)] for key in (touch, dropout)]
    out["weights_equal"] = str(sum(weights[0][s] == weights[1][s] for s in range(8)))
    # the drop-out condition's touch is the touch arm's alike-shapes touch, seed by seed
    for method in ("L-T", "H-T"):
        for direction in tables.DIRECTIONS:
            assert (tables._per_seed(dropout)[("distinct-shapes-dropout", method, direction)]
                    == tables._per_seed(touch)[("alike-shapes", method, direction)])
    # the tactile range: the farthest "up to X scaled units beyond" of every arm's range warnings (read here)
    excess: dict[str, float] = {}
    for path in RESULTS.glob("study2-*sweep/length=1/seeds/seed-*/manifest.json"):
        for checks in json.loads(path.read_text())["warnings"].values():
            for check, message in checks.items():
                found = re.search(r"tactile range \((instant|cycle).*up to ([0-9.]+) scaled", check + message)
                if found:
                    excess[found[1]] = max(excess.get(found[1], 0.0), float(found[2]))
    assert excess == {"instant": tables.tactile_range_excess("instant"), "cycle": tables.tactile_range_excess("cycle")}
    out["range_instant"], out["range_cycle"] = f"{excess['instant']:g}", f"{excess['cycle']:g}"
    # what changed between the studies' L on E3, from the manifests
    first = json.loads((RESULTS / "paper-cpu-sweep" / "seeds" / "seed-0" / "manifest.json").read_text())["methods"]["L"]
    second = tables._seed_manifests("faithful")[0]["methods"]["L"]
    assert "latent_prior" not in first["params"] and "latent_prior" not in first["defaults"]
    out["steps_second"], out["steps_first"] = str(second["params"]["max_steps"]), str(first["params"]["max_steps"])
    out["prior"] = f"{second['params']['latent_prior']:g}"
    out["epochs_second"], out["epochs_first"] = str(second["params"]["epochs"]), str(first["params"]["epochs"])
    words = {6: "six", 8: "eight"}
    out["seeds_second"] = words[len(tables._seed_manifests("faithful"))]
    out["seeds_first"] = words[len({r["seed"] for r in rows("paper-cpu-sweep", "sweep-seeds.csv")})]
    # A against L: the optimiser and its rate; MuPNet's touch step over its vision step
    a, l_ = tables._seed_manifests("touch")[0]["methods"]["A"], tables._seed_manifests("touch")[0]["methods"]["L"]
    assert a["defaults"]["optimizer"] == "adam" and a["defaults"]["encoder"] == "learned"
    # A has no latent prior; MuPNet's weights took plain steps (the study predates `weight_optimizer`)
    assert "latent_prior" not in a["params"] and "weight_optimizer" not in {**l_["params"], **l_["defaults"]}
    out["a_rate"] = f"{a['defaults']['learning_rate']:g}"
    ratios = {l_["defaults"][f"eta_{k}_tactile"] / l_["defaults"][f"eta_{k}_visual"] for k in ("y", "w")}
    assert len(ratios) == 1
    out["touch_step"] = f"{ratios.pop():.0f}"
    # seed 0's L-V, alike-shapes, query to reference: the study against the budget trend's rerun at its cap
    rerun, _ = tables._budget_values(70)
    out["machine"] = pts(abs(tables._per_seed(touch)[("alike-shapes", "L-V", tables.Q2R)][0]
                             - rerun[("alike-shapes", "L-V", tables.Q2R)]))
    return out


#: (file, a sentence of the second study's text with its numbers as {names} of `second_study_numbers`)
SECOND_STUDY_QUOTES = (
    ("README.md", "H-V's max F1 above 85 % in {gate_failed_q2r} of 8 seeds query to reference, {gate_failed_r2q} of 8 "
                  "the other way"),
    ("README.md", "a fusion could add at most +{room_l} points of recall@1 to L's codes there and +{room_h} to H's"),
    ("README.md", "the joint code is **{primary_abs} points of max F1 below**"),
    ("README.md", "(bootstrap 95 % [{primary_low}, {primary_high}], p = {primary_p}); against vision alone "
                  "(L − L-V {l_lv} points [{l_lv_low}, {l_lv_high}], p = {l_lv_p}) a loss is not shown"),
    ("README.md", "where a fusion could add {room_min}–{room_max} points, the hand-crafted H beats L ({l_h_dusk_q2r}, "
                  "{l_h_dusk_r2q} and {l_h_dropout} points, unadjusted)"),
    ("README.md", "On the faithful E3 L beats H query to reference only (+{e3}, Holm-corrected; reference to query "
                  "+{e3_r2q}, p = {e3_r2q_p}), and there H-F and H-V beat L by {e3_hf} and {e3_hv} points"),
    ("README.md", "the best mean rank over the three arms ({hf_rank}, 95 % {hf_rank_interval} over resamples of the "
                  "seeds; the lowest in {best_H-F} % of them)"),
    ("docs/RESULTS.md", "there E3's L − H is +{e3} points [{e3_low}, {e3_high}] query to reference, Holm-corrected, "
                        "and +{e3_r2q} (p = {e3_r2q_p}) reference to query"),
    ("docs/RESULTS.md", "on this cell L-F − L-V = +{lf_lv} points, about half of the primary's {primary}, and on the "
                        "drop-out arm's second draw of `alike-shapes` the weight chosen there is this cell's in only "
                        "{weights_equal} of 8 seeds"),
    ("docs/RESULTS.md", "L-F − L-V = +{lf_lv} points of the {primary} is that fusion's gain over vision alone. Against "
                        "vision alone L − L-V = {l_lv} points [{l_lv_low}, {l_lv_high}], p = {l_lv_p}: a loss is not "
                        "shown. The cell failed its aliasing gate (H-V above 85 % in {gate_failed_q2r} of 8 seeds "
                        "query to reference, {gate_failed_r2q} of 8 the other way), and a fusion could add at most "
                        "+{room_l} points of recall@1 to L's codes there (+{room_h} to H's)"),
    ("docs/RESULTS.md", "**L now beats H query to reference** (+{e3} [{e3_low}, {e3_high}], Holm p = {e3_holm}; not "
                        "within ±5 points), not the other way (+{e3_r2q} [{e3_r2q_low}, {e3_r2q_high}], "
                        "p = {e3_r2q_p}), and there H-F and H-V beat L by {e3_hf} and {e3_hv} points"),
    ("docs/RESULTS.md", "(mean rank {hf_rank} {hf_rank_interval} over the three arms' single samples, the lowest in "
                        "{best_H-F} % of 2000 resamples of the seeds; H-V in {best_H-V} %, L-F in {best_L-F} %"),
    ("docs/RESULTS.md", "could add at most +{room_l} points of recall@1 to L's pair there and +{room_h} to H's"),
    ("docs/RESULTS.md", "At dusk and under drop-out a fusion could add {room_min}–{room_max} points."),
    ("docs/RESULTS.md", "H-F has the lowest mean rank over the single samples in {best_H-F} % of the resamples, H-V in "
                        "{best_H-V} % and L-F in {best_L-F} %; over all five points H-F and L-F share it "
                        "({best_all_H-F} % and {best_all_L-F} %)"),
    ("docs/RESULTS.md", "its optimiser (Adam at a learning rate of {a_rate}, against MuPNet's plain steps), its step "
                        "sizes (one for every layer, where MuPNet's touch layers step {touch_step}× its vision "
                        "layers')"),
    ("docs/RESULTS.md", "(warnings below: up to {range_cycle} scaled units beyond [0, 1])"),
    ("docs/RESULTS.md", "Reference to query L − H is +{e3_r2q} (p = {e3_r2q_p}): the change is shown in one "
                        "direction."),
    ("docs/RESULTS.md", "the test-time solver (settling, at most {steps_second} steps, against plain steps to "
                        "{steps_first}), the latent prior ({prior}, which also enters training, against none), the "
                        "epochs ({epochs_second} against {epochs_first}) and the seeds ({seeds_second} against "
                        "{seeds_first}) all changed"),
    ("docs/RESULTS.md", "by up to {range_instant} scaled units for the single instant and {range_cycle} for the whisk "
                        "cycle's eight points"),
    ("docs/RESULTS.md", "({primary} points, the pre-registered primary endpoint; +{lf_lv} of it is that fusion's "
                        "in-sample gain over vision alone)"),
    ("docs/RESULTS.md", "Against vision alone a loss is not shown ({l_lv}, p = {l_lv_p}). That cell failed its "
                        "aliasing gate (H-V 87.6 %) and left a fusion at most +{room_l} points of recall@1"),
    ("docs/RESULTS.md", "L beats the hand-crafted H (+{e3} points, Holm-corrected; reference to query +{e3_r2q}, "
                        "p = {e3_r2q_p})"),
    ("docs/RESULTS.md", "H-V and H-F beat L by {e3_hv} and {e3_hf} points"),
    ("docs/RESULTS.md", "(dusk and drop-out, {room_min}–{room_max} points) the hand-crafted H beats L ({l_h_dusk_q2r}, "
                        "{l_h_dusk_r2q} and {l_h_dropout} points, unadjusted)"),
    ("docs/RESULTS.md", "H-F has the best mean rank, in {best_H-F} % of the seed resamples"),
    ("docs/RESULTS.md", "That the joint code loses to vision alone: {l_lv} points, p = {l_lv_p}."),
    ("docs/RESULTS.md", "(a fusion's headroom +{room_l} points of recall@1)"),
    ("docs/RESULTS.md", "moved {machine} points in one cell (the budget trend)"),
)


def test_the_second_studys_corrected_sentences_quote_the_committed_numbers():
    """Each corrected sentence of the README's and RESULTS.md's second study, with its numbers
    recomputed from the committed files, stands in the text (line breaks and quote marks
    aside): a number that does not match the files fails."""
    numbers = second_study_numbers()
    texts = {name: " ".join(re.sub(r"^> ?", "", (ROOT / name).read_text(), flags=re.M).split())
             for name, _ in SECOND_STUDY_QUOTES}
    missing = []
    for name, quote in SECOND_STUDY_QUOTES:
        sentence = re.sub(r"\{([\w-]+)\}", lambda m: numbers[m[1]], quote)
        if sentence not in texts[name]:
            missing.append(f"{name}: {sentence}")
    assert not missing, "\n".join(missing)


#: the third study's summaries -> the seeds its registration (as changed) runs
THIRD_SEEDS = {"station/single": range(20, 30), "station/seq. 2.8 m": range(20, 30),
               "faithful/single": range(20, 30), "drop-out/single": range(1000, 1010),
               "survival/epochs=70": range(8), "survival/epochs=3000": range(8)}


@pytest.mark.parametrize("key", THIRD_SEEDS)
def test_the_third_study_holds_every_method_and_condition_at_its_seeds_with_bounded_intervals(key):
    """Every arm: each method and fusion it keeps, in each of its conditions, at every one of
    its registered seeds (ten per arm; the survival comparison the second study's eight)."""
    tables = tables_module()
    arm = key.split("/")[0]
    if arm == "survival":
        folder, worlds, methods = tables.SURVIVAL_POINTS[key], tables.ARMS["touch"][2], ("L", "L-V")
    else:
        folder, (_, worlds, methods) = tables.POINTS3[key], tables.ARMS3[arm]
    per_cell: dict[tuple[str, str], set[str]] = {}
    for row in rows(folder.relative_to(RESULTS), "sweep-seeds.csv"):
        if row["metric"] == "max_f1":
            per_cell.setdefault((row["environment"], row["method"]), set()).add(row["seed"])
    assert set(per_cell) == {(w, m) for w in worlds for m in methods}
    registered = {str(i) for i in THIRD_SEEDS[key]}
    assert all(s == registered for s in per_cell.values()), {k: len(v) for k, v in per_cell.items()}
    assert_bounded_intervals(folder.relative_to(RESULTS), required=("t", "boot"), optional=("block",))


# The third study's calibration (RESULTS.md, "Third study: calibration").


def test_a_condition_has_headroom_only_where_all_four_gates_hold_together():
    """Seeds count when every gate is met in the same seed: here each gate alone is met in 7
    of 8 seeds, but in different seeds, so all four hold together in only 4."""
    tables = tables_module()
    seeds = []
    for k in range(8):
        gates = {g: {"gate": 0.5, "value": 1.0, "met": True} for g in tables.GATES3}
        if k < 4:  # seeds 0-3 each miss one gate
            gates[tables.GATES3[k]]["met"] = False
        seeds.append({"gates": gates})
    assert tables.all_gates_met(seeds) == 4
    assert tables.all_gates_met(seeds[4:]) == 4 and tables.HEADROOM_SEEDS == 7


def test_the_calibration_seeds_are_the_registered_ones_and_none_is_scored():
    """Every round of the gate calibration ran the registered calibration seeds, with each
    condition of the arm's scenario (the station arm's second, the vision-aliased one, as that
    round designed it) and the registered gates."""
    import yaml

    tables = tables_module()
    gates = {"touch_correspondence_min": 0.7, "rescue_min": 0.25, "hv_max_f1_max": 0.85, "headroom_min": 0.10}
    for arm in tables.CALIBRATION3:
        scenario = "study3-dropout" if arm == "drop-out" else "study3"
        evaluations = yaml.safe_load((ROOT / "scenarios" / f"{scenario}.yaml").read_text())["evaluations"]
        declared = [e["name"] for e in evaluations]
        per_seed = tables.calibration3(arm)
        assert sorted(per_seed) == list(range(1100, 1108) if arm == "drop-out" else range(100, 108)), arm
        for seed_rows in per_seed.values():
            names = [r["environment"] for r in seed_rows[::2]]
            assert [r["direction"] for r in seed_rows] == ["query-to-reference", "reference-to-query"] * len(names)
            if arm == "drop-out":
                assert names == declared
            else:
                assert names[:1] + names[2:] == declared[:1] + declared[2:]
            assert all({g: v["gate"] for g, v in r["gates"].items()} == gates for r in seed_rows)


def test_a_fusion_weight_is_the_best_grid_weight_averaged_over_directions_ties_to_the_smaller(tmp_path):
    """By hand: L-F's directions average 0.6 at w 0.1 and at w 1 (a tie, to 0.1), H-F is best at 3."""
    tables = tables_module()
    q2r, r2q = tables.Q2R, tables.R2Q
    by_hand = {("L-F", "0.1"): (0.5, 0.7), ("L-F", "1"): (0.7, 0.5), ("L-F", "0.3"): (0.9, 0.2),
               ("H-F", "3"): (0.4, 0.45)}
    lines = ["environment,method,direction,metric,mean"]
    for fusion in tables.FUSIONS3:
        for w in tables.GRID3:
            forward, backward = by_hand.get((fusion, w), (0.1, 0.1))
            lines += [f"{tables.PRIMARY3},{fusion}-{w},{q2r},max_f1,{forward}",
                      f"{tables.PRIMARY3},{fusion}-{w},{r2q},max_f1,{backward}",
                      f"{tables.PRIMARY3},{fusion}-{w},{q2r},auc,0.99",
                      f"alike-shapes,{fusion}-{w},{q2r},max_f1,0.99", f"alike-shapes,{fusion}-{w},{r2q},max_f1,0.99"]
    (tmp_path / "sweep.csv").write_text("\n".join(lines) + "\n")
    scores = tables.fusion_weights3(tmp_path / "sweep.csv")
    assert scores["L-F"]["0.3"] == pytest.approx(0.55) and scores["H-F"]["3"] == pytest.approx(0.425)
    assert tables.chosen_weights3(scores) == {"L-F": 0.1, "H-F": 3.0, "HOG-F": 0.0, "VLAD-F": 0.0}


def _seed_csv(folder: Path, values: dict[tuple[str, str, str], list[float]]) -> None:
    """A hand-built ``sweep-seeds.csv``: max F1 per (evaluation, method, direction), seeds 0.."""
    lines = ["seed,environment,method,direction,metric,value"]
    lines += [f"{seed},{world},{method},{direction},max_f1,{v}"
              for (world, method, direction), per_seed in values.items() for seed, v in enumerate(per_seed)]
    folder.mkdir(parents=True)
    (folder / "sweep-seeds.csv").write_text("\n".join(lines) + "\n")


def test_secondary_4_pairs_the_best_touch_using_and_vision_only_methods_by_their_means(tmp_path, monkeypatch):
    """By hand: H-F has the highest touch-using mean (0.7 against L's 0.6), HOG the highest
    vision-only one (0.5 against L-V's 0.45); the per-seed differences are H-F − HOG."""
    tables = tables_module()
    cell = ("c", tables.Q2R)
    _seed_csv(tmp_path / "hand", {(cell[0], "L", cell[1]): [0.9, 0.3], (cell[0], "H-F", cell[1]): [0.6, 0.8],
                                  (cell[0], "L-V", cell[1]): [0.9, 0.0], (cell[0], "HOG", cell[1]): [0.4, 0.6]})
    monkeypatch.setitem(tables.SUMMARIES, "hand/single", tmp_path / "hand")
    name, values = tables.endpoint_values("hand/single", *cell, ("L", "H-F"), ("L-V", "HOG"))
    assert name == "H-F − HOG" and values == pytest.approx({0: 0.2, 1: 0.2})
    name, values = tables.endpoint_values("hand/single", *cell, "L", ("L-V", "HOG"))  # per-seed best comparator
    assert name == "L − max(L-V, HOG)" and values == pytest.approx({0: 0.0, 1: -0.3})


@pytest.mark.parametrize(("before", "after", "held"), [
    ((-0.10, -0.15, -0.05), (-0.02, -0.08, 0.04), True),    # same sign, reaches +4 points: held
    ((-0.10, -0.15, -0.05), (-0.01, -0.07, 0.05), False),   # reaches +5 points the other way
    ((-0.10, -0.15, -0.05), (0.01, -0.03, 0.04), False),    # the sign turned
    ((0.06, 0.01, 0.11), (0.02, -0.049, 0.09), True),       # positive, reaches -4.9 points
])
def test_the_second_study_s_answer_held_by_the_registered_reading(tmp_path, monkeypatch, before, after, held):
    tables = tables_module()
    for key, (mean, low, high) in zip(tables.SURVIVAL_POINTS, (before, after), strict=True):
        folder = tmp_path / key.replace("/", "-")
        folder.mkdir()
        (folder / "sweep-diff.csv").write_text(
            "environment,direction,metric,method_a,method_b,mean,boot_low,boot_high\n"
            f"alike-shapes,{tables.Q2R},max_f1,L,L-V,{mean},{low},{high}\n")
        monkeypatch.setitem(tables.SUMMARIES, key, folder)
    assert tables.survival_held() is held


def test_every_arm_fuses_at_the_weight_its_calibration_fixed():
    """The scenarios' fusion weights are the calibration's choice from its committed summary,
    and that summary is the mean of the calibration seeds' own results."""
    import yaml

    tables = tables_module()
    chosen = tables.chosen_weights3(tables.fusion_weights3())
    for name in ("study3", "study3-faithful", "study3-dropout"):
        fusions = yaml.safe_load((ROOT / "scenarios" / f"{name}.yaml").read_text())["fusions"]
        assert fusions and all(f["weights"] == [chosen[f["name"]]] for f in fusions), name
    summary = {(r["environment"], r["method"], r["direction"], r["metric"]): r
               for r in rows("study3-weights", "sweep.csv")}
    seeds = sorted((RESULTS / "study3-weights" / "seeds").glob("seed-*/results.json"))
    assert len(seeds) == 8
    per_seed = [{(r["environment"], r["method"], r["direction"]): r["max_f1"] for r in json.loads(f.read_text())}
                for f in seeds]
    for (world, method, direction, metric), row in summary.items():
        if metric == "max_f1" and world == tables.PRIMARY3:
            expected = sum(s[(world, method, direction)] for s in per_seed) / 8
            assert float(row["mean"]) == pytest.approx(expected, rel=1e-12), (method, direction)


def manifests(folder: Path, key: str) -> dict[str, object]:
    """``{seed folder: its manifest's key}`` of a sweep's committed seeds."""
    return {path.parent.name: json.loads(path.read_text())[key]
            for path in (folder / "seeds").glob("seed-*/manifest.json")}


def test_the_survival_comparison_s_halves_scored_the_same_simulated_runs():
    """Each half simulated its runs itself (docs/RESULTS.md, "Third study: results"): the two
    halves the comparison reads, on one machine, record the same settings and the same samples
    and contacts per run; the first machine's half, the same settings and other contacts."""
    tables = tables_module()
    (first,) = tables.FIRST_MACHINE3.values()
    halves = [*tables.SURVIVAL_POINTS.values(), first]
    settings = [manifests(folder, "datasets") for folder in halves]
    assert all(sorted(half) == sorted(f"seed-{s}" for s in range(8)) for half in settings)
    assert settings[0] == settings[1] == settings[2]
    runs = [manifests(folder, "runs") for folder in halves]
    assert runs[0] == runs[1]
    assert all(runs[0][seed] != runs[2][seed] for seed in runs[0])
    assert (runs[0]["seed-4"]["train"]["whisker_contacts"], runs[2]["seed-4"]["train"]["whisker_contacts"]) \
        == (22992, 14393)


def test_the_survival_sentence_is_the_registered_rule_s_reading():
    tables = tables_module()
    text = " ".join((ROOT / "docs" / "RESULTS.md").read_text().split())
    held = tables.survival_held()
    assert ("**the second study's answer held**" in text) is held
    assert ("**the second study's answer did not hold**" in text) is not held



def test_the_kernel_rerun_ran_seed_20_under_haswell_on_another_machine():
    """The registered kernel rerun (docs/RESULTS.md, "Numerical noise"): one row, OpenBLAS
    reporting the Haswell kernel, seed 20 with the station arm's settings; its simulation is
    another machine's (other contacts than the arm's seed 20), so it moves what a change of
    machine moves; every cell it scored is one of the arm's."""
    tables = tables_module()
    (row,) = json.loads(tables.KERNEL3.read_text())
    assert row["kernel"] == "Haswell" and row["architecture"] == "Haswell"
    rerun = json.loads((tables.KERNEL3.parent / "manifest.json").read_text())
    station = json.loads((tables.ARMS3["station"][0]["single"] / "seeds" / f"seed-{tables.KERNEL_SEED}"
                          / "manifest.json").read_text())
    assert rerun["seed"] == station["seed"] == tables.KERNEL_SEED
    assert rerun["datasets"] == station["datasets"]
    assert (rerun["runs"]["train"]["whisker_contacts"], station["runs"]["train"]["whisker_contacts"]) == (26545, 23338)
    assert {lib["architecture"] for lib in rerun["machine"]["blas"]} == {"Haswell"}
    per_seed = tables._per_seed("station/single")
    assert all(tuple(key.split("/")) in per_seed for key in row["max_f1"])


def test_the_kernel_alone_changed_nothing_but_the_kernel():
    """The exploratory same-machine pair: Haswell then Sandybridge, each as OpenBLAS reported it,
    the second fitted on the first's simulated runs (the same runs in both manifests)."""
    tables = tables_module()
    rows = json.loads(tables.KERNEL3_ALONE.read_text())
    assert [(r["kernel"], r["architecture"]) for r in rows] == [("Haswell", "Haswell"), ("Sandybridge", "Sandybridge")]
    assert rows[0]["max_f1"] == json.loads(tables.KERNEL3.read_text())[0]["max_f1"]
    second = json.loads((tables.KERNEL3_ALONE.parent / "manifest.json").read_text())
    first = json.loads((tables.KERNEL3.parent / "manifest.json").read_text())
    assert second["runs"] == first["runs"] and second["datasets"] == first["datasets"]
    assert {lib["architecture"] for lib in second["machine"]["blas"]} == {"Sandybridge"}


def test_the_sequence_rerun_scored_the_station_arms_simulated_runs_and_networks():
    """The sequence point of docs/RESULTS.md (the third study's correction) comes from a rerun
    of the registered station sweep: every seed records the single-sample point's settings,
    simulated runs and training histories (every epoch of every learned method), so its
    sequences score the same runs and networks as the single rows."""
    tables = tables_module()
    folders = tables.ARMS3["station"][0]
    for key in ("datasets", "runs", "training"):
        single, sequences = (manifests(folders[m], key) for m in ("single", "seq. 2.8 m"))
        assert sorted(single) == [f"seed-{s}" for s in range(20, 30)] and sequences == single, key
    assert manifests(tables.SEQUENCE_RERUN3, "runs") == manifests(folders["single"], "runs")


def test_the_reruns_single_point_reproduced_the_committed_one_but_vlad():
    """Its single-sample point repeats every per-seed number of the committed one for 12 of the
    14 methods and fusions; VLAD and VLAD-F differ, their max F1 in seeds 21 and 27 only."""
    tables = tables_module()

    def per_seed(folder: Path) -> dict[tuple[str, ...], str]:
        return {(r["seed"], r["environment"], r["method"], r["direction"], r["metric"]): r["value"]
                for r in tables.read_csv(folder / "sweep-seeds.csv")}

    committed, rerun = per_seed(tables.ARMS3["station"][0]["single"]), per_seed(tables.SEQUENCE_RERUN3)
    assert committed.keys() == rerun.keys()
    differing = {k for k in committed if committed[k] != rerun[k]}
    assert {k[2] for k in differing} == {"VLAD", "VLAD-F"}
    assert {int(k[0]) for k in differing if k[4] == "max_f1"} == {21, 27}


def test_secondary_7_is_quoted_as_its_summaries_give_it():
    tables = tables_module()
    (seventh,) = (e for e in tables.endpoints(tables.ENDPOINTS3) if e["label"] == "7")
    s = seventh["stats"]
    signed = lambda v: ("+" if v > 0 else "") + _percent_points(v)  # noqa: E731
    assert seventh["tost"][0] < -0.05  # as the quote says: its interval crosses -5 points
    quote = (f"secondary 7: {_percent_points(s['mean'])} points [{signed(s['boot_low'])}, {signed(s['boot_high'])}], "
             f"p {tables.p_value(seventh['p'])}, Holm p {tables.p_value(seventh['p_holm'])}; the TOST's interval "
             f"[{signed(seventh['tost'][0])}, {signed(seventh['tost'][1])}] crosses −5")
    text = " ".join((ROOT / "docs" / "RESULTS.md").read_text().split())
    assert quote in text

