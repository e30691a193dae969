"""The Python API: `import vitaplace` has a version, docs/API.md's example runs as written,
a script without a `__main__` guard still runs (in one process) instead of breaking the pool,
and every public function's bad arguments are one-line `UserError`s naming the argument and
what was expected, with the nearest valid name for a misspelt one."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

import vitaplace

ROOT = Path(__file__).resolve().parents[2]


def _python(script: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, str(script)], cwd=cwd, capture_output=True, text=True, timeout=600, env=env)


def test_version_is_the_installed_distributions():
    assert vitaplace.__version__ == version("vitaplace")
    result = subprocess.run([sys.executable, "-c", "import vitaplace; print(vitaplace.__version__)"],
                            capture_output=True, text=True, cwd="/")
    assert result.returncode == 0 and result.stdout.strip() == version("vitaplace")


def test_every_public_name_is_documented():
    doc = (ROOT / "docs" / "API.md").read_text()
    missing = [name for name in vitaplace.__all__ if not re.search(rf"`(vitaplace\.)?{name}\b", doc)]
    assert not missing, missing
    own = [getattr(vitaplace, name) for name in vitaplace.__all__
           if getattr(getattr(vitaplace, name), "__module__", "") == "vitaplace"]
    undocumented = [f.__name__ for f in own if not f.__doc__]
    assert len(own) == 7  # extractors, fit_extractor, load_scenario, read_results, run, simulate, unguarded_script
    assert not undocumented, undocumented


def test_read_results_of_a_folder_without_results_is_one_line(tmp_path):
    with pytest.raises(vitaplace.UserError, match=r"results\.json: no results here"):
        vitaplace.read_results(tmp_path)


ENV_E1 = ROOT / "scenarios" / "environments" / "e1.yaml"
TINY = {
    "name": "tiny",
    "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
    "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
    "methods": [{"name": "H", "plugin": "handcrafted"}],
}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> tuple[Path, Path, list]:
    """(scenario file, output folder, the rows `run` returned) of a tiny run up to the evaluate stage."""
    import yaml

    tmp = tmp_path_factory.mktemp("api")
    scenario = tmp / "tiny.yaml"
    scenario.write_text(yaml.safe_dump(TINY))
    out = tmp / "run"
    return scenario, out, vitaplace.run(scenario, out=out, until="evaluate", workers=1)


def test_read_results_gives_the_rows_of_a_finished_folder(finished):
    _, out, rows = finished
    assert rows and vitaplace.read_results(out) == rows


def test_read_results_refuses_a_folder_whose_rerun_was_killed(finished, tmp_path, monkeypatch):
    """A rerun with another tau killed while it simulates has not touched the folder: its
    results are still read. Killed once it replaces them (at the evaluate stage), it leaves
    the old results.json beside the new scenario.resolved.yaml and no completed.json:
    read_results refuses, as aggregate does."""
    import shutil

    from vitaplace.engine.pipeline import orchestrate

    scenario, out, rows = finished
    folder = tmp_path / "run"
    shutil.copytree(out, folder)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(orchestrate, "simulate", killed)
    with pytest.raises(KeyboardInterrupt):
        vitaplace.run(scenario, {"scoring.tau": 0.4}, out=folder, workers=1)
    assert vitaplace.read_results(folder) == rows
    monkeypatch.undo()
    monkeypatch.setattr(orchestrate, "evaluate", killed)
    with pytest.raises(KeyboardInterrupt):
        vitaplace.run(scenario, {"scoring.tau": 0.4}, out=folder, workers=1)
    assert (folder / "results.json").is_file()  # the old run's
    with pytest.raises(vitaplace.UserError, match=r"incomplete run folder \(no completed\.json\)"):
        vitaplace.read_results(folder)


def test_read_results_of_a_damaged_results_file_is_one_line(finished, tmp_path):
    import shutil

    from conftest import reseal

    _, out, _ = finished
    folder = tmp_path / "run"
    shutil.copytree(out, folder)
    path = folder / "results.json"
    path.write_bytes(path.read_bytes()[:40])
    with pytest.raises(vitaplace.UserError, match=r"results\.json is not the file its finished run recorded"):
        vitaplace.read_results(folder)
    reseal(folder)  # as if the run itself had written it truncated
    with pytest.raises(vitaplace.UserError, match=r"results\.json: unreadable \(JSONDecodeError"):
        vitaplace.read_results(folder)


def _numpy_and_paths():
    import numpy as np

    return {"seed": np.int64(7), "scoring.recall_k": np.array([1, 5]), "name": Path("named")}


def test_numpy_values_and_paths_in_overrides_are_their_plain_values():
    scenario = vitaplace.load_scenario("quickstart", _numpy_and_paths())
    assert (scenario.seed, scenario.scoring.recall_k, scenario.name) == (7, [1, 5], "named")


def _tiny_run():
    return vitaplace.simulate("e1", n_samples=3)


#: function -> {case: (call, the one line it raises, as a regular expression)}; every public
#: function of the API has its cases (`test_every_public_function_has_one_line_errors`)
BAD_CALLS = {
    "load_scenario": {
        "a set value": (lambda: vitaplace.load_scenario("quickstart", {"scoring.recall_k": {1, 5}}),
                        r"overrides\['scoring\.recall_k'\]: set values have no YAML form"),
        "an object value": (lambda: vitaplace.load_scenario("quickstart", {"seed": object()}),
                            r"overrides\['seed'\]: object values have no YAML form"),
        "overrides a number": (lambda: vitaplace.load_scenario("quickstart", 5), r"overrides: 5: expected a mapping"),
        "a key that is not text": (lambda: vitaplace.load_scenario("quickstart", {1: 2}), r"overrides: keys \[1\]"),
        "a scenario that is no path": (lambda: vitaplace.load_scenario(5), r"scenario=5: expected a path"),
        "a misspelt scenario": (lambda: vitaplace.load_scenario("quickstrat"),
                                r"^quickstrat: no such scenario file \(shipped scenarios: .*paper, .*quickstart.*; "
                                r"did you mean 'quickstart'\?\)$"),
        "a misspelt scenario key": (lambda: vitaplace.load_scenario("quickstart", {"scoring.tua": 0.3}),
                                    r"quickstart\.yaml: scoring\.tua: unknown key; "
                                    r"did you mean 'tau'\? \(valid keys: .*\)$"),
        "a misspelt run kind": (lambda: vitaplace.load_scenario("quickstart", {"train.run.kind": "foragin"}),
                                r"quickstart\.yaml: train\.run\.kind: expected one of foraging, visits, teleop, "
                                r"stations, route, orbit, got 'foragin'; did you mean 'foraging'\?$"),
        "a misspelt plugin parameter": (lambda: vitaplace.load_scenario("quickstart", {"methods.0.params.epoch": 3}),
                                        r"quickstart\.yaml: methods\.0\.params: extractor 'mupnet': epoch: "
                                        r"unknown key; did you mean 'epochs'\? \(valid keys: .*\bepochs\b.*\)$"),
        "a misspelt plugin": (lambda: vitaplace.load_scenario("quickstart", {"methods.0.plugin": "mupent"}),
                              r"methods\.0\.plugin: unknown feature extractor 'mupent'; available: .*; "
                              r"did you mean 'mupnet'\?$"),
        "a misspelt world": (lambda: vitaplace.load_scenario("quickstart", {"train.environment": "e22"}),
                             r"train\.environment: no such file .*e22.* \(shipped environments: .*\be1\b.*\be3\b.*; "
                             r"did you mean 'e2'\?\)$"),
        "a misspelt keyword": (lambda: vitaplace.load_scenario("quickstart", overides={}),
                               r"^vitaplace\.load_scenario\(\): unknown argument 'overides'; "
                               r"did you mean 'overrides'\? \(its arguments: scenario, overrides\)$"),
    },
    "run": {
        "force past until": (lambda: vitaplace.run("quickstart", out="unused", until="fit", force=["report"]),
                             r"^force=\['report'\]: report comes after until='fit', which stops before it; "
                             r"expected stages up to until$"),
        "overrides a list of numbers": (lambda: vitaplace.run("quickstart", [1, 2]), r"overrides: \[1, 2\]: expected"),
        "workers as text": (lambda: vitaplace.run("quickstart", workers="2"),
                            r"workers='2': expected a whole number >= 1"),
        "no workers": (lambda: vitaplace.run("quickstart", workers=0), r"workers=0: expected a whole number >= 1"),
        "run's scenario no path": (lambda: vitaplace.run(["quickstart"]),
                                   r"scenario=\['quickstart'\]: expected a path"),
        "a misspelt until": (lambda: vitaplace.run("quickstart", until="evalute"),
                             r"^until='evalute': expected one of simulate, fit, transform, evaluate, report; "
                             r"did you mean 'evaluate'\?$"),
        "a misspelt stage to force": (lambda: vitaplace.run("quickstart", force=["fit", "simlate"]),
                                      r"^force=\['fit', 'simlate'\]: 'simlate' is not a stage; "
                                      r"expected some of simulate, fit, transform, evaluate, report; "
                                      r"did you mean 'simulate'\?$"),
        "force a number": (lambda: vitaplace.run("quickstart", force=3), r"^force=3: expected stage names"),
        "progress as text": (lambda: vitaplace.run("quickstart", progress="yes"),
                             r"^progress='yes': expected True or False$"),
        "a misspelt keyword": (lambda: vitaplace.run("quickstart", unitl="evaluate"),
                               r"^vitaplace\.run\(\): unknown argument 'unitl'; did you mean 'until'\? "
                               r"\(its arguments: scenario, overrides, out, until, force, progress, workers\)$"),
        "no scenario": (lambda: vitaplace.run(), r"^vitaplace\.run\(\): missing a required argument: 'scenario'"),
        "out a file": (lambda: vitaplace.run("quickstart", out=__file__),  # named as the API names it
                       r"^out .*test_api\.py: exists and is not a directory$"),
        "out a folder of other files": (lambda: vitaplace.run("quickstart", out=Path(__file__).parent),
                                        r"^out .*pipeline: not empty and not a folder vitaplace wrote"),
    },
    "read_results": {
        "out no path": (lambda: vitaplace.read_results(3), r"out=3: expected a path"),
        "a misspelt keyword": (lambda: vitaplace.read_results(folder="runs/q"),
                               r"^vitaplace\.read_results\(\): unknown argument 'folder' \(its arguments: out\)$"),
    },
    "simulate": {
        "an unknown kind": (lambda: vitaplace.simulate("e1", kind="teleport"),
                            r"^kind='teleport': expected one of foraging, visits, teleop, stations, route, orbit; "
                            r"did you mean 'teleop'\?$"),
        "no samples": (lambda: vitaplace.simulate("e1", n_samples=0), r"^n_samples=0: expected a whole number >= 1$"),
        "samples as text": (lambda: vitaplace.simulate("e1", n_samples="many"),
                            r"^n_samples='many': expected a whole number >= 1$"),
        "an unknown run setting": (lambda: vitaplace.simulate("e1", wobble=3),
                                   r"^vitaplace\.simulate\(\): wobble: unknown key \(valid keys: .*\bspeed\b.*\)$"),
        "a misspelt run setting": (lambda: vitaplace.simulate("e1", kind="route", lateral_nosie=0.1),
                                   r"^vitaplace\.simulate\(\): lateral_nosie: unknown key; "
                                   r"did you mean 'lateral_noise'\?"),
        "a negative seed": (lambda: vitaplace.simulate("e1", seed=-1), r"seed=-1: expected a whole number >= 0"),
        "a seed past a scenario's": (lambda: vitaplace.simulate("e1", seed=2**64),
                                     r"^seed=18446744073709551616: expected a whole number >= 0 and < 4294967296$"),
        "an environment that is no path": (lambda: vitaplace.simulate(3), r"environment=3: expected a path"),
        "an unknown world": (lambda: vitaplace.simulate("e9", n_samples=2),
                             r"^e9: no such environment file \(shipped environments: .*\be1\b.*\be2\b.*\be3\b[^;]*\)$"),
        "a misspelt world": (lambda: vitaplace.simulate("e2x", n_samples=2),
                             r"^e2x: no such environment file \(shipped environments: .*; did you mean 'e2'\?\)$"),
        "progress as a number": (lambda: vitaplace.simulate("e1", progress=2), r"^progress=2: expected True or False$"),
        "too many arguments": (lambda: vitaplace.simulate("e1", "route", 3, 0, False, 7),
                               r"^vitaplace\.simulate\(\): too many positional arguments \(its arguments: environment, "
                               r"kind, n_samples, seed, progress, \*\*run_settings\)$"),
    },
    "extractors": {
        "an argument": (lambda: vitaplace.extractors("mupnet"),
                        r"^vitaplace\.extractors\(\): too many positional arguments \(its arguments: none\)$"),
    },
    "fit_extractor": {
        "fit on a path": (lambda: vitaplace.fit_extractor("handcrafted", "runs/train.h5"),
                          r"train='runs/train\.h5': expected a Run"),
        "a plugin that is no name": (lambda: vitaplace.fit_extractor(3, None),
                                     r"^plugin=3: expected the name of an extractor, one of .*handcrafted"),
        "a misspelt plugin": (lambda: vitaplace.fit_extractor("handcraftd", _tiny_run()),
                              r"^unknown feature extractor 'handcraftd'; available: .*; did you mean 'handcrafted'\?$"),
        "a misspelt plugin parameter": (lambda: vitaplace.fit_extractor("handcrafted", _tiny_run(), {"gird": [4, 8]}),
                                        r"^extractor 'handcrafted': gird: unknown key; "
                                        r"did you mean 'grid'\? \(valid keys: .*\bgrid\b.*\)$"),
        "a run of no samples": (lambda: vitaplace.fit_extractor("handcrafted", _tiny_run().subset([])),
                                r"^train: run '.*' has no samples; expected a run to fit on$"),
        "params a list": (lambda: vitaplace.fit_extractor("handcrafted", _tiny_run(), [4, 8]),
                          r"^params=\[4, 8\]: expected a mapping"),
        "a misspelt keyword": (lambda: vitaplace.fit_extractor("handcrafted", _tiny_run(), progres=True),
                               r"^vitaplace\.fit_extractor\(\): unknown argument 'progres'; did you mean 'progress'\?"),
    },
    "unguarded_script": {
        "an argument": (lambda: vitaplace.unguarded_script(__file__),
                        r"^vitaplace\.unguarded_script\(\): too many positional arguments \(its arguments: none\)$"),
    },
}


@pytest.mark.parametrize("function,case", [(f, c) for f in BAD_CALLS for c in sorted(BAD_CALLS[f])])
def test_bad_arguments_are_one_line_user_errors(function, case):
    call, message = BAD_CALLS[function][case]
    with pytest.raises(vitaplace.UserError, match=message) as info:
        call()
    assert "\n" not in str(info.value)


def test_a_folder_holding_another_commands_output_is_named_as_the_api_names_it(tmp_path):
    """A sweep's summary folder given as ``out``: refused before anything runs, naming ``out``
    (the command line's ``--out`` was named)."""
    (tmp_path / ".vitaplace.lock").write_text("")
    (tmp_path / "sweep.json").write_text("{}")
    with pytest.raises(vitaplace.UserError, match=rf"^out {re.escape(str(tmp_path))}: holds the finished output of "
                                                  r".*; choose another out$"):
        vitaplace.run("quickstart", out=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".vitaplace.lock", "sweep.json"]


@pytest.mark.parametrize("path", [5, None, 2.5])
def test_open_run_of_something_that_is_no_path_is_one_line(path):
    with pytest.raises(vitaplace.UserError, match=r"^path=.*: expected the path of a run file \(text or a Path\)$"):
        vitaplace.open_run(path)


def test_every_public_function_has_one_line_errors():
    functions = {name for name in vitaplace.__all__ if callable(getattr(vitaplace, name))
                 and getattr(getattr(vitaplace, name), "__module__", "") == "vitaplace"}
    assert functions == set(BAD_CALLS)


def test_force_takes_one_stage_name_or_several(finished, tmp_path):
    """``force="simulate"`` is that stage (not its letters); a forced stage is redone."""
    import shutil

    scenario, out, _ = finished
    folder = tmp_path / "run"
    shutil.copytree(out / "cache", folder / "cache")  # the cache alone: no later stage's output to carry on to
    shutil.copy(out / ".vitaplace.lock", folder)  # a folder vitaplace wrote
    runs = sorted((folder / "cache" / "datasets").glob("*.h5"))
    before = [path.stat().st_mtime_ns for path in runs]
    assert vitaplace.run(scenario, out=folder, until="simulate", force="simulate", workers=1) == []
    assert [path.stat().st_mtime_ns for path in runs] != before
    assert vitaplace.run(scenario, out=folder, until="simulate", force=("simulate",), workers=1) == []


def test_overrides_as_a_mapping_or_as_set_strings_mean_the_same():
    as_mapping = vitaplace.load_scenario("quickstart", {"seed": 7, "methods.1.params": {"grid": [4, 8]}})
    as_strings = vitaplace.load_scenario("quickstart", ["seed=7", "methods.1.params={grid: [4, 8]}"])
    assert as_mapping == as_strings and as_mapping.seed == 7 and as_mapping.methods[1].params == {"grid": [4, 8]}
    assert vitaplace.load_scenario("quickstart", {"scoring.delta": 0.5, "seed": 1}).scoring.delta == 0.5
    assert vitaplace.load_scenario("quickstart", {"scoring.delta": None}).scoring.delta is None  # not "None"
    with pytest.raises(vitaplace.UserError, match=r"scoring\.tau"):
        vitaplace.load_scenario("quickstart", {"scoring.tau": -1})
    with pytest.raises(vitaplace.UserError, match="until='plot'"):
        vitaplace.run("quickstart", until="plot")


def test_an_overridden_environment_is_a_shipped_name_or_a_path_from_the_working_folder(tmp_path, monkeypatch):
    from vitaplace.engine.base.shipped import shipped_file

    shipped = shipped_file("e2")
    assert shipped is not None and shipped.name == "e2.yaml"
    assert vitaplace.load_scenario("quickstart", {"train.environment": "e2"}).train.environment == shipped.resolve()
    (tmp_path / "mine.yaml").write_text(shipped.read_text())
    monkeypatch.chdir(tmp_path)
    scenario = vitaplace.load_scenario("quickstart", {"evaluations.0.environment": "mine.yaml"})
    assert scenario.evaluations[0].environment == (tmp_path / "mine.yaml").resolve()
    assert scenario.train.environment == shipped_file("e1").resolve()  # the scenario file's own


@pytest.mark.slow
def test_the_documented_example_runs_as_written(tmp_path):
    doc = (ROOT / "docs" / "API.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, flags=re.S)
    script = tmp_path / "example.py"
    script.write_text(blocks[0])
    result = _python(script, tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"vitaplace {version('vitaplace')} extractors: autoencoder, handcrafted, hog, mupnet, vlad" in result.stdout
    assert re.search(r"^E1 H max F1 [01]\.\d{3} AUC [01]\.\d{3}$", result.stdout, flags=re.M), result.stdout
    assert re.search(r"train-\w+\.h5: 12 samples", result.stdout)
    assert "outside `if __name__" not in result.stderr


def _detect(tmp_path: Path, body: str) -> str:
    """What `unguarded_script` says when called as ``body`` places it."""
    script = tmp_path / "probe.py"
    script.write_text("import vitaplace\n\ndef where():\n    return vitaplace.unguarded_script()\n\n"
                      + textwrap.dedent(body))
    result = _python(script, tmp_path)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip()


@pytest.mark.parametrize(
    "body, unguarded",
    [
        ("print(where())\n", True),
        ("def main():\n    print(where())\n\nmain()\n", True),
        ("if __name__ == '__main__':\n    print(where())\n", False),
        ("if '__main__' == __name__:\n    def main():\n        print(where())\n    main()\n", False),
        ("if True:\n    print(where())\n", True),
    ],
)
def test_a_call_from_a_scripts_top_level_outside_the_guard_is_detected(tmp_path, body, unguarded):
    assert _detect(tmp_path, body) == (str(tmp_path / "probe.py") if unguarded else "None")


def test_no_script_means_no_guard_needed():
    result = subprocess.run([sys.executable, "-c", "import vitaplace; print(vitaplace.unguarded_script())"],
                            capture_output=True, text=True)
    assert result.stdout.strip() == "None"


@pytest.mark.slow
def test_a_script_without_a_guard_runs_in_one_process_instead_of_breaking_the_pool(tmp_path):
    script = tmp_path / "unguarded.py"
    script.write_text(textwrap.dedent("""
        import logging
        import vitaplace

        logging.basicConfig(level="INFO", format="%(message)s")
        small = {"train.run.n_samples": 5, "evaluations.0.run.n_samples": 5,
                 "methods": [{"name": "H", "plugin": "handcrafted"}]}
        vitaplace.run("quickstart", small, out="out", until="simulate", workers=None)
        print("done")
    """))
    result = _python(script, tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "done" in result.stdout and "BrokenProcessPool" not in result.stderr
    assert "calls vitaplace.run outside `if __name__" in result.stderr
    assert len(list((tmp_path / "out" / "cache" / "datasets").glob("*.h5"))) == 3


@pytest.mark.parametrize("case", ["text", "12 whiskers", "smaller images"])
def test_a_fitted_extractor_refuses_a_run_it_cannot_read_in_one_line(case):
    """``transform`` is given a `Run` of the whiskers and image size it was fitted on (as the
    pipeline's runs are checked against the training run); anything else is one line naming
    the method, its plugin and what differs, not the plugin's broadcasting error."""
    rng = np.random.default_rng(0)

    def made(name, whiskers=24, image=(12, 16, 3)):
        """A run of 6 samples whose whiskers all touch (deflections of 0.05-0.2)."""
        return vitaplace.Run.from_arrays(images=rng.integers(0, 255, (6, *image), dtype=np.uint8),
                                         theta=rng.uniform(0.05, 0.2, (6, whiskers)),
                                         xy=rng.uniform(0.05, 0.2, (6, whiskers, 2)),
                                         poses=rng.uniform(0, 1, (6, 3)), name=name)

    run = made("train")
    m = vitaplace.fit_extractor("mupnet", run, {"epochs": 1, "visual_layers": [8], "tactile_layers": [8],
                                                "joint_size": 4})
    other = {"text": "x", "12 whiskers": made("twelve", whiskers=12),
             "smaller images": made("small", image=(6, 8, 3))}[case]
    message = {"text": r"run='x': expected a Run \(vitaplace\.open_run\(path\) reads a run file\)$",
               "12 whiskers": r"'twelve' has 12 whiskers, the extractor's training run 24$",
               "smaller images": r"'small' has \d+x\d+x3 images, the extractor's training run \d+x\d+x3$"}[case]
    with pytest.raises(vitaplace.UserError, match=r"^transform \(plugin 'mupnet'\): " + message) as info:
        m.transform(other)
    assert "\n" not in str(info.value)
    assert m.transform(run)["latent"].shape[0] == len(run)


def test_a_fitted_extractor_checks_its_features_and_distances_as_the_pipeline_does():
    """``fit_extractor(...).distance`` refuses NaN features in one line naming the method and
    its plugin, as the pipeline refuses them, instead of returning NaN distances; what it
    returns for good features is the plugin's own matrix."""
    import pickle

    run = _tiny_run()
    h = vitaplace.fit_extractor("handcrafted", run)
    features = h.transform(run)
    assert type(h).__name__ == "HandcraftedExtractor" and pickle.loads(pickle.dumps(h)).params == h.params
    np.testing.assert_array_equal(h.distance(features, features), type(h).distance(h, features, features))
    broken = {key: np.array(values, dtype=float) for key, values in features.items()}
    broken["profile"][1, 0] = np.nan
    with pytest.raises(vitaplace.UserError, match=r"^distance \(plugin 'handcrafted'\), its reference features: "
                                                  r"feature 'profile' has NaN or infinite values in 1 samples"):
        h.distance(features, broken)
