"""Parameter grids (`vitaplace sweep --grid`) on the process pool, Ray and SLURM's local
executor, `vitaplace config`, and the refusal of a sweep into a folder whose summary covers
seeds or grid points the sweep lacks. Expectations come from elsewhere: a grid point's
seed folder holds what `vitaplace config --set` resolves for the same assignments, a point's
rows in the grid table are what `vitaplace aggregate` writes for that point's seed folders,
and the statistics are recomputed here from the seeds' own results.json."""

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats
from test_sweep import LIST_TASKS, own_ray, plugin_env, read_csv, tiny_scenario, vitaplace  # noqa: F401 - fixtures

import vitaplace as api
from vitaplace.engine.cli.main import main
from vitaplace.engine.config.scenario import Scenario, ScenarioError
from vitaplace.engine.study import grid

AXES = ["--grid", "scoring.tau=0.3,0.5", "--grid", "methods.1.params.crop_fraction=0.5,1.0"]
#: the product of AXES, the first varying slowest: (folder, tau, crop_fraction)
POINTS = [("tau=0.3,crop_fraction=0.5", 0.3, 0.5), ("tau=0.3,crop_fraction=1.0", 0.3, 1.0),
          ("tau=0.5,crop_fraction=0.5", 0.5, 0.5), ("tau=0.5,crop_fraction=1.0", 0.5, 1.0)]
NAMES = [name for name, _, _ in POINTS]


def _scenario_file(folder: Path, fail_seed: int = -1, test_plugin: bool = True) -> Path:
    """The tiny scenario; without ``test_plugin``, its hand-crafted method alone (for this process)."""
    scenario = tiny_scenario(fail_seed)
    scenario["methods"] = scenario["methods"][0 if test_plugin else 1:]
    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path


@pytest.fixture(scope="module")
def grid_sweep(tmp_path_factory, plugin_env):  # noqa: F811
    """A 2 x 2 grid over seeds 0 and 1 on two local processes."""
    tmp = tmp_path_factory.mktemp("grid")
    path, out = _scenario_file(tmp), tmp / "out"
    args = ["sweep", str(path), *AXES, "--seeds", "0", "1", "--workers", "2", "--out", str(out), "--no-progress"]
    return path, out, vitaplace(args, plugin_env)


def _without_environment_paths(resolved: dict) -> dict:
    """``resolved`` without the environment paths (a seed folder's name its own copies)."""
    resolved = json.loads(json.dumps(resolved))
    for entry in [resolved["train"], *resolved["evaluations"]]:
        entry.pop("environment", None)
    return resolved


#: `vitaplace config` for each argument list in argv[1] (JSON), the outputs between MARK lines
CONFIGS = """
import json, sys
from vitaplace.engine.cli.main import main
for args in json.loads(sys.argv[1]):
    print("=====", flush=True)
    assert main(["config", *args]) == 0
    sys.stdout.flush()
"""


def test_every_point_and_seed_runs_what_config_resolves_for_its_assignments(grid_sweep, plugin_env):  # noqa: F811
    path, out, result = grid_sweep
    assert result.returncode == 0, result.stderr[-3000:]
    assert sorted(p.name for p in out.iterdir() if "=" in p.name) == sorted(NAMES)  # 2 x 2 points, no more
    # a sweep's seeds draw the summary figures unless the scenario chooses (docs/SCALE.md)
    runs = [(name, seed, [str(path), "--set", f"seed={seed}", "--set", f"scoring.tau={tau}",
                          "--set", f"methods.1.params.crop_fraction={crop}", "--set", "report.figures=summary"])
            for name, tau, crop in POINTS for seed in (0, 1)]
    configs = subprocess.run([sys.executable, "-c", CONFIGS, json.dumps([args for _, _, args in runs])],
                             capture_output=True, text=True, timeout=300, env=plugin_env, check=True).stdout
    for (name, seed, _), printed in zip(runs, configs.split("=====\n")[1:], strict=True):
        ran = yaml.safe_load((out / name / f"seed-{seed}" / "scenario.resolved.yaml").read_text())
        assert _without_environment_paths(ran) == _without_environment_paths(yaml.safe_load(printed))
    for name in NAMES:
        assert json.loads((out / name / "sweep.json").read_text())["seeds"] == [0, 1]
    record = json.loads((out / "grid.json").read_text())
    assert [p["name"] for p in record["points"]] == NAMES
    assert record["grid"] == {"scoring.tau": [0.3, 0.5], "methods.1.params.crop_fraction": [0.5, 1.0]}
    assert "summary of 8 runs (4 points x 2 seeds) in" in result.stderr and str(out / "grid.md") in result.stderr


def test_a_point_s_rows_in_the_grid_table_are_what_aggregate_writes_for_its_seeds(grid_sweep, tmp_path):
    _, out, _ = grid_sweep
    rows = read_csv(out / "grid.csv")
    assert [r["point"] for r in rows][:: len(rows) // 4] == NAMES  # point by point, in the product's order
    for name, tau, crop in POINTS:
        folder = tmp_path / name
        assert main(["aggregate", str(out / name / "seed-0"), str(out / name / "seed-1"), "--out", str(folder)]) == 0
        aggregated = read_csv(folder / "sweep.csv")
        mine = [{k: v for k, v in r.items() if k not in ("point", "scoring.tau", "methods.1.params.crop_fraction")}
                for r in rows if r["point"] == name]
        assert mine == aggregated
        assert {(r["scoring.tau"], r["methods.1.params.crop_fraction"]) for r in rows if r["point"] == name} == {
            (str(tau), str(crop))}


def test_the_grid_table_is_each_point_s_mean_and_t_interval_over_its_seeds(grid_sweep):
    _, out, _ = grid_sweep
    rows = read_csv(out / "grid.csv")
    table = (out / "grid.md").read_text()
    for name, _, _ in POINTS:
        for method in ("O", "H"):
            values = [r["max_f1"] for seed in (0, 1)
                      for r in json.loads((out / name / f"seed-{seed}" / "results.json").read_text())
                      if r["method"] == method and r["direction"] == "query-to-reference"]
            (row,) = [r for r in rows if (r["point"], r["method"], r["metric"], r["direction"])
                      == (name, method, "max_f1", "query-to-reference")]
            mean, std = sum(values) / 2, abs(values[0] - values[1]) / math.sqrt(2)
            half = stats.t.ppf(0.975, 1) * std / math.sqrt(2)
            assert row["n"] == "2" and float(row["mean"]) == pytest.approx(mean)
            assert float(row["t_low"]) == pytest.approx(max(0.0, mean - half))
            assert float(row["t_high"]) == pytest.approx(min(1.0, mean + half))
            assert f"| {name} | E1 | {method} | query-to-reference | max_f1 | 2 | {mean:.3f} ± {std:.3f} |" in table


def test_a_sweep_that_would_drop_seeds_or_points_of_the_summary_is_refused_in_one_line(grid_sweep, plugin_env):  # noqa: F811
    path, out, _ = grid_sweep
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.suffix in (".json", ".csv", ".md")}
    cases = [(["--seeds", "0", "1"], "no grid, seeds 0 1"),  # a plain sweep where a grid is
             ([*AXES, "--seeds", "0"], "grid points " + " ".join(NAMES) + ", seeds 0"),  # a seed fewer
             (["--grid", "scoring.tau=0.3", *AXES[2:], "--seeds", "0", "1"], None)]  # two points fewer
    for args, this in cases:
        refused = vitaplace(["sweep", str(path), *args, "--out", str(out), "--no-progress"], plugin_env)
        err = refused.stderr.strip().splitlines()
        assert refused.returncode == 2 and len(err) == 1 and err[0].startswith(
            f"vitaplace: error: --out {out}: its summary (grid.json) covers "
            f"grid points {' '.join(NAMES)}, seeds 0 1"), err
        assert "give --replace to replace it" in err[0] and (this is None or f"sweep of {this} would" in err[0])
    assert not (out / "seed-0").exists() and not (out / "sweep.json").exists()
    assert {p: p.read_bytes() for p in before} == before  # nothing lost, nothing rewritten


def test_more_seeds_extend_a_summary_and_replace_swaps_it_for_another(tmp_path, plugin_env):  # noqa: F811
    path, out = _scenario_file(tmp_path), tmp_path / "out"
    common = ["sweep", str(path), "--workers", "1", "--out", str(out), "--no-progress"]
    assert vitaplace([*common, "--seeds", "0"], plugin_env).returncode == 0
    more = vitaplace([*common, "--seeds", "0", "1"], plugin_env)  # seed 0 resumes from its cache, seed 1 is new
    assert more.returncode == 0, more.stderr[-2000:]
    assert json.loads((out / "sweep.json").read_text())["seeds"] == [0, 1]
    refused = vitaplace([*common, "--seeds", "1"], plugin_env)
    assert refused.returncode == 2
    assert "covers no grid, seeds 0 1, which this sweep of no grid, seeds 1" in refused.stderr
    assert json.loads((out / "sweep.json").read_text())["seeds"] == [0, 1]
    replaced = vitaplace([*common, "--seeds", "1", "--replace"], plugin_env)
    assert replaced.returncode == 0, replaced.stderr[-2000:]
    assert json.loads((out / "sweep.json").read_text())["seeds"] == [1]
    to_grid = vitaplace([*common, "--seeds", "1", "--grid", "scoring.tau=0.3,0.5", "--replace"], plugin_env)
    assert to_grid.returncode == 0, to_grid.stderr[-2000:]
    assert not (out / "sweep.json").exists() and not list(out.glob("pr-bands-*"))
    assert [p["name"] for p in json.loads((out / "grid.json").read_text())["points"]] == ["tau=0.3", "tau=0.5"]


def test_an_unreadable_summary_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "sweep.json").write_text("{not json")
    (tmp_path / ".vitaplace.lock").write_text("")  # a sweep's folder
    assert main(["sweep", "quickstart", "--seeds", "0", "--out", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "its summary sweep.json cannot be read" in err[0] and "--replace" in err[0], err


def test_a_grid_is_the_product_of_its_axes_named_by_path_ends():
    axes = grid.parse_axes(["a.x=1,2,3", "b.y=[1, 2],{k: v}", "c=true,off"])
    assert [(a.path, a.values) for a in axes] == [("a.x", (1, 2, 3)), ("b.y", ([1, 2], {"k": "v"})),
                                                  ("c", (True, False))]
    points = grid.grid_points(axes)
    assert len(points) == 3 * 2 * 2 and len({p.name for p in points}) == 12
    assert [p.name for p in points[:4]] == ["x=1,y=_1__2_,c=true", "x=1,y=_1__2_,c=off", "x=1,y=_k__v_,c=true",
                                            "x=1,y=_k__v_,c=off"]
    assert points[2].assignments == ("a.x=1", "b.y={k: v}", "c=true")
    assert points[2].values == {"a.x": 1, "b.y": {"k": "v"}, "c": True}
    shared = grid.grid_points(grid.parse_axes(["methods.0.params.epochs=1", "methods.1.params.epochs=2,3"]))
    assert [p.name for p in shared] == ["methods.0.params.epochs=1,methods.1.params.epochs=2",
                                        "methods.0.params.epochs=1,methods.1.params.epochs=3"]
    assert grid.grid_points([]) == [grid.GridPoint("")]
    assert grid.split_values(" 'a,b' , \"c\" ,d,[1, 2]") == ["'a,b'", '"c"', "d", "[1, 2]"]
    assert grid.parse_axes(["evaluation.tau=0.3"])[0].path == "scoring.tau"  # the old name, as --set reads it


@pytest.mark.parametrize("options, overrides, message", [
    (["scoring.tau"], [], "expected KEY.PATH=VALUE1,VALUE2"),
    (["methods+=1,2"], [], "expected KEY.PATH=VALUE1,VALUE2"),
    (["scoring.tau="], [], "an empty value"),
    (["scoring.tau=0.3,,0.5"], [], "an empty value"),
    (["scoring.tau=[1,2"], [], "a value is not YAML"),
    (["scoring.tau=0.3,0.30,0.5"], [], "the value 0.3 is given more than once (0.3, 0.30)"),
    (["scoring.recall_k.0=1,1.0"], [], "the value 1 is given more than once (1, 1.0)"),  # one number, int or float
    (["scoring.tau=0.3,0.5"], ["scoring.tau=0.2"], "--set also sets scoring.tau"),
    (["scoring.tau=0.3,0.5"], ["evaluation.tau=0.2"], "--set also sets scoring.tau"),
    (["scoring.tau=0.3", "scoring.tau=0.5"], [], "scoring.tau is already a --grid axis"),
    (["scoring.tau=0.2,0.4", "scoring={tau: 0.5}"], [], "scoring overlaps the --grid axis scoring.tau"),
    (["scoring={tau: 0.5}", "scoring.tau=0.2,0.4"], [], "scoring.tau overlaps the --grid axis scoring"),
    (["methods=[]", "scoring.tau=1", "methods.0.params.epochs=1"], [], "overlaps the --grid axis methods"),
    (["scoring={tau: 0.5},{tau: 0.6}"], ["scoring.tau=0.3"], "what --set scoring.tau sets"),
    (["methods=[]"], ["methods.0.params.epochs=3"], "what --set methods.0.params.epochs sets"),
    (["seed=1,2"], [], "the seeds are --seeds"),
])
def test_a_bad_grid_is_one_line_naming_the_option(options, overrides, message):
    with pytest.raises(ScenarioError) as error:
        grid.parse_axes(options, overrides)
    assert message in str(error.value) and str(error.value).startswith(f"--grid '{options[-1]}': ")
    assert "\n" not in str(error.value)


def test_paths_that_share_only_the_start_of_a_name_do_not_overlap():
    axes = grid.parse_axes(["methods.1.params.epochs=1,2", "methods.10.params.epochs=3", "scoring.ta=1"],
                           ["scoring.tau=0.3", "methods+={name: X, plugin: handcrafted}"])
    assert [a.path for a in axes] == ["methods.1.params.epochs", "methods.10.params.epochs", "scoring.ta"]
    # a grid path inside a --set path: the point's value is set after the --set's, and named
    assert [a.path for a in grid.parse_axes(["scoring.tau=0.2"], ["scoring={tau: 0.5, delta: 1}"])] == ["scoring.tau"]


def test_overlapping_axes_are_refused_on_the_command_line_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "out"  # tau -1: a sweep that took the grid would stop at its first point
    args = ["sweep", "quickstart", "--grid", "scoring.tau=0.2,0.4", "--grid", "scoring={tau: -1}", "--seeds", "0",
            "--out", str(out), "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vitaplace: error: --grid 'scoring={tau: -1}': scoring overlaps the --grid axis scoring.tau (one "
                   "path inside the other: the later would overwrite the earlier's values while the folders name "
                   "both); give one of them"]
    assert not out.exists()


def test_a_grid_over_the_bound_needs_yes(tmp_path, capsys):
    # the first point's tau is one the scenario refuses: what is loaded fails at once
    out, taus = tmp_path / "out", ",".join(["-1", *(f"0.{i:03d}" for i in range(1, 40))])
    big = ["--grid", f"scoring.tau={taus}", "--grid", f"methods.0.params.epochs={','.join(map(str, range(1, 27)))}"]
    assert main(["sweep", "quickstart", *big, "--seeds", "0", "1", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vitaplace: error: --grid: 1040 grid points (40 x 26) x 2 seed(s) = 2080 runs, over 1000 points; "
                   "give --yes to run them all"] and not out.exists()
    # with --yes the points are loaded
    assert main(["sweep", "quickstart", *big, "--seeds", "0", "--out", str(out), "--no-progress", "--yes"]) == 2
    assert capsys.readouterr().err.startswith("vitaplace: error: --grid point tau=-1,epochs=1: ")
    at_bound = grid.parse_axes([f"a={taus}", f"b={','.join(map(str, range(25)))}"])
    assert grid.check_size(at_bound, 3, False) == 1000
    assert grid.check_size([*at_bound, grid.Axis("c", ("1", "2"), (1, 2))], 1, True) == 2000
    assert grid.check_size([], 3, False) == 1  # no grid: the sweep's one point


def test_loading_a_grid_shows_its_progress_once_it_takes_long(monkeypatch, capsys):
    points = grid.grid_points(grid.parse_axes(["a=1,2,3"]))
    loaded = grid.load_points(points, lambda assignments: (None, {"a": assignments}), progress=True)
    assert [p.resolved for p in loaded] == [{"a": ("a=1",)}, {"a": ("a=2",)}, {"a": ("a=3",)}]
    assert capsys.readouterr().err == ""  # quicker than the delay: no bar
    monkeypatch.setattr(grid, "PROGRESS_DELAY_S", 0.0)
    grid.load_points(points, lambda assignments: (None, {}), progress=True)
    assert "grid points loaded: 100%" in capsys.readouterr().err
    grid.load_points(points, lambda assignments: (None, {}), progress=False)
    assert capsys.readouterr().err == ""


def test_a_drive_without_revisits_is_named_on_the_console_in_the_tables_and_by_aggregate(tmp_path, capsys):
    """At tau 0.018 m seed 0's query drive of the tiny scenario has no query that close to a
    reference pose (its nearest is 0.021 m away) while seed 2's has five (0.013-0.016 m): the
    point's F1 is seed 2's alone, with the count; at tau 0.3 both seeds count. Progress bars
    drawn at once (no delay) show each step over the grid points."""
    path, out = _scenario_file(tmp_path, test_plugin=False), tmp_path / "out"
    args = ["sweep", str(path), "--grid", "scoring.tau=0.018,0.3", "--seeds", "0", "2", "--workers", "2", "--out",
            str(out)]
    result = vitaplace(args, dict(os.environ), "import vitaplace.engine.study.grid as g\ng.PROGRESS_DELAY_S = 0.0")
    assert result.returncode == 0, result.stderr[-3000:]
    revisits = {(name, seed): json.loads((out / name / f"seed-{seed}" / "results.json").read_text())[0]
                for name in ("tau=0.018", "tau=0.3") for seed in (0, 2)}
    assert [r["n_revisit"] for r in revisits.values()] == [0, 5, 5, 5]  # what the test stands on
    f1 = revisits[("tau=0.018", 2)]["max_f1"]
    expected = f"{f1:.3f} (1 of 2 seeds; 1 without revisits)"
    assert re.search(rf"tau=0\.018 E1 +H +query-to-reference +max F1 {re.escape(expected)}", result.stderr)
    assert len(re.findall(r"seed 0, E1 query-to-reference: no revisit", result.stderr)) == 1
    assert f"| tau=0.018 | E1 | H | query-to-reference | max_f1 | 1 | {expected} |" in (out / "grid.md").read_text()
    assert "| 0 | E1 | query-to-reference | H |" in (out / "tau=0.018" / "sweep.md").read_text()
    assert "without revisits" not in (out / "tau=0.3" / "sweep.md").read_text().split("\n", 3)[3]  # past the legend
    for step in ("grid points loaded", "grid points prepared", "grid point summaries"):
        assert f"{step}: 100%" in result.stderr, step
    folders = [str(out / "tau=0.018" / f"seed-{seed}") for seed in (0, 2)]
    assert main(["aggregate", *folders, "--out", str(tmp_path / "agg")]) == 0
    assert "seed 0, E1 query-to-reference: no revisit" in capsys.readouterr().err
    (row,) = [r for r in read_csv(tmp_path / "agg" / "sweep.csv") if r["metric"] == "max_f1"]
    assert (row["n"], row["n_no_revisit"], float(row["mean"])) == ("1", "1", f1)


def test_points_that_would_share_a_folder_are_refused():
    with pytest.raises(ScenarioError, match="two grid points would share the folder x=a_b"):
        grid.grid_points(grid.parse_axes(["a.x=a b,a/b"]))


@pytest.mark.parametrize("option, message", [
    ("methods.0.params.epocs=1,2", "epocs"),
    ("methods.7.params.epochs=1,2", "has no item 7"),
    ("scoring.taus=1,2", "taus"),
    ("scoring.tau=0.3,-1", "tau"),
])
def test_a_grid_point_the_scenario_refuses_is_one_line_before_anything_is_written(option, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["sweep", "quickstart", "--grid", option, "--seeds", "0", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vitaplace: error: --grid point ") and message in err[0], err
    assert not out.exists()


def test_config_prints_the_scenario_the_api_resolves(tmp_path, capsys):
    path = _scenario_file(tmp_path, test_plugin=False)
    sets = ["scoring.tau=0.4", "methods.0.params.crop_fraction=0.5", "methods+={name: H2, plugin: handcrafted}"]
    assert main(["config", str(path), *(a for s in sets for a in ("--set", s))]) == 0
    printed = capsys.readouterr().out
    assert Scenario.model_validate(yaml.safe_load(printed)) == api.load_scenario(path, sets)
    resolved = yaml.safe_load(printed)
    assert resolved["scoring"]["tau"] == 0.4 and resolved["methods"][1]["name"] == "H2"
    assert main(["config", "quickstart"]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["name"] == api.load_scenario("quickstart").name


def test_config_resolved_fills_every_default_and_keeps_what_the_scenario_sets(tmp_path, capsys):
    from vitaplace.engine.config.scenario import ScoringSettings
    from vitaplace.engine.sim.robot import RobotSpec
    from vitaplace.plugins.handcrafted.extractor import HandcraftedParams
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    path = _scenario_file(tmp_path, test_plugin=False)  # sets scoring.tau 0.3; method H with no params
    sets = ["methods.0.params.crop_fraction=0.5", "seed=7", "methods+={name: L, plugin: mupnet}"]
    assert main(["config", str(path), "--resolved", *(a for s in sets for a in ("--set", s))]) == 0
    resolved = yaml.safe_load(capsys.readouterr().out)
    assert resolved["scoring"]["tau"] == 0.3 and resolved["seed"] == 7
    assert resolved["scoring"]["direction"] == ScoringSettings.model_fields["direction"].default
    assert resolved["robot"]["whisk_hz"] == RobotSpec.model_fields["whisk_hz"].default
    h, mupnet = resolved["methods"]
    assert h["params"]["crop_fraction"] == 0.5
    assert h["params"]["max_shift"] == HandcraftedParams.model_fields["max_shift"].default
    assert set(h["params"]) == set(HandcraftedParams.model_fields)
    assert mupnet["params"]["epochs"] == MupnetParams.model_fields["epochs"].default
    # the seed the run hands the second method: SeedSequence([scenario seed, 1000 + its place])
    assert mupnet["params"]["seed"] == int(np.random.SeedSequence([7, 1001]).generate_state(1)[0])
    assert Scenario.model_validate(resolved).model_dump(mode="json") == resolved


@pytest.mark.parametrize("args, message", [
    (["--set", "scoring.taus=1"], "taus"),
    (["--set", "methods.9.name=x"], "has no item 9"),
])
def test_config_of_a_bad_scenario_is_one_line_exit_2(args, message, tmp_path, capsys):
    assert main(["config", str(_scenario_file(tmp_path, test_plugin=False)), *args]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert captured.out == "" and len(err) == 1 and message in err[0], err
    assert main(["config", str(tmp_path / "missing.yaml")]) == 2
    assert "no such scenario file" in capsys.readouterr().err


def test_a_grid_on_ray_runs_every_point_and_reports_a_failed_seed_by_its_point(tmp_path, own_ray):  # noqa: F811
    prelude, env = own_ray
    path, out = _scenario_file(tmp_path, fail_seed=1), tmp_path / "out"
    args = ["sweep", str(path), "--grid", "scoring.tau=0.3,0.5", "--seeds", "0", "1", "--out", str(out), "--ray",
            "auto", "--no-progress"]
    result = vitaplace(args, env, prelude, LIST_TASKS.replace(">= 2", ">= 4"))
    assert result.returncode == 1, result.stderr[-3000:]
    assert "TASKS ['tiny tau=0.3 seed 0', 'tiny tau=0.3 seed 1', 'tiny tau=0.5 seed 0', 'tiny tau=0.5 seed 1']" \
        in result.stdout, result.stdout
    for name in ("tau=0.3", "tau=0.5"):
        assert len(re.findall(rf"{name} seed 1 failed: ValueError: injected failure", result.stderr)) == 1
        assert "Traceback" in (out / name / "seed-1" / "error.txt").read_text()
        assert json.loads((out / name / "sweep.json").read_text())["seeds"] == [0]
    assert ("2 of 4 runs (2 points x 2 seeds) failed, missing from the summary: tau=0.3/seed-1 tau=0.5/seed-1"
            in result.stderr)
    record = json.loads((out / "grid.json").read_text())
    assert [p["failed"] for p in record["points"]] == [
        {"1": "ValueError: injected failure second line of the message"}] * 2
    assert {r["n"] for r in read_csv(out / "grid.csv")} == {"1"}


def test_a_grid_on_slurm_s_local_executor_is_one_array_of_every_point_s_seeds(tmp_path, plugin_env):  # noqa: F811
    pytest.importorskip("submitit", reason="submitit is not installed (pip install 'vitaplace[slurm]')")
    path, out = _scenario_file(tmp_path), tmp_path / "out"
    args = ["sweep", str(path), "--grid", "methods.1.params.crop_fraction=0.5,1.0", "--seeds", "0", "--out", str(out),
            "--slurm", "local", "--time", "10", "--no-progress"]
    result = vitaplace(args, plugin_env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert re.search(r"SLURM \(local\): job .*2 task\(s\)", result.stderr), result.stderr[-3000:]
    assert [p["name"] for p in json.loads((out / "grid.json").read_text())["points"]] == ["crop_fraction=0.5",
                                                                                         "crop_fraction=1.0"]
    assert {r["point"] for r in read_csv(out / "grid.csv")} == {"crop_fraction=0.5", "crop_fraction=1.0"}
