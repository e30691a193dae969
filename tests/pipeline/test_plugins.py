"""Plugin discovery and the third-party extractor contract (docs/plugins.md).

The third-party package used here is the real one in tests/plugin_example (the same code
docs/plugins.md prints). Expected distances are computed by hand from the synthetic runs.
"""

from __future__ import annotations

import ast
import inspect
import re
import sys
import textwrap
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

import numpy as np
import pluggy
import pytest

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension import hookspecs
from vitaplace.engine.extension.features import ExtractorParamsError, FeatureExtractor
from vitaplace.engine.extension.registry import ONLY_ENV, PluginError, discover

TESTS = Path(__file__).resolve().parents[1]
ROOT = TESTS.parent
EXAMPLE_DIR = TESTS / "plugin_example"
EXAMPLE_MODULE = EXAMPLE_DIR / "vitaplace_example_plugin" / "__init__.py"
DOC = ROOT / "docs" / "plugins.md"
GROUP = hookspecs.ENTRY_POINT_GROUP
EXAMPLE = "example-mean-colour"


def ep(name: str, value: str) -> EntryPoint:
    return EntryPoint(name=name, value=value, group=GROUP)


@pytest.fixture
def example_path(monkeypatch):
    """Make the example package importable (as if pip-installed) for one test."""
    monkeypatch.syspath_prepend(str(EXAMPLE_DIR))
    return EXAMPLE_DIR


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    """A folder on sys.path where a test writes throw-away plugin modules; they are unloaded afterwards."""
    monkeypatch.syspath_prepend(str(tmp_path))
    before = set(sys.modules)
    yield tmp_path
    for name in set(sys.modules) - before:
        if name.startswith("tmp_plugin_"):
            del sys.modules[name]


def write_plugin(directory: Path, module: str, body: str) -> str:
    (directory / f"{module}.py").write_text(textwrap.dedent(body))
    return module


#: A plugin module registering one extractor called NAME (formatted in).
EXTRACTOR_PLUGIN = """
    from pathlib import Path
    import numpy as np
    from vitaplace.engine.extension.features import FeatureExtractor
    from vitaplace.engine.extension.hookspecs import hookimpl

    class Constant(FeatureExtractor):
        name = {name!r}
        def fit(self, train): pass
        def transform(self, run): return {{"x": np.zeros((len(run), 1))}}
        def distance(self, query, reference): return np.zeros((len(query["x"]), len(reference["x"])))
        def save_state(self, directory: Path): pass
        def load_state(self, directory: Path): pass

    @hookimpl
    def vitaplace_register_features(register):
        register(Constant)
"""


def uniform_run(colours, thetas, size=(4, 5)) -> Run:
    """Samples whose images are one flat RGB colour and whose 24 whiskers share one theta."""
    colours = np.asarray(colours, dtype=np.uint8)
    n = len(colours)
    images = np.broadcast_to(colours[:, None, None, :], (n, *size, 3)).copy()
    theta = np.repeat(np.asarray(thetas, dtype=np.float32)[:, None], 24, axis=1)
    rng = np.random.default_rng(0)
    return Run.from_arrays(
        images=images, theta=theta, xy=rng.normal(0, 0.01, (n, 24, 2)), poses=np.zeros((n, 3))
    )


# --------------------------------------------------------------------------- built-ins


def test_builtin_plugins_are_declared_entry_points():
    names = {e.name for e in entry_points(group=GROUP)}
    assert {"mupnet", "handcrafted"} <= names


def test_builtins_discovered_through_real_entry_points(monkeypatch):
    monkeypatch.delenv(ONLY_ENV, raising=False)
    registry = discover()
    assert "mupnet" in registry.names()
    assert registry.sources["mupnet"].startswith("mupnet (")
    from vitaplace.plugins.mupnet.extractor import MupnetExtractor

    assert registry.get("mupnet") is MupnetExtractor
    assert not {k for k in registry.failed if k.startswith(("mupnet", "handcrafted"))}, registry.failed


def test_handcrafted_builtin_discovered(monkeypatch):
    monkeypatch.delenv(ONLY_ENV, raising=False)
    module = pytest.importorskip("vitaplace.plugins.handcrafted")
    if not hasattr(module, "vitaplace_register_features"):
        pytest.skip("vitaplace.plugins.handcrafted has no hook implementation yet")
    registry = discover()
    assert "handcrafted" in registry.names()
    assert registry.sources["handcrafted"].startswith("handcrafted (")
    assert issubclass(registry.get("handcrafted"), FeatureExtractor)


# --------------------------------------------------------------------------- third-party path


def test_third_party_extractor_discovered_and_used(example_path):
    registry = discover(eps=[ep("mupnet", "vitaplace.plugins.mupnet"), ep("example", "vitaplace_example_plugin")])
    assert registry.failed == {}
    assert {"mupnet", EXAMPLE} <= set(registry.names())
    assert registry.sources[EXAMPLE] == "example (vitaplace_example_plugin)"

    extractor = registry.create(EXAMPLE, {"theta_weight": 2.0})
    train = uniform_run([(0, 0, 0), (100, 50, 10), (200, 100, 20)], [0.0, 0.2, 0.4])
    query = uniform_run([(10, 20, 30), (200, 100, 20)], [0.1, 0.4])
    reference = uniform_run([(10, 20, 40), (0, 0, 0), (200, 90, 20)], [0.6, 0.0, 0.4])
    extractor.fit(train)
    fq, fr = extractor.transform(query), extractor.transform(reference)
    assert fq["colour_theta"].shape == (2, 4)
    tme = extractor.distance(fq, fr)
    # L1 over (R, G, B, 2 * theta); the training-mean centring cancels in differences.
    expected = np.array(
        [
            [0 + 0 + 10 + 2 * 0.5, 10 + 20 + 30 + 2 * 0.1, 190 + 70 + 10 + 2 * 0.3],
            [190 + 80 + 20 + 2 * 0.2, 200 + 100 + 20 + 2 * 0.4, 0 + 10 + 0 + 0],
        ]
    )
    np.testing.assert_allclose(tme, expected, atol=1e-5)
    # The fitted state is the mean feature of the training run.
    np.testing.assert_allclose(extractor.centre, [100, 50, 10, 2 * 0.2], atol=1e-5)


def test_example_dist_info_is_found_by_real_entry_points(example_path, tmp_path, monkeypatch):
    """Install-like: a dist-info folder generated from the example's pyproject.toml."""
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((EXAMPLE_DIR / "pyproject.toml").read_text())["project"]
    dist_info = tmp_path / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\n"
                                        f"Version: {project['version']}\n")
    lines = [f"[{GROUP}]"] + [f"{k} = {v}" for k, v in project["entry-points"][GROUP].items()]
    (dist_info / "entry_points.txt").write_text("\n".join(lines) + "\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv(ONLY_ENV, raising=False)

    registry = discover()
    assert registry.sources[EXAMPLE] == "example (vitaplace-example-plugin)"
    assert "mupnet" in registry.names()
    registry = discover(only="example")
    assert registry.names() == [EXAMPLE]


def test_example_save_load_round_trip(example_path, tmp_path):
    registry = discover(eps=[ep("example", "vitaplace_example_plugin")])
    extractor = registry.create(EXAMPLE, {"theta_weight": 0.5})
    run = uniform_run([(5, 6, 7), (50, 60, 70), (9, 9, 9)], [0.3, -0.2, 0.0])
    with pytest.raises(RuntimeError, match="fit"):
        extractor.transform(run)
    extractor.fit(run)
    extractor.save(tmp_path / "saved")
    loaded = registry.get(EXAMPLE).load(tmp_path / "saved")
    assert type(loaded) is type(extractor)
    assert loaded.params == extractor.params
    before, after = extractor.transform(run), loaded.transform(run)
    assert before.keys() == after.keys()
    np.testing.assert_array_equal(before["colour_theta"], after["colour_theta"])
    np.testing.assert_array_equal(extractor.distance(before, before), loaded.distance(after, after))


# --------------------------------------------------------------------------- errors


def test_duplicate_names_raise_naming_both_sources(example_path, plugin_dir):
    write_plugin(plugin_dir, "tmp_plugin_dup", EXTRACTOR_PLUGIN.format(name=EXAMPLE))
    with pytest.raises(PluginError) as info:
        discover(eps=[ep("example", "vitaplace_example_plugin"), ep("impostor", "tmp_plugin_dup")])
    message = str(info.value)
    assert EXAMPLE in message
    assert "example (vitaplace_example_plugin)" in message
    assert "impostor (tmp_plugin_dup)" in message


def test_duplicate_of_a_builtin_name_is_an_error(plugin_dir):
    write_plugin(plugin_dir, "tmp_plugin_mupnet", EXTRACTOR_PLUGIN.format(name="mupnet"))
    with pytest.raises(PluginError, match=r"mupnet \(vitaplace.plugins.mupnet\).*other \(tmp_plugin_mupnet\)"):
        discover(eps=[ep("mupnet", "vitaplace.plugins.mupnet"), ep("other", "tmp_plugin_mupnet")])


def test_same_module_under_two_entry_points_is_a_plugin_error(example_path):
    with pytest.raises(PluginError, match=r"example \(vitaplace_example_plugin\).*again \(vitaplace_example_plugin\)"):
        discover(eps=[ep("example", "vitaplace_example_plugin"), ep("again", "vitaplace_example_plugin")])


def test_plugin_failing_to_import_is_reported_and_skipped(example_path, plugin_dir, capsys):
    write_plugin(plugin_dir, "tmp_plugin_broken", "import a_dependency_that_is_not_installed_xyz\n")
    eps = [ep("broken", "tmp_plugin_broken"), ep("example", "vitaplace_example_plugin"),
           ep("gone", "tmp_plugin_nowhere")]
    registry = discover(eps=eps)
    err = capsys.readouterr().err
    assert "broken (tmp_plugin_broken)" in err and "a_dependency_that_is_not_installed_xyz" in err
    assert "gone (tmp_plugin_nowhere)" in err
    assert set(registry.failed) == {"broken (tmp_plugin_broken)", "gone (tmp_plugin_nowhere)"}
    assert "import failed" in registry.failed["broken (tmp_plugin_broken)"]
    # The others keep working.
    assert registry.names() == [EXAMPLE]
    extractor = registry.create(EXAMPLE)
    run = uniform_run([(1, 2, 3), (4, 5, 6)], [0.0, 0.0])
    extractor.fit(run)
    assert extractor.distance(extractor.transform(run), extractor.transform(run))[0, 1] == pytest.approx(9.0)


def test_plugin_whose_module_raises_on_import_is_skipped(example_path, plugin_dir, capsys):
    write_plugin(plugin_dir, "tmp_plugin_raises", "raise RuntimeError('boom at import')\n")
    registry = discover(eps=[ep("raises", "tmp_plugin_raises"), ep("example", "vitaplace_example_plugin")])
    assert "raises (tmp_plugin_raises)" in capsys.readouterr().err
    assert "boom at import" in registry.failed["raises (tmp_plugin_raises)"]
    assert registry.names() == [EXAMPLE]


def test_plugin_calling_sys_exit_at_import_is_skipped(example_path, plugin_dir, capsys):
    write_plugin(plugin_dir, "tmp_plugin_exits", "import sys\nsys.exit(3)\n")
    registry = discover(eps=[ep("exits", "tmp_plugin_exits"), ep("example", "vitaplace_example_plugin")])
    assert "SystemExit" in registry.failed["exits (tmp_plugin_exits)"]
    assert registry.names() == [EXAMPLE]


def test_plugin_whose_hook_raises_is_skipped(example_path, plugin_dir, capsys):
    write_plugin(
        plugin_dir,
        "tmp_plugin_hook",
        textwrap.dedent(EXTRACTOR_PLUGIN.format(name="half-registered"))
        + textwrap.dedent(
            """
            @hookimpl
            def vitaplace_register_features(register):  # replaces the hook above
                register(Constant)
                raise KeyError("hook failed halfway")
            """
        ),
    )
    registry = discover(eps=[ep("hooky", "tmp_plugin_hook"), ep("example", "vitaplace_example_plugin")])
    err = capsys.readouterr().err
    assert "hooky (tmp_plugin_hook)" in err and "hook failed halfway" in err
    assert "hooky (tmp_plugin_hook)" in registry.failed
    # A skipped plugin contributes nothing, not even what it registered before failing.
    assert registry.names() == [EXAMPLE]
    assert registry.create(EXAMPLE).name == EXAMPLE


def test_env_var_restricts_which_plugins_load(example_path, plugin_dir, monkeypatch, capsys):
    write_plugin(plugin_dir, "tmp_plugin_broken2", "raise ImportError('must not even be imported')\n")
    eps = [ep("mupnet", "vitaplace.plugins.mupnet"), ep("example", "vitaplace_example_plugin"),
           ep("b", "tmp_plugin_broken2")]
    monkeypatch.setenv(ONLY_ENV, " example , mupnet")
    registry = discover(eps=eps)
    assert registry.names() == [EXAMPLE, "mupnet"]
    assert registry.failed == {}
    assert "tmp_plugin_broken2" not in sys.modules
    assert capsys.readouterr().err == ""
    monkeypatch.setenv(ONLY_ENV, "example")
    assert discover(eps=eps).names() == [EXAMPLE]
    # `only=` overrides the environment variable.
    assert discover(eps=eps, only="mupnet").names() == ["mupnet"]


def test_env_var_restricts_real_entry_points(monkeypatch):
    monkeypatch.setenv(ONLY_ENV, "mupnet")
    assert discover().names() == ["mupnet"]
    monkeypatch.setenv(ONLY_ENV, "no-such-plugin")
    assert discover().names() == []


def test_unknown_extractor_lists_valid_names(example_path):
    registry = discover(eps=[ep("mupnet", "vitaplace.plugins.mupnet"), ep("example", "vitaplace_example_plugin")])
    with pytest.raises(PluginError, match=r"unknown feature extractor 'nope'.*example-mean-colour, mupnet"):
        registry.get("nope")
    with pytest.raises(PluginError, match="nope"):
        registry.create("nope", {})
    with pytest.raises(PluginError, match="none installed"):
        discover(eps=[]).get("mupnet")


@pytest.mark.parametrize(
    "registered",
    ["object()", "int", "Constant()", "type('Loose', (), {'name': 'loose'})"],
    ids=["instance", "builtin-class", "extractor-instance", "duck-typed-class"],
)
def test_registering_a_non_extractor_is_an_error(plugin_dir, registered):
    body = EXTRACTOR_PLUGIN.format(name="ok").replace("register(Constant)", f"register({registered})")
    write_plugin(plugin_dir, f"tmp_plugin_bad_{abs(hash(registered))}", body)
    with pytest.raises(PluginError, match=r"bad \(tmp_plugin_bad_\d+\).*not a FeatureExtractor"):
        discover(eps=[ep("bad", f"tmp_plugin_bad_{abs(hash(registered))}")])


def test_registering_an_extractor_without_name_is_an_error(plugin_dir):
    body = EXTRACTOR_PLUGIN.format(name="").replace("name = ''", "")
    write_plugin(plugin_dir, "tmp_plugin_noname", body)
    with pytest.raises(PluginError, match=r"noname \(tmp_plugin_noname\).*Constant.*without a 'name'"):
        discover(eps=[ep("noname", "tmp_plugin_noname")])


# --------------------------------------------------------------------------- params


@pytest.fixture
def example_class(example_path):
    return discover(eps=[ep("example", "vitaplace_example_plugin")]).get(EXAMPLE)


def test_params_defaults_and_valid_values(example_class):
    assert example_class().params.theta_weight == 1.0
    assert example_class({"theta_weight": 3}).params.theta_weight == 3.0


@pytest.mark.parametrize(
    "params, key",
    [
        ({"theta_wieght": 1.0}, "theta_wieght"),
        ({"theta_weight": "heavy"}, "theta_weight"),
        ({"theta_weight": [1.0]}, "theta_weight"),
        ({"theta_weight": -0.5}, "theta_weight"),
    ],
    ids=["unknown-key", "wrong-type-str", "wrong-type-list", "out-of-range"],
)
def test_params_errors_name_extractor_and_key(example_class, params, key):
    with pytest.raises(ExtractorParamsError) as info:
        example_class(params)
    message = str(info.value)
    assert f"'{EXAMPLE}'" in message and key in message
    with pytest.raises(ExtractorParamsError, match=key):
        example_class.validate_params(params)


def test_mupnet_params_errors_name_extractor_and_key():
    from vitaplace.plugins.mupnet.extractor import MupnetExtractor

    with pytest.raises(ExtractorParamsError, match=r"'mupnet'.*epochz"):
        MupnetExtractor({"epochz": 3})
    with pytest.raises(ExtractorParamsError, match=r"'mupnet'.*joint_size"):
        MupnetExtractor({"joint_size": "big"})


# --------------------------------------------------------------------------- docs


def hook_names() -> list[str]:
    """Every hookspec of engine/extension/hookspecs.py, found by introspection (two ways, which must agree)."""
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    from_manager = sorted(name for name in vars(pm.hook) if not name.startswith("_"))
    marker = f"{hookspecs.PROJECT}_spec"
    from_markers = sorted(
        name for name, obj in inspect.getmembers(hookspecs, inspect.isfunction) if hasattr(obj, marker)
    )
    assert from_manager == from_markers
    return from_manager


def doc_sections(text: str) -> dict[str, str]:
    """Markdown heading text -> body up to the next heading of any level (code blocks skipped)."""
    sections: dict[str, str] = {}
    current, fence = None, False
    for line in text.splitlines():
        if line.startswith("```"):
            fence = not fence
        if not fence and (m := re.match(r"^(#{1,6})\s+(.*?)\s*$", line)):
            current = m.group(2).strip("` ")
            sections[current] = ""
        elif current is not None:
            sections[current] += line + "\n"
    return sections


def test_hookspecs_found():
    assert "vitaplace_register_features" in hook_names()


@pytest.mark.parametrize("hook", hook_names())
def test_every_hook_is_documented(hook):
    text = DOC.read_text()
    assert re.search(rf"^### {re.escape(hook)}\s*$", text, re.M), f"docs/plugins.md lacks a '### {hook}' section"
    body = doc_sections(text)[hook]
    assert len(body.split()) >= 20, f"the '### {hook}' section of docs/plugins.md is (nearly) empty"
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    argnames = getattr(pm.hook, hook).spec.argnames
    assert f"{hook}({', '.join(argnames)})" in body


def doc_example_block() -> tuple[str, str]:
    """(path named by the marker, code) of the example-plugin code block in docs/plugins.md."""
    m = re.search(r"<!-- example-plugin: (\S+) -->\n```python\n(.*?)```", DOC.read_text(), re.S)
    assert m, "docs/plugins.md lacks the marked example-plugin code block"
    return m.group(1), m.group(2)


def test_doc_example_is_the_example_package():
    path, code = doc_example_block()
    assert ROOT / path == EXAMPLE_MODULE
    assert code == EXAMPLE_MODULE.read_text()
    tree = ast.parse(code)
    compile(tree, "docs/plugins.md", "exec")
    defined = {n.name for n in tree.body if isinstance(n, (ast.ClassDef, ast.FunctionDef))}
    assert {"MeanColourParams", "MeanColourExtractor", "vitaplace_register_features"} <= defined


def test_doc_packaging_snippet_and_example_pyproject_declare_the_group():
    tomllib = pytest.importorskip("tomllib")
    blocks = re.findall(r"```toml\n(.*?)```", DOC.read_text(), re.S)
    assert blocks
    doc_project = tomllib.loads(blocks[0])["project"]
    assert doc_project["entry-points"][GROUP] == {"mine": "my_package"}
    example_project = tomllib.loads((EXAMPLE_DIR / "pyproject.toml").read_text())["project"]
    assert example_project["name"] == "vitaplace-example-plugin"
    assert example_project["entry-points"][GROUP] == {"example": "vitaplace_example_plugin"}


def test_doc_testing_snippet_runs(example_path):
    """The 'Testing a plugin' example of the docs passes against the example package."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)
    snippet = next(b for b in blocks if "def test_discovered_and_used" in b)
    namespace: dict = {}
    exec(compile(snippet.replace('"my_package"', '"vitaplace_example_plugin"'), "docs/plugins.md", "exec"), namespace)
    tests = [f for name, f in namespace.items() if name.startswith("test_") and callable(f)]
    assert len(tests) >= 2
    for test in tests:
        test()


def test_every_extractor_member_is_documented():
    """Each public member of FeatureExtractor appears in the interface section of the docs."""
    members = {n for n in vars(FeatureExtractor) if not n.startswith("_")} | {
        n for n in FeatureExtractor.__annotations__ if not n.startswith("_")
    }
    assert {"name", "Params", "fit", "transform", "distance", "save_state", "load_state", "save", "load"} <= members
    section = doc_sections(DOC.read_text())["The extractor interface"]
    missing = sorted(m for m in members if not re.search(rf"`{re.escape(m)}[`(]", section))
    assert not missing, f"docs/plugins.md 'The extractor interface' does not describe {missing}"


def test_doc_mentions_error_behaviour_and_usage():
    text = DOC.read_text()
    for needle in [ONLY_ENV, "vitaplace plugins", "methods:", "plugin: example-mean-colour", "PluginError",
                   "ExtractorParamsError", "skipping plugin", "save_state", "load_state"]:
        assert needle in text, needle


def test_cache_keys_change_with_the_plugin_version(monkeypatch):
    """A new version of a plugin must not reuse the old version's fitted model and features;
    nor may another training run's content."""
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.pipeline.keys import fit_key
    from vitaplace.engine.pipeline.plan import params_for
    from vitaplace.engine.pipeline.records import RunFile

    scenario, _ = load_scenario("quickstart")
    registry = discover()
    assert registry.version_of("handcrafted").startswith("vitaplace==")
    method = scenario.methods[1]
    train = RunFile("train", Path("train.h5"), "k", "d", False, 0, {})

    def key(run: RunFile = train) -> str:
        return fit_key(method.plugin, registry.version_of(method.plugin), registry.code_digest(method.plugin),
                       params_for(scenario, registry, method), run)

    before = key()
    registry.distributions[registry.sources[method.plugin]] = "vitaplace==99.0"
    assert key() != before
    before = key()
    assert key(RunFile("train", Path("train.h5"), "k", "another training run's content", False, 0, {})) != before


def test_the_scenario_seed_reaches_the_methods_seed():
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.pipeline.plan import params_for

    registry = discover()
    keys = {}
    for seed in (0, 1):
        scenario, _ = load_scenario("quickstart", [f"seed={seed}"])
        keys[seed] = params_for(scenario, registry, scenario.methods[0])["seed"]
    assert keys[0] != keys[1]
    scenario, _ = load_scenario("quickstart", ["methods.0.params.seed=7"])
    assert params_for(scenario, registry, scenario.methods[0])["seed"] == 7


def test_a_hook_written_before_an_argument_was_added_gets_the_arguments_it_names(tmp_path):
    """`vitaplace_sweep_started` gained ``grid``: a plugin whose hook takes the three older
    arguments is still called, with those, and what it asks for reaches the seeds."""
    from vitaplace.engine.extension.registry import Registry, announce_sweep_started

    class Older:
        @hookspecs.hookimpl
        def vitaplace_sweep_started(self, out, scenario, seeds):
            return {"ASKED": f"{out.name} {scenario} {seeds}"}

    manager = pluggy.PluginManager(hookspecs.PROJECT)
    manager.add_hookspecs(hookspecs)
    registry = Registry(manager)
    registry.add_plugin(Older(), "older")
    assert announce_sweep_started(registry, tmp_path / "sweep", "tiny", [0, 1], []) == {"ASKED": "sweep tiny [0, 1]"}
