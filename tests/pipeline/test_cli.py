"""The command line: bad scenarios fail with one clear line; the quickstart runs end to end and caches."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import install_plugin

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
ENV_E1 = str(SCENARIOS / "environments" / "e1.yaml")

#: The quickstart scenario, sized down so the whole pipeline runs in seconds.
TINY = [
    "train.run.n_samples=40",  # the first sample whose whiskers touch is the 34th
    "evaluations.0.run.n_samples=10",
    "methods.0.params.image_size=[9,16]",
    "methods.0.params.visual_layers=[12]",
    "methods.0.params.tactile_layers=[8]",
    "methods.0.params.joint_size=6",
    "methods.0.params.epochs=2",
    "methods.0.params.batch_size=6",
    "methods.0.params.max_steps=20",
]


def write_scenario(tmp_path: Path, data: dict, name: str = "scenario.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def valid_scenario() -> dict:
    return {
        "name": "t",
        "train": {"environment": ENV_E1, "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": ENV_E1, "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
        "scoring": {"tau": 0.3},
    }


def run_cli(args: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "vitaplace.engine.cli.main", *args], capture_output=True, text=True, timeout=600, cwd=cwd
    )


def test_valid_scenario_validates(tmp_path, capsys):
    assert main(["validate", str(write_scenario(tmp_path, valid_scenario()))]) == 0
    assert "valid scenario 't'" in capsys.readouterr().out


BAD = {
    "wrong type": (lambda d: d["scoring"].update(tau="far"), r"scoring\.tau: .*number"),
    "unknown key": (lambda d: d.update(colour="red"), r"colour: unknown key"),
    "typo": (lambda d: d["scoring"].update(tua=0.3), r"scoring\.tua: unknown key; did you mean 'tau'\?"),
    "missing file": (lambda d: d["train"].update(environment="nowhere.yaml"), r"train\.environment: no such file"),
    "unknown plugin": (
        lambda d: d["methods"][0].update(plugin="sift"),
        r"methods\.0\.plugin: unknown feature extractor 'sift'; available: .*handcrafted.*mupnet",
    ),
    "negative tau": (lambda d: d["scoring"].update(tau=-1), r"scoring\.tau: .*greater than 0"),
    "zero tau": (lambda d: d["scoring"].update(tau=0), r"scoring\.tau: .*greater than 0"),
    "infinite tau": (lambda d: d["scoring"].update(tau=float("inf")), r"scoring\.tau: .*finite"),
    # the faithful E1 is 6.05 m square: its diagonal is 8.56 m
    "tau over the diagonal": (lambda d: d["scoring"].update(tau=9.0), r"scoring\.tau: 9\.0 m is not below the 8\.56 m"),
    "nan delta": (lambda d: d["scoring"].update(delta=float("nan")), r"scoring\.delta: .*finite"),
    "heading tolerance past 180": (
        lambda d: d["scoring"].update(heading_tolerance_deg=200), r"scoring\.heading_tolerance_deg: .*180"
    ),
    "one evaluation sample": (
        lambda d: d["evaluations"][0]["run"].update(n_samples=1), r"evaluations\.0\.run: .*at least 5 samples"
    ),
    "negative seed": (lambda d: d.update(seed=-1), r"seed: .*greater than or equal to 0"),
    "boolean seed": (lambda d: d.update(seed=True), r"seed: expected a whole number, not a boolean"),
    "fractional seed": (lambda d: d.update(seed=1.5), r"seed: .*valid integer"),
    "method named ..": (lambda d: d["methods"][0].update(name=".."), r"methods\.0\.name: .*parent folder"),
    "method name with a slash": (lambda d: d["methods"][0].update(name="../../x"), r"methods\.0\.name: .*pattern"),
    "huge name": (lambda d: d.update(name="x" * 1_000_000), r"name: .*pattern"),
    # refused before any compute: memory estimated from sizes against this machine's RAM
    "1e12 samples": (lambda d: d["train"]["run"].update(n_samples=10**12), r"train\.run\.n_samples: .* GB of memory"),
    "huge images": (
        lambda d: d["methods"][0].update(plugin="mupnet", params={"image_size": [20000, 20000]}),
        r"methods\.0\.params\.image_size: 20000x20000 images need .* GB",
    ),
    "a huge joint latent": (  # its weights from a 100-wide top visual layer alone: 1e9 x 100 x 4 B x 2 copies
        lambda d: d["methods"][0].update(plugin="mupnet", params={"joint_size": 10**9}),
        r"methods\.0\.params\.joint_size: joint latents of 1000000000 need .* GB",
    ),
    "huge hidden layers": (  # 1e6 x 1e6 weights x 4 B x 3 copies (W, its transpose, the default momentum)
        lambda d: d["methods"][0].update(plugin="mupnet", params={"tactile_layers": [10**6, 10**6]}),
        r"methods\.0\.params\.tactile_layers: tactile layers \[1000000, 1000000\] need 1.2e\+04 GB",
    ),
    "unknown activation": (
        lambda d: d["methods"][0].update(plugin="mupnet", params={"activation": "relu6"}),
        r"methods\.0\.params: .*activation",
    ),
    "bad params": (
        lambda d: d["methods"][0].update(params={"grid": "big"}),
        r"methods\.0\.params: extractor 'handcrafted': grid",
    ),
    "missing key": (lambda d: d.pop("methods"), r"methods: required key is missing"),
    "complementarity of an unknown method": (
        lambda d: d["scoring"].update(complementarity=[{"vision": "H", "touch": "HT"}]),
        r"scoring\.complementarity\.0\.touch: no method 'HT' \(methods: H\)",
    ),
    "complementarity of one method with itself": (
        lambda d: d["scoring"].update(complementarity=[{"vision": "H", "touch": "H"}]),
        r"scoring\.complementarity\.0: vision and touch are the same method 'H'",
    ),
    "gate over 1": (
        lambda d: d["evaluations"][0].update(gates={"rescue_min": 1.5}),
        r"evaluations\.0\.gates\.rescue_min: .*less than or equal to 1",
    ),
    "unknown gate": (
        lambda d: d["evaluations"][0].update(gates={"rescue": 0.5}),
        r"evaluations\.0\.gates\.rescue: unknown key; did you mean 'rescue_min'",
    ),
    "evaluations not a list": (lambda d: d.update(evaluations=True), r"evaluations: Input should be a valid list"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scenario_exits_2_with_one_clear_line(tmp_path, case):
    data = valid_scenario()
    BAD[case][0](data)
    path = write_scenario(tmp_path, data)
    result = run_cli(["run", str(path), "--out", str(tmp_path / "out")])
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert lines[0].startswith(f"vitaplace: error: {path}: ")
    import re

    assert re.search(BAD[case][1], lines[0]), lines[0]
    assert not (tmp_path / "out" / "cache").exists()


def test_invalid_yaml_names_the_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: t\ntrain: [unclosed\n")
    result = run_cli(["validate", str(path)])
    assert result.returncode == 2
    assert re_line(result.stderr, rf"{path}: invalid YAML at line \d+")


def test_missing_scenario_file(tmp_path):
    result = run_cli(["run", str(tmp_path / "nope.yaml")])
    assert result.returncode == 2
    assert "no such scenario file" in result.stderr and "quickstart" in result.stderr


def test_bad_override_is_reported(tmp_path):
    path = write_scenario(tmp_path, valid_scenario())
    result = run_cli(["validate", str(path), "--set", "scoring.tau"])
    assert result.returncode == 2 and "expected key.path=value" in result.stderr


def test_an_override_value_that_is_not_yaml_is_one_line(tmp_path):
    path = write_scenario(tmp_path, valid_scenario())
    result = run_cli(["validate", str(path), "--set", "scoring.tau=[0.3"])
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "vitaplace: error: --set 'scoring.tau=[0.3': the value is not YAML (expected ',' or ']', but got "
        "'<stream end>'); a text with YAML's special characters needs quotes"]


def re_line(text: str, pattern: str) -> bool:
    import re

    return any(re.search(pattern, line) for line in text.splitlines())


def test_extends_merges_over_the_base(tmp_path):
    from vitaplace.engine.config.loading import load_scenario

    base = write_scenario(tmp_path, valid_scenario(), "base.yaml")
    child = write_scenario(tmp_path, {"extends": base.name, "name": "child", "scoring": {"tau": 0.5}}, "child.yaml")
    scenario, _ = load_scenario(child)
    assert scenario.name == "child" and scenario.scoring.tau == 0.5
    assert scenario.methods[0].plugin == "handcrafted"


def test_extends_names_a_file_next_to_it_first_with_or_without_yaml(tmp_path):
    """README: ``extends: quickstart`` reads a file of that name next to yours before the
    shipped one; ``extends: base`` finds base.yaml."""
    from vitaplace.engine.config.loading import load_scenario

    write_scenario(tmp_path, valid_scenario() | {"description": "the local quickstart"}, "quickstart.yaml")
    write_scenario(tmp_path, valid_scenario() | {"description": "the local base"}, "base.yaml")
    for parent, description in (("quickstart", "the local quickstart"), ("base", "the local base")):
        child = write_scenario(tmp_path, {"extends": parent, "name": "child"}, "child.yaml")
        assert load_scenario(child)[0].description == description


@pytest.mark.parametrize("parent, there", [("nothere", "no file {tmp}/nothere or .yaml"),
                                           ("folder", "{tmp}/folder is a folder")])
def test_extends_naming_nothing_readable_is_one_line_naming_the_key(tmp_path, parent, there):
    (tmp_path / "folder").mkdir()
    child = write_scenario(tmp_path, {"extends": parent, "name": "child"}, "child.yaml")
    result = run_cli(["validate", str(child)])
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [
        f"vitaplace: error: {child.resolve()}: extends: {parent!r}: expected a YAML file; "
        f"{there.format(tmp=tmp_path.resolve())}, and vitaplace ships none of that name"]


def test_the_old_scoring_key_is_read_with_a_warning(tmp_path, caplog):
    """`scoring:` was called `evaluation:`; files and --set paths that say so still load, as
    `scoring`, each with one warning naming the file or the assignment; a file setting both
    names is an error naming it."""
    from vitaplace.engine.config.loading import load_scenario

    old = {k: v for k, v in valid_scenario().items() if k != "scoring"} | {"evaluation": {"tau": 0.5}}
    base = write_scenario(tmp_path, old, "base.yaml")
    child = write_scenario(tmp_path, {"extends": base.name, "name": "child", "scoring": {"direction": "both"}},
                           "child.yaml")
    with caplog.at_level("WARNING", logger="vitaplace"):
        scenario, raw = load_scenario(child, ["evaluation.heading_tolerance_deg=null"])
    assert (scenario.scoring.tau, scenario.scoring.direction, scenario.scoring.heading_tolerance_deg) == (
        0.5, "both", None)
    assert "evaluation" not in raw and raw["scoring"]["tau"] == 0.5
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 2, warnings
    assert str(base.resolve()) in warnings[0] and "'evaluation' is now called 'scoring'" in warnings[0]
    assert "--set 'evaluation.heading_tolerance_deg=null'" in warnings[1]

    both = write_scenario(tmp_path, valid_scenario() | {"evaluation": {"tau": 0.5}}, "both.yaml")
    result = run_cli(["validate", str(both)])
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert re_line(result.stderr, r"both\.yaml: both 'evaluation' and 'scoring' are set"), result.stderr


@pytest.fixture(scope="module")
def quickstart_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("quickstart") / "out"
    args = ["run", "quickstart", "--out", str(out), "--no-progress"]
    for override in TINY:
        args += ["--set", override]
    first = run_cli(args)
    assert first.returncode == 0, first.stderr
    manifest_first = json.loads((out / "manifest.json").read_text())
    second = run_cli(args)
    assert second.returncode == 0, second.stderr
    return out, manifest_first, json.loads((out / "manifest.json").read_text())


def test_quickstart_writes_every_output(quickstart_run):
    out, manifest, _ = quickstart_run
    for name in ("scenario.resolved.yaml", "manifest.json", "results.json", "results.csv", "report.md", "log.txt"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    rows = json.loads((out / "results.json").read_text())
    assert {(r["environment"], r["method"]) for r in rows} == {("E1", "L"), ("E1", "H")}
    for row in rows:
        assert 0.0 <= row["max_f1"] <= 1.0 and row["n_queries"] == 10
        assert row["heading_tolerance_deg"] == 30.0  # the documented default
        # E1 is the training world: its own max-F1 threshold gives its max F1; without a
        # revisit it has none (test_f1_at_the_training_threshold_is_undefined_where_...)
        if row["n_revisit"]:
            assert row["f1_at_e1_threshold"] == pytest.approx(row["max_f1"])
            assert row["e1_threshold"] == pytest.approx(row["delta_at_max_f1"])
        else:
            assert row["f1_at_e1_threshold"] is None and row["e1_threshold"] is None
    difficulties = [row["difficulty"] for row in rows]
    assert list(difficulties[0]) == ["nearest_ref_median_m", "nearest_ref_p90_m", "nearest_ref_heading_median_deg",
                                     "chance_r1", "query_touch_share", "reference_touch_share",
                                     "query_longest_stay_share", "reference_longest_stay_share",
                                     "touch_both_share", "touch_one_side_share", "touch_correspondence"]
    assert difficulties[0] == difficulties[1]  # a property of the evaluation pair, not of the method
    for method in ("L", "H"):
        folder = out / "evaluations" / "E1" / method / "query-to-reference"
        assert (folder / "decisions.csv").is_file() and (folder / "matrices.npz").is_file()
    figures = {p.name for p in (out / "figures").iterdir()}
    for stem in ("pr-E1", "matrices-E1-L-query-to-reference", "trajectories-E1-H-query-to-reference", "training-L"):
        assert f"{stem}.png" in figures and f"{stem}.pdf" not in figures, stem  # PDF only when asked
    assert all(r["status"] == "ran" for r in manifest["stages"])
    by_stage = {(r["stage"], r["item"]): r for r in manifest["stages"]}
    transform = by_stage[("transform", "L E1/query")]
    assert transform["inputs"] == [by_stage[("fit", "L")]["key"], by_stage[("simulate", "E1/query")]["key"]]
    assert (out / transform["output"]).is_file() and (out / by_stage[("fit", "L")]["output"]).is_dir()
    assert manifest["vitaplace_version"] and manifest["machine"]["cpus"]
    assert manifest["machine"]["blas"]
    assert all(lib["architecture"] and lib["threads"] >= 1 for lib in manifest["machine"]["blas"])
    assert manifest["packages"]["numpy"] == np.__version__ and manifest["packages"]["mujoco"]


def test_the_manifest_says_how_training_ended_for_the_methods_that_train(quickstart_run):
    """TINY trains L for 2 epochs (epochs=2): the manifest's ``training`` holds MuPNet's summary
    of that, in both runs (the second finds the fit cached); ViTa-SLAM (H) trains nothing."""
    _, first, second = quickstart_run
    for manifest in (first, second):
        assert set(manifest["training"]) == {"L"}
        assert manifest["training"]["L"]["max_epochs"] == 2 and 1 <= manifest["training"]["L"]["epochs"] <= 2


def test_second_run_reuses_every_stage(quickstart_run):
    _, first, second = quickstart_run
    assert [(r["stage"], r["item"]) for r in second["stages"]] == [(r["stage"], r["item"]) for r in first["stages"]]
    assert {r["status"] for r in second["stages"]} == {"cached"}


def test_force_redoes_one_stage(quickstart_run):
    out, _, _ = quickstart_run
    args = ["evaluate", "quickstart", "--out", str(out), "--no-progress", "--force", "evaluate"]
    for override in TINY:
        args += ["--set", override]
    assert run_cli(args).returncode == 0
    stages = json.loads((out / "manifest.json").read_text())["stages"]
    ran = {r["stage"] for r in stages if r["status"] == "ran"}
    assert ran == {"evaluate"}


def _rerun(out: Path, *extra: str) -> dict[tuple[str, str], str]:
    """Re-run the tiny quickstart into ``out`` with extra overrides; (stage, item) -> status."""
    args = ["run", "quickstart", "--out", str(out), "--no-progress"]
    for override in (*TINY, *extra):
        args += ["--set", override]
    result = run_cli(args)
    assert result.returncode == 0, result.stderr
    return {(r["stage"], r["item"]): r["status"] for r in json.loads((out / "manifest.json").read_text())["stages"]}


@pytest.mark.slow  # the runner's cache and recovery, not a dependency's version
def test_cache_redoes_exactly_what_a_change_touches(tmp_path):
    """A method parameter re-runs that method's fit, transforms and evaluations and the report,
    never the simulation nor the other method; the revisit tolerance re-runs only the
    evaluations and the report."""
    out = tmp_path / "out"
    assert set(_rerun(out).values()) == {"ran"}
    status = _rerun(out, "methods.0.params.epochs=3")
    ran = {key for key, s in status.items() if s == "ran"}
    assert ran == {("fit", "L"), ("transform", "L E1/query"), ("transform", "L E1/reference"),
                   ("evaluate", "E1 L query-to-reference"), ("report", "report")}, ran
    status = _rerun(out, "methods.0.params.epochs=3", "scoring.tau=0.4")
    ran = {key for key, s in status.items() if s == "ran"}
    assert ran == {("evaluate", "E1 L query-to-reference"), ("evaluate", "E1 H query-to-reference"),
                   ("report", "report")}, ran


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENARIOS.glob("*.yaml")))
def test_shipped_scenarios_validate(name, capsys):
    assert main(["validate", name]) == 0
    assert f"valid scenario '{name}'" in capsys.readouterr().out


def test_simulate_an_environment_file_writes_a_dataset(tmp_path):
    import h5py

    result = run_cli(["simulate", ENV_E1, "--samples", "3", "--out", str(tmp_path), "--no-progress"])
    assert result.returncode == 0, result.stderr
    (path,) = tmp_path.glob("*.h5")
    with h5py.File(path) as f:
        assert f["images"].shape == (3, 120, 160, 3) and f["theta"].shape == (3, 24)


def test_unknown_forced_stage_is_a_user_error(tmp_path):
    path = write_scenario(tmp_path, valid_scenario())
    result = run_cli(["run", str(path), "--out", str(tmp_path / "out"), "--force", "fitt"])
    assert result.returncode == 2 and "unknown stage(s) fitt" in result.stderr and "Traceback" not in result.stderr


def test_plugins_command_lists_the_builtins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "handcrafted" in out and "mupnet" in out


def test_non_finite_features_stop_the_pipeline_with_a_clear_error():
    import numpy as np

    from vitaplace.engine.pipeline.output_checks import StageError, check_finite

    good = {"latent": np.ones((3, 2))}
    assert check_finite(good, "x") is good
    bad = {"latent": np.array([[1.0, 2.0], [np.nan, 0.0], [np.inf, 1.0]])}
    with pytest.raises(StageError, match=r"transform L E1/query: feature 'latent' .* in 2 samples \(first: 1\)"):
        check_finite(bad, "transform L E1/query")


ORACLE_PLUGIN = '''
from pathlib import Path
import numpy as np
from scipy.spatial.distance import cdist
from vitaplace.engine.extension.features import FeatureExtractor
from vitaplace.engine.extension.hookspecs import hookimpl


class Oracle(FeatureExtractor):
    """Test-only: the feature of a sample is its true position, the distance Euclidean."""
    name = "oracle"
    def fit(self, train): pass
    def transform(self, run): return {"xy": np.asarray(run.poses[:, :2], dtype=np.float64)}
    def distance(self, query, reference): return cdist(query["xy"], reference["xy"])
    def save_state(self, directory: Path): pass
    def load_state(self, directory: Path): pass


@hookimpl
def vitaplace_register_features(register):
    register(Oracle)
'''


def test_oracle_features_score_perfectly_end_to_end(tmp_path):
    """Features that are the true positions must give max F1 = 1 and recall@1 = 1 through the
    whole CLI, and matrices.npz must hold TME and GTM index-aligned (query rows, reference
    columns): GTM is the Euclidean distance of the two runs' poses, which here is the TME,
    where they face alike."""
    pkg = tmp_path / "site"
    pkg.mkdir()
    install_plugin(pkg, "vitaplace_oracle_plugin", ORACLE_PLUGIN, "vitaplace-oracle-plugin", "0.0.1", "oracle")
    scenario = valid_scenario()
    scenario["evaluations"][0]["run"]["n_samples"] = 12
    scenario["methods"] = [{"name": "O", "plugin": "oracle"}]
    path = write_scenario(tmp_path, scenario)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(pkg), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "run", str(path), "--out", str(out)],
                          capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (row,) = json.loads((out / "results.json").read_text())
    assert row["max_f1"] == pytest.approx(1.0)
    assert row["recall_at_k"]["1"] == pytest.approx(1.0)
    (npz,) = list(out.glob("evaluations/E1/O/**/matrices.npz"))
    # and +inf where the two runs face more than the default 30 degrees apart
    from vitaplace.engine.data.dataset import open_run

    yaw = [open_run(next((out / "cache" / "datasets").glob(f"E1-{role}-*.h5"))).poses[:, 2]
           for role in ("query", "reference")]
    facing_apart = np.degrees(np.abs(np.angle(np.exp(1j * (yaw[0][:, None] - yaw[1][None, :]))))) > 30
    assert facing_apart.any() and not facing_apart.all()
    with np.load(npz) as m:
        np.testing.assert_array_equal(np.isinf(m["gtm"]), facing_apart)
        np.testing.assert_allclose(m["gtm"][~facing_apart], m["tme"][~facing_apart], atol=1e-9)


HOSTILE_PLUGIN = ORACLE_PLUGIN.replace('name = "oracle"', 'name = "hostile"').replace(
    "    def fit(self, train): pass", """    def fit(self, train):
        import os
        if os.environ["HOSTILE"] == "fit":
            raise ValueError("boom\\nsecond line")""").replace(
    '    def transform(self, run): return {"xy"', '''    def transform(self, run):
        import os
        if os.environ["HOSTILE"] == "transform":
            raise KeyError("xy")
        return {"xy"''').replace(
    '    def distance(self, query, reference): return cdist(query["xy"], reference["xy"])',
    """    def distance(self, query, reference):
        import os
        d = cdist(query["xy"], reference["xy"])
        with np.errstate(over="ignore"):  # huge: near the largest float, +inf beyond (the contract allows both)
            return {"complex": d + 1j, "bool": d < 1, "huge": d * 1e308}[os.environ["HOSTILE"]]""")


def run_hostile(tmp_path: Path, hostile: str) -> tuple[subprocess.CompletedProcess, Path]:
    """``vitaplace run`` of one method of the hostile plugin, told how to misbehave by ``hostile``."""
    pkg = tmp_path / "site"
    pkg.mkdir()
    install_plugin(pkg, "vitaplace_hostile_plugin", HOSTILE_PLUGIN, "vitaplace-hostile-plugin", "0.0.1", "hostile")
    scenario = valid_scenario()
    scenario["methods"] = [{"name": "O", "plugin": "hostile"}]
    scenario["report"] = {"figures": "all"}
    out = tmp_path / "out"
    path = os.pathsep.join([str(pkg), os.environ.get("PYTHONPATH", "")])
    file = write_scenario(tmp_path, scenario)
    proc = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "run", str(file), "--out", str(out)],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ, "HOSTILE": hostile, "PYTHONPATH": path})
    return proc, out


@pytest.mark.parametrize("hostile", ["complex", "bool", "huge"])
def test_a_plugins_distances_of_no_real_dtype_are_refused_and_huge_ones_reported(tmp_path, hostile):
    """Complex or boolean distances stop the run in one line naming the stage, method, plugin
    and what was expected (never cast: the imaginary part dropped); distances near the largest
    float with +inf, which the contract allows, are scored and drawn without a warning."""
    proc, out = run_hostile(tmp_path, hostile)
    assert "Warning" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    if hostile == "huge":
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert (out / "figures" / "matrices-E1-O-query-to-reference.png").is_file()
    else:
        assert proc.returncode == 2
        dtype = {"complex": "complex128", "bool": "bool"}[hostile]
        assert proc.stderr.strip().splitlines()[-1].endswith(
            f"evaluate E1 O (plugin 'hostile'): distance returned an array of {dtype}, expected real numbers "
            "(a float or integer dtype), finite or +inf")


@pytest.mark.parametrize(("hostile", "line"), [
    ("fit", r"fit O \(plugin 'hostile'\): fit\(\) raised ValueError: boom"),
    ("transform", r"transform O \(plugin 'hostile'\) E1/query: transform\(\) raised KeyError: 'xy'"),
    ("distance", r"evaluate E1 O \(plugin 'hostile'\): distance\(\) raised KeyError: 'distance'"),
], ids=["fit", "transform", "distance"])
def test_a_plugin_method_that_raises_ends_the_run_in_one_line_its_traceback_in_a_file(tmp_path, hostile, line):
    """A plugin's own exception in fit, transform or distance is a bug of the plugin, not bad
    input: one line naming the stage, method, plugin and error (exit status 1), its traceback
    in OUT/error.txt, which the line names."""
    proc, out = run_hostile(tmp_path, hostile)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert re.fullmatch(rf"vitaplace: error: {line} \(traceback in {re.escape(str(out / 'error.txt'))}\)", last), last
    assert (out / "error.txt").read_text().startswith("Traceback (most recent call last):")


def test_a_plugins_traceback_goes_when_the_folder_is_next_written():
    """error.txt describes the failed command; once a later run of the folder replaces its
    results, the stale traceback is removed with the old record."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        proc, out = run_hostile(Path(folder), "fit")
        assert proc.returncode == 1 and (out / "error.txt").is_file()
        site = os.pathsep.join([str(Path(folder) / "site"), os.environ.get("PYTHONPATH", "")])
        again = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "-q", "run",
                                str(Path(folder) / "scenario.yaml"), "--out", str(out)], capture_output=True, text=True,
                               timeout=600, env={**os.environ, "HOSTILE": "huge", "PYTHONPATH": site})
        assert again.returncode == 0, again.stderr[-2000:]
        assert not (out / "error.txt").exists()


def _alias_bomb() -> str:
    text = "a: &a [x, x, x, x, x, x, x, x, x]\n"
    for i in range(1, 12):
        prev = "a" if i == 1 else f"b{i - 1}"
        text += f"b{i}: &b{i} [" + ", ".join([f"*{prev}"] * 9) + "]\n"
    return text


HOSTILE = {
    "binary": (bytes(range(256)), r"not UTF-8 text"),
    "duplicate key": (b"name: a\nname: b\n", r"duplicate key 'name'"),
    "alias bomb": (_alias_bomb().encode(), r"expands to more than 1,000,000 values"),
    "deep nesting": (b"name: " + b"[" * 20000 + b"]" * 20000 + b"\n", r"nested more than 100 levels deep"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_files_end_in_one_line_quickly(tmp_path, case):
    content, pattern = HOSTILE[case]
    path = tmp_path / "hostile.yaml"
    path.write_bytes(content)
    result = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "validate", str(path)],
                            capture_output=True, text=True, timeout=60)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-500:]
    import re

    assert re.search(pattern, lines[0]), lines[0]
    assert len(lines[0]) < 400


@pytest.mark.parametrize("kind", ["a file", "/dev/null", "read-only"])
def test_unusable_output_directory_is_one_line_before_any_work(tmp_path, kind):
    if kind == "a file":
        out = tmp_path / "file"
        out.write_text("x")
    elif kind == "/dev/null":
        out = Path("/dev/null")
    else:
        if os.geteuid() == 0:
            pytest.skip("root can write anywhere")
        out = tmp_path / "ro" / "out"
        (tmp_path / "ro").mkdir(mode=0o500)
    path = write_scenario(tmp_path, valid_scenario())
    result = run_cli(["run", str(path), "--out", str(out)])
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-500:]
    assert f"--out {out}" in lines[0]


def test_an_unstable_stiffness_is_refused_before_any_compute_with_one_clear_error(tmp_path):
    data = valid_scenario()
    data["robot"] = {"spring_stiffness": 1e30}
    path = write_scenario(tmp_path, data)
    result = run_cli(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"])
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-800:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "robot: spring_stiffness" in lines[0] and "stable range" in lines[0], lines
    assert not (tmp_path / "out" / "cache").exists()


def test_extractor_outputs_are_checked_with_one_line():
    from vitaplace.engine.pipeline.output_checks import StageError, check_distance, check_features

    good = {"x": np.zeros((3, 2))}
    assert check_features(good, 3, "t") is good
    with pytest.raises(StageError, match=r"t: feature 'x' has shape \(2, 2\), expected 3 rows"):
        check_features({"x": np.zeros((2, 2))}, 3, "t")
    with pytest.raises(StageError, match=r"t: transform returned list"):
        check_features([np.zeros(3)], 3, "t")
    with pytest.raises(StageError, match=r"t: distance returned shape \(3, 2\), expected \(2, 3\)"):
        check_distance(np.zeros((3, 2)), (2, 3), "t")
    cannot_compare = np.array([[0.5, np.inf, 1.0], [np.inf, np.inf, np.inf]])  # +inf: never a match
    assert check_distance(cannot_compare, (2, 3), "t") is not None
    for bad in (np.nan, -np.inf):
        with pytest.raises(StageError,
                           match=r"t: feature 'distance' has NaN or infinite values in 1 samples \(first: 1\)"):
            check_distance(np.array([[0.5, 1.0, 1.0], [1.0, bad, 1.0]]), (2, 3), "t")
    assert check_distance(np.ones((2, 3), np.int64), (2, 3), "t") is not None  # integers are real numbers
    for bad_type, dtype in ((np.ones((2, 3)) + 1j, "complex128"), (np.ones((2, 3), object), "object"),
                            (np.ones((2, 3), bool), "bool")):
        with pytest.raises(StageError, match=rf"t: distance returned an array of {dtype}, expected real numbers"):
            check_distance(bad_type, (2, 3), "t")


def test_a_second_run_into_the_same_output_is_refused_naming_the_holder(tmp_path):
    from vitaplace.engine.outputs.outdir import OutputDirError, OutputLock

    out = tmp_path / "out"
    out.mkdir()
    with OutputLock(out):  # taken and released in this process
        pass
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import time\nfrom pathlib import Path\nfrom vitaplace.engine.outputs.outdir import OutputLock\n"
         f"with OutputLock(Path({str(out)!r})):\n    print('locked', flush=True)\n    time.sleep(30)\n"],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputDirError, match=rf"another vitaplace run \(pid {holder.pid}\) is writing there"):
            with OutputLock(out):
                pass
        path = write_scenario(tmp_path, valid_scenario())
        result = run_cli(["run", str(path), "--out", str(out)])
        assert result.returncode == 2 and f"pid {holder.pid}" in result.stderr.strip().splitlines()[-1]
    finally:
        holder.kill()
        holder.wait()
    with OutputLock(out):  # released by the kernel when the holder died, even by SIGKILL
        pass


def test_temporaries_left_by_an_interrupted_run_are_removed(tmp_path):
    from vitaplace.engine.outputs.outdir import remove_stale_temporaries

    (tmp_path / "cache" / "models").mkdir(parents=True)
    part = tmp_path / "evaluations" / ".summary.json.abc.part"
    part.parent.mkdir(parents=True)
    part.write_text("half")
    model_tmp = tmp_path / "cache" / "models" / ".L-123.xyz"
    model_tmp.mkdir()
    keep = tmp_path / "evaluations" / "summary.json"
    keep.write_text("{}")
    removed = remove_stale_temporaries(tmp_path)
    assert set(removed) == {part, model_tmp} and keep.exists() and not part.exists() and not model_tmp.exists()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _worker_outlives_a_killed_parent(tmp_path: Path, main_body: str) -> bool:
    """Run a parent whose ``__main__`` body (making ``pool = worker_pool(1)``) prints a worker's
    pid, kill -9 the parent at once, and say whether the worker is still alive 20 s later."""
    import signal
    import time

    script = tmp_path / "parent.py"
    script.write_text("import os, time\nfrom vitaplace.engine.pipeline.processes import worker_pool\n"
                      "if __name__ == '__main__':\n    pool = worker_pool(1)\n" + main_body + "    time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    worker = int(parent.stdout.readline())
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 20
    while _alive(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    return _alive(worker)


def test_simulation_workers_die_with_their_parent(tmp_path):
    """kill -9 of the process that started a worker pool takes the workers with it."""
    assert not _worker_outlives_a_killed_parent(tmp_path, "    print(pool.submit(os.getpid).result(), flush=True)\n")


def test_a_worker_that_starts_after_its_parent_died_exits_at_once(tmp_path):
    """kill -9 of the parent while its spawned worker is still importing: the worker, finding
    another process as its parent, exits instead of running its task (a minute's sleep)."""
    body = "    pool.submit(time.sleep, 60)\n    print(*pool._processes, flush=True)\n"
    assert not _worker_outlives_a_killed_parent(tmp_path, body)


def _sigint(pid: int) -> str | None:
    """How process ``pid`` treats SIGINT: "ignored", "caught" (a Python that has begun to start
    up sets its handler before importing anything) or None (default, or no such process)."""
    import signal

    try:
        status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines())
    except OSError:
        return None
    bit = 1 << (signal.SIGINT - 1)
    return "ignored" if int(status["SigIgn"], 16) & bit else "caught" if int(status["SigCgt"], 16) & bit else None


def test_semaphores_left_by_an_abrupt_exit_are_cleaned_up_without_a_report():
    """A driver that made a worker pool and then ended abruptly (as after Ctrl-C) leaves its
    semaphores to multiprocessing's resource tracker, which cleans them up; its "leaked
    semaphore objects" warning, printed by that separate process after the interrupt's one
    line, is silenced (the CI once saw it break that line)."""
    code = ("import multiprocessing, os; from vitaplace.engine.pipeline.processes import worker_pool\n"
            "if __name__ == '__main__':\n"
            "    pool = worker_pool(1); multiprocessing.get_context('spawn').Semaphore(); os._exit(0)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stderr == "", done.stderr


@pytest.mark.skipif((os.cpu_count() or 1) < 2 or not Path("/proc/self/status").exists(),
                    reason="needs simulation worker processes (2+ CPUs) and /proc")
def test_ctrl_c_while_workers_start_is_one_line(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while the spawned
    simulation workers are still importing: one line, exit 130, no worker left behind, none
    that went on to record its run. Sent once the driver has started its workers (it ignores
    Ctrl-C for the moment it takes to start them, so that they start ignoring it too; a
    Ctrl-C in that moment is lost, docs/DESIGN.md), while they still import."""
    import signal
    import time
    from functools import partial

    out = tmp_path / "out"
    args = ["run", "quickstart", "--out", str(out), "-q"] + [a for o in TINY for a in ("--set", o)]
    # as from a terminal: Ctrl-C not ignored (a test run started in the background, e.g. by
    # `cmd &` in a script, ignores SIGINT, and a process keeps an ignored SIGINT ignored)
    proc = subprocess.Popen([sys.executable, "-m", "vitaplace.engine.cli.main", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=partial(signal.signal, signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    workers: list[int] = []
    while time.monotonic() < deadline and proc.poll() is None:
        try:  # the spawned workers (not multiprocessing's resource tracker)
            children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
            workers = [int(c) for c in children if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
        except OSError:
            workers = []
        started = (out / "log.txt").exists() and "worker processes" in (out / "log.txt").read_text()
        if started and len(workers) >= 2 and all(_sigint(c) for c in workers) and _sigint(proc.pid) == "caught":
            break
        time.sleep(0.005)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    assert {_sigint(c) for c in workers} == {"ignored"}  # from their first instant
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-3000:]
    assert err.strip().splitlines() == [
        "vitaplace: interrupted; finished stages are cached, run again to resume"], err[-3000:]
    time.sleep(1)
    assert not any(_alive(c) for c in workers)
    assert not list((out / "cache").rglob("*.h5")), "workers went on simulating after the interrupt"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="process identities need /proc")
def test_a_worker_whose_parent_is_not_the_one_named_exits_at_once():
    """`die_with_parent` compares the worker's parent with the identity (pid and start time)
    handed down: the right one lets the worker go on, another (a parent that died and left
    the worker to a new one) ends it with exit status 1 before it does anything."""
    from vitaplace.engine.pipeline.processes import process_identity

    code = ("import sys; from vitaplace.engine.pipeline.processes import die_with_parent; "
            "die_with_parent(sys.argv[1]); print('went on')")
    here = process_identity(os.getpid())
    pid, start = here.split(":")
    for parent, status, out in ((here, 0, "went on\n"), (f"{pid}:{int(start) + 1}", 1, ""), (f"1:{start}", 1, "")):
        result = subprocess.run([sys.executable, "-c", code, parent], capture_output=True, text=True, timeout=120)
        assert (result.returncode, result.stdout) == (status, out), (parent, result.stderr[-2000:])


@pytest.mark.slow  # the runner's cache and recovery, not a dependency's version
def test_a_damaged_cache_is_recomputed_with_one_line_each(tmp_path):
    """Flip a byte of a recorded dataset, truncate a feature file, delete a file of a trained
    model and one of an evaluation: the next run recomputes exactly those (and what depends
    on them), says why in one log line each, and ends with the same results as before."""
    out = tmp_path / "out"
    _rerun(out)
    first = json.loads((out / "results.json").read_text())
    cache = out / "cache"
    dataset = next(p for p in (cache / "datasets").rglob("*.h5") if "train" not in p.name)
    data = bytearray(dataset.read_bytes())
    data[len(data) // 2] ^= 0xFF
    dataset.write_bytes(bytes(data))
    features = next((cache / "features").glob("H-*.npz"))
    features.write_bytes(features.read_bytes()[:100])
    model = next(p for p in (cache / "models").iterdir() if p.is_dir() and p.name.startswith("L-"))
    victim = next(p for p in sorted(model.rglob("*")) if p.is_file())
    victim.unlink()
    (out / "evaluations" / "E1" / "H" / "query-to-reference" / "decisions.npz").unlink()
    status = _rerun(out)
    log_text = (out / "log.txt").read_text()
    assert log_text.count("is damaged") == 4 and "recomputing" in log_text  # dataset, features, model, evaluation
    assert ("fit", "L") in {k for k, s in status.items() if s == "ran"}
    assert json.loads((out / "results.json").read_text()) == first


@pytest.mark.slow  # the runner's cache and recovery, not a dependency's version
def test_kill_9_during_a_stage_then_resume_gives_identical_results(tmp_path):
    """SIGKILL the run while the learned method trains; running again resumes from the cached
    stages and ends with results byte-identical to an uninterrupted run."""
    import signal
    import time

    args = ["run", "quickstart", "--no-progress"]
    for override in (*TINY, "methods.0.params.epochs=400"):
        args += ["--set", override]
    clean = tmp_path / "clean"
    assert run_cli([*args, "--out", str(clean)]).returncode == 0
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "vitaplace.engine.cli.main", *args, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log_file = out / "log.txt"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if log_file.exists() and "fit       L" in log_file.read_text():
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "results.json").exists()
    resumed = run_cli([*args, "--out", str(out)])
    assert resumed.returncode == 0, resumed.stderr[-500:]
    assert (out / "results.json").read_bytes() == (clean / "results.json").read_bytes()
    statuses = {(r["stage"], r["item"]): r["status"] for r in json.loads((out / "manifest.json").read_text())["stages"]}
    assert statuses[("simulate", "train")] == "cached" and statuses[("fit", "L")] == "ran"


def test_query_off_route_drives_only_the_end_of_the_query_run_off_the_route(tmp_path):
    """Partial revisits of the route kind (the near-duplicate regression protocol): with
    query_off_route 0.5 the last half of the query run (and only that, and never the
    reference run) runs off_route_offset (0.6 m, facing outward: towards the centre) away from
    E1's route, farther than tau = 0.3, so those queries have no match. (The teleop kind's
    detours, spread along the run: tests/components/test_teleop.py.)"""
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.data.dataset import open_run
    from vitaplace.engine.outputs.outdir import cache_dir, dataset_file
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store
    from vitaplace.engine.sim.clearance import Route
    from vitaplace.engine.sim.environment import load_environment

    overrides = ["train.run.n_samples=3", "evaluations.0.run.n_samples=40", "evaluations.0.query_off_route=0.5"]
    scenario, resolved = load_scenario("near-duplicate", overrides)
    run_stages(scenario, resolved, Store(tmp_path, progress=False, workers=1), until="simulate")
    datasets = json.loads((tmp_path / "manifest.json").read_text())["datasets"]
    route = Route(load_environment("e1").route)
    query, reference = (route.distance(open_run(dataset_file(cache_dir(tmp_path), label, datasets[label])).poses[:, :2])
                        for label in ("E1/query", "E1/reference"))
    assert query[:20].max() < 0.1 and reference.max() < 0.1
    assert query[-12:].min() > 0.4  # the detour starts at sample 20; ~8 samples to get there


def test_until_runs_the_stages_up_to_and_including_the_one_named(tmp_path):
    """``until="fit"``: the runs are simulated and the method fitted, nothing transformed or
    evaluated; the completion record covers the manifest alone (no results, no report)."""
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.outputs import outdir
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store

    overrides = ["train.run.n_samples=5", "evaluations.0.run.n_samples=5", "methods=[{name: H, plugin: handcrafted}]"]
    scenario, resolved = load_scenario("quickstart", overrides)
    assert run_stages(scenario, resolved, Store(tmp_path, progress=False, workers=1), until="fit") == []
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert {(r["stage"], r["item"]) for r in manifest["stages"]} == {
        ("simulate", "train"), ("simulate", "E1/query"), ("simulate", "E1/reference"), ("fit", "H")}
    assert "features" not in manifest
    assert list(json.loads((tmp_path / outdir.COMPLETED).read_text())["files"]) == ["manifest.json"]


# --------------------------------------------------------------------------- CLI habits


#: A scenario that names the shipped environment, with the tiny MuPNet of TINY and ViTa-SLAM.
BY_NAME = """\
name: t
train: {environment: e1, run: {kind: foraging, n_samples: 40}}
evaluations: [{name: E1, environment: e1, run: {kind: route, n_samples: 10}}]
methods:
  - name: L
    plugin: mupnet
    params: {image_size: [9, 16], visual_layers: [12], tactile_layers: [8], joint_size: 6, epochs: 2,
             batch_size: 6, max_steps: 20}
  - {name: H, plugin: handcrafted}
"""


@pytest.fixture(scope="module")
def quiet_json_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """`vitaplace -q run s.yaml --json` in a folder that holds nothing but that scenario."""
    folder = tmp_path_factory.mktemp("elsewhere")
    (folder / "s.yaml").write_text(BY_NAME)
    proc = run_cli(["-q", "run", "s.yaml", "--json", "--out", "out"], cwd=folder)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return folder / "out", proc


def test_shipped_environment_by_name_from_any_folder(quiet_json_run):
    out, _ = quiet_json_run
    resolved = yaml.safe_load((out / "scenario.resolved.yaml").read_text())
    shipped = (SCENARIOS / "environments" / "e1.yaml").resolve()
    assert Path(resolved["train"]["environment"]) == shipped
    assert Path(resolved["evaluations"][0]["environment"]) == shipped


def test_json_puts_the_results_rows_alone_on_stdout(quiet_json_run):
    out, proc = quiet_json_run
    rows = json.loads(proc.stdout)  # the whole of stdout is the JSON document
    assert rows == json.loads((out / "results.json").read_text())
    assert {(r["environment"], r["method"]) for r in rows} == {("E1", "L"), ("E1", "H")}


def test_quiet_leaves_warnings_only_on_stderr_and_everything_in_the_log(quiet_json_run):
    out, proc = quiet_json_run
    log_text = (out / "log.txt").read_text()
    for info in ("running", "max F1", "results in"):
        assert info in log_text and info not in proc.stderr, info
    assert "%|" not in proc.stderr  # -q: no progress bars either


def test_verbose_and_quiet_are_accepted_by_every_command(tmp_path, capsys):
    import argparse

    from vitaplace.engine.cli.main import build_parser

    parser = build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for name, sub in commands.choices.items():
        assert {"-v", "--verbose", "-q", "--quiet"} <= set(sub._option_string_actions), name
    path = str(write_scenario(tmp_path, valid_scenario()))
    for argv in (["-v", "validate", path], ["validate", path, "--verbose"], ["plugins", "-v"]):
        assert main(argv) == 0
        assert "vitaplace 0.1.0, Python" in capsys.readouterr().err, argv  # a debug line
    assert main(["validate", path]) == 0
    assert "Python" not in capsys.readouterr().err  # INFO by default
    assert main(["-q", "validate", path]) == 0 and "valid scenario 't'" in capsys.readouterr().out


def test_every_command_names_its_own_handler():
    """Each subparser's ``handler`` default is the function named for its command, so no
    command is left without one and no two share one."""
    import argparse

    import vitaplace.engine.cli.main as cli
    from vitaplace.engine.cli import commands

    documented = cli.__doc__.split("COMMAND one of ``")[1].split("``")[0].replace("\n", "").split("|")
    (sub,) = [a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert sorted(sub.choices) == sorted(documented)
    for name, parser in sub.choices.items():
        assert parser.get_default("handler") is getattr(commands, f"{name}_command"), name


@pytest.mark.parametrize("argv, expected", [
    (["bogus"], "vitaplace: error: argument COMMAND: invalid choice: 'bogus' (choose from "),
    ([], "vitaplace: error: the following arguments are required: COMMAND"),
    (["-q"], "vitaplace: error: the following arguments are required: COMMAND"),
])
def test_an_unknown_or_missing_command_is_argparses_usage_error(capsys, argv, expected):
    """argparse's error in one line on stderr (not its usage block), naming the help, exit 2."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(expected) and err[0].endswith("(see `vitaplace --help`)"), err


@pytest.mark.parametrize("argv, expected", [
    (["sweep", "quickstart", "--seeds", "1.5"],
     "vitaplace: error: argument --seeds: invalid int value: '1.5' (see `vitaplace sweep --help`)"),
    (["run"], "vitaplace: error: the following arguments are required: scenario (see `vitaplace run --help`)"),
])
def test_a_commands_usage_error_is_one_line_naming_its_help(capsys, argv, expected):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and capsys.readouterr().err.strip().splitlines() == [expected]


@pytest.mark.parametrize("argv", [
    ["simulate", "SCENARIO", "--force", "fit"],
    ["train", "SCENARIO", "--force", "transform"],
    ["evaluate", "SCENARIO", "--force", "report"],
    ["simulate", ENV_E1, "--force", "simulate"],
])
def test_force_of_a_stage_the_command_does_not_reach_is_refused(tmp_path, capsys, argv):
    path = str(write_scenario(tmp_path, valid_scenario()))
    out = tmp_path / "out"
    argv = [path if a == "SCENARIO" else a for a in argv]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: --force"), lines
    assert not out.exists() or not any(out.iterdir())


def test_set_appends_to_a_list_and_refuses_anything_else(capsys):
    from vitaplace.engine.config.overrides import apply_overrides
    from vitaplace.engine.config.scenario import ScenarioError

    data = {"methods": [{"name": "L"}], "scoring": {"tau": 0.3}}
    appended = apply_overrides(data, ["methods+={name: L2, plugin: mupnet, params: {epochs: 1}}"])
    assert appended["methods"] == [{"name": "L"}, {"name": "L2", "plugin": "mupnet", "params": {"epochs": 1}}]
    assert data["methods"] == [{"name": "L"}]
    assert main(["validate", "quickstart", "--set", "methods+={name: L2, plugin: handcrafted}"]) == 0
    assert "methods L, H, L2" in capsys.readouterr().out
    for bad in ("scoring.tau+=1", "scoring.recall_k+=20", "methods.0.name+=x"):
        with pytest.raises(ScenarioError, match=r"\+= appends to a list"):
            apply_overrides(data, [bad])
    assert main(["validate", "quickstart", "--set", "scoring.tau+=1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "'scoring.tau' is a float, not a list" in lines[0], lines


def test_validate_checks_environment_files(tmp_path, capsys):
    assert main(["validate", ENV_E1]) == 0
    assert "valid environment 'e1': arena 6.05 x 6.05 m, 3 landmark(s)" in capsys.readouterr().out
    assert main(["validate", "e2"]) == 0 and "valid environment 'e2'" in capsys.readouterr().out
    own = tmp_path / "mine.yaml"
    own.write_text("extends: e1\nlandmarks: []\n")  # a shipped environment by name, from another folder
    assert main(["validate", str(own)]) == 0
    printed = capsys.readouterr().out
    assert "valid environment 'mine'" in printed and "0 landmark(s)" in printed
    broken = tmp_path / "broken.yaml"
    broken.write_text("extends: e1\narena: {size: -1}\n")
    assert main(["validate", str(broken)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vitaplace: error: {broken}: arena.size"), lines


def test_shell_completion_when_shtab_is_installed():
    pytest.importorskip("shtab")
    result = run_cli(["--print-completion", "bash"])
    assert result.returncode == 0 and "sweep" in result.stdout and "validate" in result.stdout


def test_mupnet_inference_shows_a_bar_and_logs_samples_cap_and_time(quiet_json_run, capsys):
    import re

    from vitaplace.engine.data.dataset import open_run
    from vitaplace.plugins.mupnet.extractor import MupnetExtractor

    out, _ = quiet_json_run
    log_text = (out / "log.txt").read_text()
    assert re.search(r"test-time inference of 10 samples of run 'E1/query' \(step cap 20, .*\) in \d+\.\d s", log_text)
    model = next(p for p in (out / "cache" / "models").iterdir() if p.is_dir() and p.name.startswith("L-"))
    run = open_run(next((out / "cache" / "datasets").glob("E1-query-*.h5")))
    extractor = MupnetExtractor.load(model)
    for progress in (True, False):
        extractor.progress = progress
        extractor.transform(run)
        assert ("sample/s" in capsys.readouterr().err) == progress


def test_every_simulated_run_logs_its_samples_and_seconds(quiet_json_run):
    """Each run's log line gives its samples and the seconds its simulation took, and the
    manifest records those seconds, not how long the main process waited for a worker's run
    (three runs on two workers: one finishes while another is awaited)."""
    import re

    log_text = (quiet_json_run[0] / "log.txt").read_text()
    stages = json.loads((quiet_json_run[0] / "manifest.json").read_text())["stages"]
    for label, samples in (("train", 40), ("E1/query", 10), ("E1/reference", 10)):
        found = re.search(rf"simulate\s+{label}\s+simulated {samples} samples in (\d+\.\d) s", log_text)
        assert found, label
        recorded = next(r["seconds"] for r in stages if r["stage"] == "simulate" and r["item"] == label)
        assert recorded == pytest.approx(float(found.group(1)), abs=0.051), label


def test_report_states_sample_counts_and_method_parameters(quiet_json_run):
    out, _ = quiet_json_run
    report = (out / "report.md").read_text()
    (row, _) = json.loads((out / "results.json").read_text())
    assert "Training run: 40 samples" in report
    assert f"| E1 | query-to-reference | 10 | 10 | {row['n_revisit']} |" in report
    assert "**L** (`mupnet`): image_size=[9, 16]" in report and "max_steps=20" in report
    assert "**H** (`handcrafted`): none; defaults: grid=" in report
    change = json.loads((out / "manifest.json").read_text())["training"]["L"]["latent_change"]
    assert len(change) >= 1 and all(c > 0 for c in change)  # measured every epoch; latents still move
    assert (f"L: in its last epoch, each minibatch's latent steps still moved a sample's latents by a median "
            f"{100 * change[-1]:.2g} % (relative; {100 * change[0]:.2g} % in the first epoch") in report
    training = json.loads((out / "manifest.json").read_text())["training"]["L"]
    assert training["epochs"] == 2 and training["converged"] is False  # 2 epochs, a window of 20
    assert "L: training stopped at its epoch cap without meeting its convergence criterion after 2 epochs." in report
    held = training["held_out"]  # the default held-out tenth of 40 samples: 4, measured after each epoch
    assert len(held) == 2 and all(h > 0 for h in held)
    best = 0 if held[0] <= held[1] else 1
    assert (f"L: held-out energy per sample (samples kept out of training, at the latents test-time inference "
            f"settles them at) {held[-1]:.4g} after the last epoch, {held[0]:.4g} after the first, lowest "
            f"{held[best]:.4g} after epoch {best + 1}.") in report


def _copy_without_cache(out: Path, to: Path) -> Path:
    """``out`` copied to ``to`` without its cache, report and figures."""
    import shutil

    return Path(shutil.copytree(out, to, ignore=shutil.ignore_patterns("cache", "figures", "report.md*")))


def test_report_is_rebuilt_from_a_copy_of_the_output_folder_alone(quiet_json_run, tmp_path, monkeypatch, capsys):
    """`vitaplace report COPY` on a copy without the cache, the report and the figures, with
    no plugin to be found: report.md byte for byte as the run wrote it, and the same figures."""
    from vitaplace.engine.extension import registry as plugins
    out, _ = quiet_json_run
    copy = _copy_without_cache(out, tmp_path / "copy")
    monkeypatch.setattr(plugins, "discover", lambda *a, **k: pytest.fail("the report looked for plugins"))
    assert main(["-q", "report", str(copy)]) == 0
    assert capsys.readouterr().out == f"wrote {copy / 'report.md'} and its figures\n"
    report = (out / "report.md").read_text()
    for part in ("## Test-time inference", "## Training", "![trajectories]", "Training run: 40 samples",
                 "**L** (`mupnet`): image_size=[9, 16]"):
        assert part in report, part  # what the folder's manifest, training curves and poses hold is in it
    assert (copy / "report.md").read_bytes() == (out / "report.md").read_bytes()
    drawn = sorted(p.name for p in (out / "figures").iterdir())
    assert "training-L.png" in drawn and sorted(p.name for p in (copy / "figures").iterdir()) == drawn
    for name in drawn:
        assert (copy / "figures" / name).read_bytes() == (out / "figures" / name).read_bytes(), name


@pytest.mark.parametrize("damage, expected", [
    (lambda copy: (copy / "results.json").unlink(),
     "results.json: missing; expected the result rows a `vitaplace run` writes"),
    (lambda copy: (copy / "manifest.json").write_text("{"),
     "manifest.json: unreadable (JSONDecodeError); expected the manifest a `vitaplace run` writes"),
    (lambda copy: (copy / "poses" / "E1.npz").unlink(),
     "poses/E1.npz: missing; expected it in the folder of a finished `vitaplace run`"),
    (lambda copy: (copy / "completed.json").unlink(), ": not a finished run: no completed.json"),
    (lambda copy: (copy / "evaluations/E1/H/query-to-reference/decisions.npz").write_bytes(b"PK"),
     ": not a finished run: evaluations/E1/H/query-to-reference/decisions.npz is not the file its finished run "
     "recorded in completed.json"),
], ids=["no results", "corrupt manifest", "no poses", "unfinished", "damaged decisions"])
def test_report_of_a_damaged_output_folder_is_one_line_naming_the_file(quiet_json_run, tmp_path, capsys, damage,
                                                                       expected):
    copy = _copy_without_cache(quiet_json_run[0], tmp_path / "copy")
    damage(copy)
    assert main(["report", str(copy)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vitaplace: error: {copy}") and expected in err and err.count("\n") == 1, err
    assert not (copy / "report.md").exists()


def test_the_report_key_follows_what_the_report_reads_and_nothing_else(quiet_json_run, tmp_path):
    """The report stage's key (a hash of `report_key_inputs`) changes with a manifest entry the
    report prints or a file it draws, not with the manifest's timings and stage records."""
    from vitaplace.engine.report.report import report_key_inputs

    copy = _copy_without_cache(quiet_json_run[0], tmp_path / "copy")
    before = report_key_inputs(copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    (copy / "manifest.json").write_text(json.dumps({**manifest, "seconds": manifest["seconds"] + 1, "stages": []}))
    assert report_key_inputs(copy) == before
    (copy / "manifest.json").write_text(json.dumps({**manifest, "git_commit": "another"}))
    assert report_key_inputs(copy) != before
    (copy / "manifest.json").write_text(json.dumps(manifest))
    np.savez(copy / "poses" / "E1.npz", query=np.zeros((10, 3)), reference=np.zeros((10, 3)))
    assert report_key_inputs(copy) != before


def test_report_of_a_folder_takes_no_scenario_options(quiet_json_run, tmp_path, capsys):
    copy = _copy_without_cache(quiet_json_run[0], tmp_path / "copy")
    assert main(["report", str(copy), "--set", "seed=1"]) == 2
    assert "--set: apply to a scenario" in capsys.readouterr().err


def test_results_csv_has_precision_recall_f1_at_max_f1_without_fixed_delta(quiet_json_run):
    import csv

    out, _ = quiet_json_run
    rows = {r["method"]: r for r in json.loads((out / "results.json").read_text())}
    with open(out / "results.csv", newline="") as f:
        for line in csv.DictReader(f):
            row = rows[line["method"]]
            assert "f1" not in row  # no scoring.delta in the scenario
            assert float(line["f1"]) == pytest.approx(row["max_f1"])
            assert float(line["precision"]) == pytest.approx(row["precision_at_max_f1"])
            assert float(line["recall"]) == pytest.approx(row["recall_at_max_f1"])
            assert float(line["delta"]) == pytest.approx(row["delta_at_max_f1"])


def test_figures_label_colour_bars_and_keep_legends_off_the_data(tmp_path, monkeypatch):
    from vitaplace.engine.evaluation import evaluate as ev
    from vitaplace.engine.report import figures
    drawn = []
    monkeypatch.setattr(figures, "_save", lambda fig, stem, *formats: drawn.append(fig) or [])
    t = np.linspace(0, 2 * np.pi, 30)
    poses = np.c_[np.cos(t), np.sin(t), t]
    gtm = ev.ground_truth_matrix(poses, poses[::-1])
    tme = gtm + np.random.default_rng(0).random(gtm.shape)
    curve = ev.pr_curve(tme, gtm, 0.3)
    decisions = ev.decide(tme, gtm, 0.3, curve.delta_at_max_f1)
    figures.plot_matrices(tmp_path / "m", tme, gtm, decisions)
    figures.plot_pr_curves(tmp_path / "p", {"L": curve, "H": curve})
    figures.plot_trajectories(tmp_path / "t", poses, poses[::-1], decisions, arena={"width": 3, "depth": 3})
    figures.plot_energy(tmp_path / "e", {"visual.0": [3.0, 2.0], "joint": [1.0, 0.5]})
    for fig in drawn:
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()
        colour_bars = [ax for ax in fig.axes if hasattr(ax, "_colorbar")]
        data = [ax for ax in fig.axes if ax not in colour_bars]
        assert all(ax.get_ylabel() for ax in colour_bars)
        assert fig.legends and not any(ax.get_legend() for ax in data)
        for legend in fig.legends:
            box = legend.get_window_extent(renderer)
            assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes)
    assert sum(hasattr(ax, "_colorbar") for ax in drawn[0].axes) == 2


def test_pr_figures_of_a_study_keep_their_axes_legend_and_lines_readable(tmp_path, monkeypatch):
    """A study's report draws 14 methods x 2 directions = 28 PR curves in one figure, and its
    sweep 14 bands in one: the axes keep a readable size (at least 4 x 3 inches: no collapsed
    layout, no matplotlib warning), the legend of one line per curve covers none of them and
    lies whole inside the figure, and
    no curve is drawn thicker than 3 points or thinner than 1, however many there are."""
    import warnings

    from vitaplace.engine.evaluation import evaluate as ev
    from vitaplace.engine.report import figures
    drawn = []
    monkeypatch.setattr(figures, "_save", lambda fig, stem, *formats: drawn.append(fig) or [])
    t = np.linspace(0, 2 * np.pi, 30)
    poses = np.c_[np.cos(t), np.sin(t), t]
    gtm = ev.ground_truth_matrix(poses, poses[::-1])
    rng = np.random.default_rng(0)
    curves = [ev.pr_curve(gtm + rng.random(gtm.shape), gtm, 0.3) for _ in range(28)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures.plot_pr_curves(tmp_path / "p", {f"VLAD-F {i} reference-to-query": c for i, c in enumerate(curves)})
        figures.plot_pr_bands(tmp_path / "b", {f"VLAD-F {i}": curves[2 * i:2 * i + 2] for i in range(14)})
        for fig in drawn:
            fig.draw_without_rendering()
    for fig in drawn:
        renderer = fig.canvas.get_renderer()
        (ax,) = fig.axes
        box = ax.get_window_extent(renderer)
        assert box.width / fig.dpi >= 4 and box.height / fig.dpi >= 3
        for legend in fig.legends:  # off the data, and whole inside the figure
            extent = legend.get_window_extent(renderer)
            assert not extent.overlaps(box)
            assert fig.bbox.x0 <= extent.x0 and extent.x1 <= fig.bbox.x1
            assert fig.bbox.y0 <= extent.y0 and extent.y1 <= fig.bbox.y1
        widths = [line.get_linewidth() for line in ax.get_lines() if line.get_linestyle() != "None"]
        assert len(widths) in (28, 14) and 1.0 <= min(widths) and max(widths) <= 3.0


@pytest.mark.slow  # the runner's cache and recovery, not a dependency's version
def test_force_alone_redoes_every_stage_the_command_runs(tmp_path):
    path = str(write_scenario(tmp_path, valid_scenario()))
    out = tmp_path / "out"

    def statuses(*extra: str) -> set[str]:
        assert main(["-q", "simulate", path, "--out", str(out), *extra]) == 0
        return {r["status"] for r in json.loads((out / "manifest.json").read_text())["stages"]}

    assert statuses() == {"ran"}
    assert statuses() == {"cached"}
    assert statuses("--force") == {"ran"}
    assert statuses("--force", "all") == {"ran"}


def test_report_gives_the_distribution_of_test_time_inference_steps(quickstart_run):
    """MuPNet's features record each sample's inference steps and whether it stopped before
    the cap; the report's table is their median, 90th percentile, maximum, the share settled
    and the share under the thresholds (TINY: max_steps 20), recomputed here from the saved
    features."""
    from vitaplace.engine.extension.features import load_features

    out, _, _ = quickstart_run
    report = (out / "report.md").read_text()
    assert "## Test-time inference" in report
    for label in ("E1-query", "E1-reference"):
        (path,) = (out / "cache" / "features").glob(f"L-{label}-*.npz")
        features = load_features(path)
        steps, stopped = features["inference_steps"], features["inference_stopped"].astype(bool)
        assert steps.shape == (10,) and 1 <= steps.min() and steps.max() <= 20
        assert np.all(stopped | (steps == 20))  # a sample that did not stop ran to the cap
        # the paper's rule (no inference_rtol): settled means stopped under the thresholds
        row = (f"| L | {label.replace('-', '/')} | {np.median(steps):.0f} | {np.percentile(steps, 90):.0f} | "
               f"{steps.max()} | {100 * stopped.mean():.1f} | {100 * stopped.mean():.1f} |")
        assert row in report, row


# --------------------------------------------------------------------------- physical plausibility at validate

IMPLAUSIBLE = {
    "an infinite tactile range": (["methods.0.params.tactile_min_range=.inf"],
                                  "methods.0.params: extractor 'mupnet': tactile_min_range: "
                                  "Input should be a finite number"),
    "a negative whisker length": (["robot.whisker_lengths_mm=[50, -70, 100, 160]"],
                                  "robot.whisker_lengths_mm.1: Input should be greater than 0"),
    "a detour outside the arena": (["evaluations.0.query_off_route=0.3", "evaluations.0.run.off_route_offset=-3"],
                                   "evaluations.0.run.off_route_offset: -3 m off the path takes the robot"),
    "a 0.1 us timestep": (["robot.timestep=1e-7"], "robot.timestep: Input should be greater than or equal to 0.0001"),
    "an orbit beyond the arena": (["evaluations.0.run={kind: orbit, n_samples: 10, orbit_radius: 5}"],
                                  "evaluations.0.run.orbit_radius: an orbit of 5 m around (0, 0)"),
    "an orbit centre outside": (["evaluations.0.run={kind: orbit, n_samples: 10, orbit_centre: [9, 0]}"],
                                "evaluations.0.run.orbit_centre: (9, 0) is outside the 6.05 x 6.05 m arena"),
    "a start outside": (["train.run.start=[10, 0, 0]"], "train.run.start: (10, 0) puts the robot"),
    "a start in the wall": (["train.run.start=[2.9, 0, 0]"], "train.run.start: (2.9, 0) puts the robot"),
    "a start in a landmark": (["train.run.start=[2.138, 0, 0]"],
                              "train.run.start: (2.138, 0) is inside a landmark of 'e1'; expected free floor"),
    "a 0.001 Hz controller": (["train.run.control_hz=0.001"],
                              "train.run.control_hz: 0.001 Hz is below the whisking rate"),
}


@pytest.mark.parametrize("case", sorted(IMPLAUSIBLE))
def test_implausible_settings_are_refused_at_validate_naming_the_key(capsys, case):
    overrides, message = IMPLAUSIBLE[case]
    argv = ["validate", "quickstart"] + [a for o in overrides for a in ("--set", o)]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: ") and message in lines[0], lines


@pytest.mark.parametrize("kind", ["teleop", "route"])
def test_a_run_along_the_route_in_an_environment_without_one_is_refused_at_validate(tmp_path, capsys, kind):
    """Teleop drives and route runs follow the environment's loop: in an environment without
    one they are refused in one line naming the evaluation's key and the environment (a teleop
    evaluation used to pass validate and die in its simulation worker)."""
    (tmp_path / "open.yaml").write_text(f"extends: {SCENARIOS / 'environments' / 'e1.yaml'}\n"
                                        "name: e1-open\nroute: []\n")
    argv = ["validate", "quickstart", "--set", f"evaluations.0.environment={tmp_path / 'open.yaml'}",
            "--set", f"evaluations.0.run={{kind: {kind}, n_samples: 10}}"]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: "), lines
    assert f"evaluations.0.run.kind: a {kind} run needs the environment's route; 'e1-open' has none" in lines[0], lines


def test_settings_just_inside_the_arena_are_valid(capsys):
    """The arena of e1 is 6.05 m wide, the body's radius 0.23 m: 3.025 - 0.23 = 2.795 m is the
    farthest the base's centre can be from the middle."""
    ok = ["train.run.start=[2.79, 0, 0]", "evaluations.0.run={kind: orbit, n_samples: 10, orbit_radius: 2.79}",
          "train.run.control_hz=2"]
    assert main(["validate", "quickstart"] + [a for o in ok for a in ("--set", o)]) == 0
    assert main(["validate", "quickstart", "--set", "train.run.start=[2.8, 0, 0]"]) == 2


def test_a_long_simulation_is_announced_with_an_estimate(capsys):
    """0.1 ms steps at 2 Hz whisking: 5000 steps per sample. Estimate: (samples + warm-up
    cycle) x steps x 25 us + samples x 1 ms; train 5000 samples, two evaluation runs of 450."""
    from vitaplace.engine.sim.plausibility import duration

    seconds = (5001 * 5000 * 25e-6 + 5000 * 1e-3) + 2 * (451 * 5000 * 25e-6 + 450 * 1e-3)
    assert duration(seconds) == "12 min"  # 743.8 s
    assert main(["validate", "quickstart", "--set", "robot.timestep=1e-4", "--set", "train.run.n_samples=5000"]) == 0
    assert "simulating its runs takes about 12 min on one core (estimate)" in capsys.readouterr().out
    assert main(["validate", "quickstart"]) == 0
    assert "estimate" not in capsys.readouterr().out


def test_a_long_simulation_in_a_worker_logs_its_progress(monkeypatch, caplog):
    """While a worker simulates a run estimated to take long, a line each tenth of the estimate."""
    import threading
    from concurrent.futures import Future

    from vitaplace.engine.pipeline import simulation

    monkeypatch.setattr(simulation, "LONG_SECONDS", 0.1)
    future: Future = Future()
    threading.Timer(0.35, future.set_result, ((10, 1.0),)).start()
    job = simulation.SimulationJob("train", "e1", {}, {}, 0, "key", Path("unused.h5"), estimate=1.0)
    with caplog.at_level("INFO", logger="vitaplace"):
        assert simulation._await(future, job) == (10, 1.0)
    lines = [r.getMessage() for r in caplog.records if "of an estimated 1 s" in r.getMessage()]
    assert 2 <= len(lines) <= 4, lines


@pytest.mark.parametrize("workers", ["-1", "0"])
def test_bad_worker_counts_are_one_line(tmp_path, capsys, workers):
    assert main(["sweep", "quickstart", "--workers", workers, "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [f"vitaplace: error: --workers {workers}: expected a number of worker processes, at least 1"]


def test_ctrl_c_before_the_command_starts_is_one_line(capsys, monkeypatch):
    """A Ctrl-C while the arguments are parsed (or anything before the command runs)."""
    import vitaplace.engine.cli.main as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["validate", "quickstart"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        "vitaplace: interrupted; finished stages are cached, run again to resume"]


@pytest.mark.parametrize("setting, expected", [
    # kv = 2 zeta sqrt(kp I) overflows: the servo's gain kp / |kp - I w^2 + i kv w| is 0
    pytest.param("servo_damping_ratio=1e308", r"robot: servo_kp 10, servo_damping_ratio 1e\+308 .* a gain of 0 at "
                 r"whisk_hz 2", id="damping"),
    pytest.param("servo_armature=1e308", r"robot: .*servo_armature 1e\+308 leave the protraction servo a gain of 0",
                 id="armature"),
    # gain ~ kp / (I w^2) ~ 1e-299: a command of ~1e299 rad, past MuJoCo's 1e10 on any control
    pytest.param("servo_kp=1e-300", r"robot: servo_kp 1e-300, .* beyond MuJoCo's bound of 1e\+10 rad", id="kp"),
    # the base's pose servo gain m (2 pi 10 Hz)^2 overflows
    pytest.param("base_mass=1e308", r"robot: base_mass 1e\+308 kg and base_servo_hz 10 give the base's pose servo an "
                 "infinite gain", id="base_mass"),
])
def test_a_robot_the_simulator_cannot_drive_is_one_line(tmp_path, setting, expected):
    """Settings inside every key's own range whose servo gains overflow: one line naming the
    robot's keys, not a ZeroDivisionError or a MuJoCo warning per physics step."""
    import re

    path = write_scenario(tmp_path, valid_scenario())
    result = run_cli(["-q", "simulate", str(path), "--out", str(tmp_path / "out"), "--set", f"robot.{setting}"])
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-800:]
    assert re.search(expected, lines[0]), lines[0]


def finished_folders(tmp_path: Path) -> None:
    """RUN, a finished run's folder (its completion record over its resolved scenario), and
    SWEEP, a sweep's (its summary), as `vitaplace.engine.outputs.completion.holder` reads them."""
    from vitaplace.engine.outputs import completion

    (tmp_path / "RUN").mkdir()
    (tmp_path / "RUN" / completion.SCENARIO).write_text("name: t\n")
    completion.write(tmp_path / "RUN", [])
    (tmp_path / "SWEEP").mkdir()
    (tmp_path / "SWEEP" / "sweep.json").write_text("{}")


def test_simulate_an_environment_replaces_its_run_file_only_when_asked(tmp_path, capsys):
    """`simulate e1 --samples 2` then `--samples 3` into one folder replaced the first run file
    without a word (its name does not say its samples, and a scenario's `dataset:` may read
    it); `--replace` asks for that. A scenario's runs are not files of its own: refused there."""
    import h5py

    argv = ["simulate", "e1", "--no-progress", "--out", str(tmp_path)]
    path = tmp_path / "e1-foraging-seed0.h5"
    assert main([*argv, "--samples", "2"]) == 0
    before = path.read_bytes()
    capsys.readouterr()
    assert main([*argv, "--samples", "3"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vitaplace: error: --out {tmp_path}: already holds {path.name}")
    assert "--replace" in lines[0] and path.read_bytes() == before
    assert main([*argv, "--samples", "3", "--replace"]) == 0
    with h5py.File(path) as f:
        assert len(f["theta"]) == 3
    capsys.readouterr()
    scenario = str(write_scenario(tmp_path, valid_scenario()))
    assert main(["simulate", scenario, "--replace", "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: --replace applies to "), lines


@pytest.mark.parametrize("options", [["--samples", "5"], ["--seed", "7"], ["--samples", "5", "--seed", "0"]])
def test_simulate_a_scenario_refuses_the_environment_files_options(tmp_path, capsys, options):
    """--samples and --seed set `vitaplace simulate ENV.yaml`'s run; a scenario's runs would
    silently keep the scenario's: refused in one line naming them, before anything is written."""
    scenario = str(write_scenario(tmp_path, valid_scenario()))
    assert main(["simulate", scenario, *options, "--out", str(tmp_path / "out")]) == 2
    named = " and ".join(option for option in ("--samples", "--seed") if option in options)
    assert capsys.readouterr().err.strip().splitlines() == [
        f"vitaplace: error: {named} apply to `vitaplace simulate ENV.yaml`; a scenario's runs take theirs from the "
        "scenario (e.g. --set train.run.n_samples=N --set seed=S)"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv, expected", [
    pytest.param(["--samples", "0"], "--samples 0: expected a number of samples, at least 1", id="0"),  # was 200
    pytest.param(["--samples", "-3"], "--samples -3: expected a number of samples, at least 1", id="-3"),
    pytest.param(["--seed", "-1"], "--seed -1: expected a whole number >= 0", id="seed"),
    pytest.param(["--samples", "10000000000"], "--samples 10000000000: 10000000000 samples of 120x160 frames need ",
                 id="memory"),
    pytest.param(["--out", "FILE"], "--out FILE: exists and is not a directory", id="file"),
    pytest.param(["--out", "FOLDER"], "FOLDER/e1-foraging-seed0.h5: is a folder; expected the run file to write there",
                 id="folder"),
    # a scenario's seed is below 2**32 = 4294967296, and the run's seed is one
    pytest.param(["--seed", "4294967296"], "--seed 4294967296: expected a whole number >= 0 and < 4294967296",
                 id="seed bound"),
    pytest.param(["--out", "RUN"], "--out RUN: holds the finished output of a run of a scenario's stages",
                 id="run folder"),
    pytest.param(["--out", "SWEEP"], "--out SWEEP: holds the finished output of the summary of `vitaplace sweep`",
                 id="sweep folder"),
    pytest.param(["--out", "DONE"], "--out DONE: already holds e1-foraging-seed0.h5", id="existing run file"),
])
def test_simulate_an_environment_refuses_bad_options_before_simulating(tmp_path, capsys, monkeypatch, argv,
                                                                          expected):
    from vitaplace.engine.sim import simulate

    def never(*args, **kwargs):
        raise AssertionError("simulated before the options were checked")

    monkeypatch.setattr(simulate, "simulate_run", never)
    (tmp_path / "FILE").write_text("x")
    (tmp_path / "FOLDER" / "e1-foraging-seed0.h5").mkdir(parents=True)
    finished_folders(tmp_path)
    (tmp_path / "DONE").mkdir()
    (tmp_path / "DONE" / "e1-foraging-seed0.h5").write_text("an earlier run")
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "e1", "--no-progress", *argv]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vitaplace: error: {expected}"), lines


@pytest.mark.parametrize("key", ["train.dataset", "train.environment"])
def test_a_folder_where_a_file_is_expected_is_named_as_a_folder(tmp_path, capsys, key):
    data = valid_scenario()
    if key == "train.dataset":
        data["train"] = {"dataset": str(tmp_path)}
    else:
        data["train"]["environment"] = str(tmp_path)
    assert main(["validate", str(write_scenario(tmp_path, data))]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{key}: '{tmp_path}' is a folder; expected a file" in lines[0], lines


def _undecodable_texture_world(tmp_path: Path) -> Path:
    """E1 with a wall texture whose PNG header is whole (validate reads no further) but whose
    IHDR chunk's CRC is wrong: MuJoCo refuses to decode it when it compiles the model."""
    import struct

    header = b"IHDR" + struct.pack(">IIBBBBB", 4, 2, 8, 2, 0, 0, 0)
    (tmp_path / "crc.png").write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + header + b"\0\0\0\0")
    world = tmp_path / "crc.yaml"
    world.write_text("extends: e1\nmaterials: {wall: {texture: {file: crc.png}}}\n")
    return world


#: the start of the line a model MuJoCo cannot compile ends in (MuJoCo's two lines in one)
UNCOMPILED = ("environment 'crc': MuJoCo could not compile the model: Error: error decoding PNG file "
              "'{}': invalid CRC")


def test_a_model_mujoco_cannot_compile_ends_simulate_in_one_line(tmp_path, capsys):
    world = _undecodable_texture_world(tmp_path)
    assert main(["validate", str(world)]) == 0
    capsys.readouterr()
    assert main(["simulate", str(world), "--samples", "2", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    expected = "vitaplace: error: " + UNCOMPILED.format(tmp_path / "crc.png")
    assert len(lines) == 1 and lines[0].startswith(expected), lines


def test_a_model_mujoco_cannot_compile_is_a_user_error_from_a_worker_process(tmp_path):
    """The same error raised in a worker of `vitaplace run`'s pool comes back as the one-line
    kind (`UserError`), not as a traceback of the worker's."""
    from vitaplace.engine.base.errors import UserError
    from vitaplace.engine.pipeline.simulation import SimulationJob, simulations_in_workers

    world = str(_undecodable_texture_world(tmp_path))
    run = {"kind": "foraging", "n_samples": 2}
    jobs = [SimulationJob(label, world, run, {}, 0, label, tmp_path / f"{label}.h5", 1.0) for label in ("a", "b")]
    with simulations_in_workers(jobs, 2) as waits:
        assert set(waits) == {"a", "b"}  # on the workers, not in this process
        with pytest.raises(UserError) as caught:
            waits["a"]()
    assert str(caught.value).startswith(UNCOMPILED.format(tmp_path / "crc.png")), str(caught.value)
    assert "\n" not in str(caught.value)


def test_an_error_quoting_a_line_break_stays_one_line(tmp_path, capsys):
    """A file name (or any value an error quotes) with a line break, a tab or an escape: the
    error line writes them as Python writes them in a string."""
    from vitaplace.engine.cli.main import one_line

    assert one_line("a\nb\tc\x1b ü") == "a\\nb\\tc\\x1b ü"
    path = write_scenario(tmp_path, valid_scenario(), name="two\nlines.yaml")
    assert main(["validate", str(path), "--set", "seed=-1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [f"vitaplace: error: {tmp_path}/two\\nlines.yaml: seed: Input should be greater than or equal "
                     "to 0 (got -1)"]


def test_f1_at_the_training_threshold_is_undefined_where_the_training_world_has_no_revisit(tmp_path):
    """A training world's evaluation with no query that has a true match has no F1-maximising
    threshold (its max F1 is 0 by convention): the other worlds' F1 at it is null, not the 0
    of accepting nothing, so that a summary leaves it out instead of averaging a 0."""
    path = write_scenario(tmp_path, {
        "name": "tiny", "seed": 0, "train": {"environment": "e1", "run": {"kind": "foraging", "n_samples": 20}},
        "evaluations": [{"name": "E1", "environment": "e1", "run": {"kind": "teleop", "n_samples": 12}},
                        {"name": "E2", "environment": "e2", "run": {"kind": "route", "n_samples": 20}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}], "scoring": {"tau": 0.3, "recall_k": [1, 5]},
        "report": {"figures": "none"}})
    out = tmp_path / "out"
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress"]) == 0
    rows = {row["environment"]: row for row in json.loads((out / "results.json").read_text())}
    assert rows["E1"]["n_revisit"] == 0 and rows["E2"]["n_revisit"] > 0 and rows["E2"]["max_f1"] > 0
    assert [(rows[e]["f1_at_e1_threshold"], rows[e]["e1_threshold"]) for e in ("E1", "E2")] == [(None, None)] * 2


@pytest.mark.parametrize("out", ["proj", ""])
def test_a_folder_vitaplace_did_not_write_is_refused_untouched(tmp_path, monkeypatch, capsys, out):
    """A run prunes the result folders (training/, poses/, figures/ ...) it finds in --out: a
    folder that holds files but no claim of vitaplace's (``.vitaplace.lock``), such as a
    project folder, or the current one through an empty --out, is refused in one line and
    left as it was."""
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / (out or ".")
    mine = {folder / "training" / "train_model.py": "print(1)", folder / "sub" / ".big.iso.part": "p"}
    for path, text in mine.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    assert main(["-q", "run", "quickstart", "--out", out, *sum((["--set", o] for o in TINY), [])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"vitaplace: error: --out {out or '.'}: not empty and not a folder vitaplace wrote (no "
                   ".vitaplace.lock); expected a new or empty folder, or one a vitaplace command wrote"]
    assert {path: path.read_text() for path in mine} == mine
    assert sorted(p.name for p in folder.iterdir()) == ["sub", "training"]


def test_a_path_the_system_refuses_is_one_line(tmp_path, monkeypatch, capsys):
    """An --out name longer than the file system allows (255 bytes a name): the system's
    refusal in one line naming the path, exit 2, not a traceback."""
    monkeypatch.chdir(tmp_path)
    name = "x" * 300
    assert main(["-q", "run", "quickstart", "--out", name]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"vitaplace: error: {name}: File name too long"]


def test_a_run_of_another_scenario_says_it_replaces_the_folders_results(tmp_path, capsys):
    """One set of results per folder: a run of another scenario replaces the results there,
    and says so in one warning naming both scenarios; a run of the same one says nothing."""
    scenario = {"name": "first", "seed": 0, "train": {"environment": "e1", "run": {"kind": "foraging", "n_samples": 8}},
                "evaluations": [{"name": "E1", "environment": "e1", "run": {"kind": "route", "n_samples": 6}}],
                "methods": [{"name": "H", "plugin": "handcrafted"}], "scoring": {"recall_k": [1]},
                "report": {"figures": "none"}}
    out = tmp_path / "out"
    first = write_scenario(tmp_path, scenario, "first.yaml")
    assert main(["-q", "run", str(first), "--out", str(out), "--no-progress"]) == 0
    assert main(["-q", "run", str(first), "--out", str(out), "--no-progress"]) == 0
    assert "replaces them" not in capsys.readouterr().err
    second = write_scenario(tmp_path, {**scenario, "name": "second"}, "second.yaml")
    assert main(["-q", "run", str(second), "--out", str(out), "--no-progress"]) == 0
    assert f"{out} holds the results of scenario 'first': this run of 'second' replaces them" in capsys.readouterr().err


@pytest.mark.parametrize("command", [["aggregate", "run-a", "run-b"], ["sensitivity", "run-a"]])
def test_aggregate_and_sensitivity_refuse_a_folder_vitaplace_did_not_write(tmp_path, monkeypatch, capsys, command):
    """They write without a claim, into --out: a non-empty folder with neither the claim nor
    their own summary (a project folder holding a sweep.md of the user's) is refused untouched."""
    monkeypatch.chdir(tmp_path)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "sweep.md").write_text("my notes")
    assert main([*command, "--out", str(mine)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"vitaplace: error: --out {mine}: not empty and not a folder vitaplace wrote (no .vitaplace.lock); expected "
        "a new or empty folder, or one a vitaplace command wrote"]
    assert [p.name for p in mine.iterdir()] == ["sweep.md"] and (mine / "sweep.md").read_text() == "my notes"
