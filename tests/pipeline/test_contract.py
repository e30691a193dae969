"""The plugin contract suite `vitaplace.testing.check_extractor` and the plugin API's stable
home `vitaplace.plugin`.

The shipped extractors and the example plugin (as docs/plugins.md prints it) keep the
contract; a reference extractor written here keeps it too, and for each rule a variant of it
that breaks only that rule makes `check_extractor` fail with a message naming the check and
the extractor.
"""

from __future__ import annotations

import re
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pydantic
import pytest
from scipy.spatial.distance import cdist

import vitaplace.plugin
from vitaplace.engine.extension.registry import discover
from vitaplace.testing import CHECKS, ContractError, check_extractor, parametrize_with_checks, synthetic_run

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_DIR = ROOT / "tests" / "plugin_example"

#: mupnet small enough to fit in a fraction of a second
TINY_MUPNET = {"image_size": [6, 8], "visual_layers": [8], "tactile_layers": [4], "joint_size": 3, "epochs": 2,
               "batch_size": 4, "inference_steps": 5, "max_steps": 50}
#: the backprop control at the same size
TINY_AUTOENCODER = {"image_size": [6, 8], "visual_layers": [8], "tactile_layers": [4], "joint_size": 3, "epochs": 2,
                    "batch_size": 4}

# --------------------------------------------------------------------------- shipped extractors


SHIPPED = discover()


@parametrize_with_checks([
    ("handcrafted", SHIPPED.get("handcrafted"), {"grid": [6, 8], "max_shift": 2}),
    ("handcrafted-tactile", SHIPPED.get("handcrafted"),
     {"use_visual": False, "sigma_samples": 3}),
    ("mupnet-numpy", SHIPPED.get("mupnet"), {**TINY_MUPNET, "backend": "numpy"}),
    ("mupnet-warp", SHIPPED.get("mupnet"), {**TINY_MUPNET, "backend": "warp"}),
    ("mupnet-cycle", SHIPPED.get("mupnet"), {**TINY_MUPNET, "backend": "numpy", "tactile_input": "cycle"}),
    ("autoencoder", SHIPPED.get("autoencoder"), TINY_AUTOENCODER),
    ("autoencoder-tied-cycle", SHIPPED.get("autoencoder"),
     {**TINY_AUTOENCODER, "encoder": "tied", "tactile_input": "cycle"}),
])
def test_shipped_extractors_keep_the_contract(extractor, params, check):
    check(extractor, params, synthetic_run())


def test_each_check_of_each_shipped_extractor_is_a_test_of_its_own(request):
    """Per-check ids: 7 configurations x every check, each id naming both."""
    ids = [item.callspec.id for item in request.session.items
           if getattr(item, "originalname", "") == "test_shipped_extractors_keep_the_contract"]
    if not ids:
        pytest.skip("the parametrised test was deselected")
    names = ("handcrafted", "handcrafted-tactile", "mupnet-numpy", "mupnet-warp", "mupnet-cycle", "autoencoder",
             "autoencoder-tied-cycle")
    expected = {f"{name}-{check.__name__}" for name in names for check in CHECKS}
    assert set(ids) == expected and len(ids) == len(names) * len(CHECKS)


def test_the_example_plugin_as_documented_keeps_the_contract(monkeypatch):
    """The example plugin exactly as docs/plugins.md prints it, discovered through its entry
    point, passes the whole suite with the parameters the docs use."""
    monkeypatch.syspath_prepend(str(EXAMPLE_DIR))
    registry = discover(eps=[EntryPoint(name="example", value="vitaplace_example_plugin", group="vitaplace.features")])
    assert registry.failed == {}
    check_extractor(registry.get("example-mean-colour"), {"theta_weight": 2.0})


def test_the_plugin_api_and_the_package_give_the_same_objects():
    assert set(vitaplace.plugin.__all__) >= {"Run", "ExtractorParams", "FeatureExtractor", "Features", "hookimpl"}
    assert vitaplace.Run is vitaplace.plugin.Run and vitaplace.FeatureExtractor is vitaplace.plugin.FeatureExtractor


def test_docs_tell_plugin_authors_to_run_the_suite(monkeypatch):
    """The 'Testing a plugin' section shows `check_extractor`, and its snippet passes for the example."""
    text = (ROOT / "docs" / "plugins.md").read_text()
    snippet = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "check_extractor(" in b)
    assert "from vitaplace.plugin import" in text
    monkeypatch.syspath_prepend(str(EXAMPLE_DIR))
    namespace: dict = {}
    exec(compile(snippet.replace("my_package", "vitaplace_example_plugin"), "docs/plugins.md", "exec"), namespace)
    tests = [f for name, f in namespace.items() if name.startswith("test_") and callable(f)]
    assert tests
    for test in tests:
        test()


def test_the_synthetic_run_has_contacts_deflection_series_and_distinct_samples():
    run = synthetic_run(n_samples=5, seed=3)
    assert len(run) == 5 and run.n_whiskers == 24 and run.image_shape == (24, 32, 3)
    assert run.deflection.shape[1] == 3 and (np.diff(run.contact_offsets) >= 2).all()
    assert np.allclose(np.linalg.norm(run.contacts(0)[1], axis=1), 1.0)
    assert len({run.images[i].tobytes() for i in range(5)}) == 5
    np.testing.assert_array_equal(synthetic_run(5, seed=3).theta, run.theta)


# --------------------------------------------------------------------------- a reference extractor


class ReferenceParams(vitaplace.plugin.ExtractorParams):
    seed: int = 0
    dims: list[int] = pydantic.Field(default_factory=lambda: [2])


class Reference(vitaplace.plugin.FeatureExtractor):
    """Mean colour and theta projected on ``dims[0]`` random axes (drawn from ``seed``),
    compared with the L2 distance divided by its spread on the training run: both
    ``transform`` and ``distance`` need the fitted state."""

    name = "reference"
    Params = ReferenceParams

    def __init__(self, params=None) -> None:
        super().__init__(params)
        self.axes: np.ndarray | None = None
        self.spread: float | None = None

    def _raw(self, run):
        return np.column_stack([run.images.reshape(len(run), -1, 3).mean(axis=1), run.theta.mean(axis=1)])

    def _draw_axes(self) -> np.ndarray:
        return np.random.default_rng(self.params.seed).normal(size=(4, self.params.dims[0]))

    def fit(self, train) -> None:
        self.axes = self._draw_axes()
        self.spread = float(np.std(cdist(self._raw(train) @ self.axes, self._raw(train) @ self.axes)))

    def transform(self, run):
        if self.axes is None:
            raise RuntimeError(f"{self.name}: fit() or load() before transform()")
        return {"projection": self._raw(run) @ self.axes}

    def distance(self, query, reference):
        if self.spread is None:
            raise RuntimeError(f"{self.name}: fit() or load() before distance()")
        return cdist(query["projection"], reference["projection"]) / self.spread

    def save_state(self, directory: Path) -> None:
        np.savez(directory / "state.npz", axes=self.axes, spread=self.spread)

    def load_state(self, directory: Path) -> None:
        with np.load(directory / "state.npz") as state:
            self.axes, self.spread = state["axes"], float(state["spread"])


def test_the_reference_extractor_keeps_the_contract():
    check_extractor(Reference, {"seed": 4, "dims": [3]})


def broken(name: str, **methods) -> type[Reference]:
    """`Reference` with some methods replaced: an extractor that breaks one rule."""
    return type(f"Broken{name.title().replace('-', '')}", (Reference,), {"name": name, **methods})


def _transform(reference_transform):
    """A transform method built from `Reference.transform`'s output (features -> features)."""
    def transform(self, run):
        return reference_transform(Reference.transform(self, run), len(run))
    return transform


def _distance(reference_distance):
    def distance(self, query, reference):
        return reference_distance(Reference.distance(self, query, reference))
    return distance


def _unguarded_distance(self, query, reference):
    return cdist(query["projection"], reference["projection"]) / (self.spread + 0.0)


def _fit_without_seed(self, train):
    Reference.fit(self, train)
    self.axes = np.random.default_rng().normal(size=self.axes.shape)


def _fit_changing_params(self, train):
    Reference.fit(self, train)
    self.params = self.params.model_copy(update={"seed": self.params.seed + 1})


def _fit_growing_a_list_param(self, train):
    Reference.fit(self, train)
    self.params.dims.append(1)


def _init_keeping_the_given_params(self, params=None):
    Reference.__init__(self, params)
    self.given = params


def _fit_changing_the_given_params(self, train):
    Reference.fit(self, train)
    self.given["dims"].append(3)  # dims[0], all that transform uses, stays


def _save_state_clobbering_params(self, directory):
    Reference.save_state(self, directory)
    (directory / "params.json").write_text("{}")


def _init_naming_features_raw(self, params=None):
    Reference.__init__(self, params)
    self.feature_name = "raw"


def _fit_naming_features(self, train):
    Reference.fit(self, train)
    self.feature_name = "projection"  # fitted state that save_state does not save


def _transform_with_fitted_name(self, run):
    return {self.feature_name: Reference.transform(self, run)["projection"]}


def _distance_of_the_only_feature(self, query, reference):
    (q,), (r,) = query.values(), reference.values()
    return Reference.distance(self, {"projection": q}, {"projection": r})


def _load_state_forgetting_spread(self, directory):
    Reference.load_state(self, directory)
    self.spread = 1.0


def _transform_centred_on_its_run(self, run):
    features = Reference.transform(self, run)["projection"]
    return {"projection": features - features.mean(axis=0)}


def _init_with_default_spread(self, params=None):
    Reference.__init__(self, params)
    self.spread = 1.0


def _distance_refusing_cryptically(self, query, reference):
    if self.spread is None:
        raise ValueError("no state")
    return Reference.distance(self, query, reference)


#: (extractor breaking one rule, the check that must catch it, the rest of the message)
BROKEN = [
    (broken("short-features", transform=_transform(lambda f, n: {"projection": f["projection"][:-1]})),
     "check_features_output", r"feature 'projection' has shape \(7, 2\) for a run of 8 samples"),
    (broken("nan-features", transform=_transform(lambda f, n: {"projection": f["projection"] * np.nan})),
     "check_features_output", r"feature 'projection' has NaN or infinite values \(first in sample 0\)"),
    (broken("list-features", transform=_transform(lambda f, n: [f["projection"]])),
     "check_features_output", r"transform returned list, expected a non-empty dict of arrays"),
    (broken("no-features", transform=_transform(lambda f, n: {})),
     "check_features_output", r"transform returned an empty dict, expected a non-empty dict of arrays"),
    (broken("text-features", transform=_transform(lambda f, n: {"name": np.array(["x"] * n)})),
     "check_features_output", r"feature 'name' is an array of <U1, expected a numpy array of numbers"),
    (broken("transposed-distance", distance=_distance(lambda d: d.T)),
     "check_distance_output", r"distance of 4 query and 8 reference samples has shape \(8, 4\), expected \(4, 8\)"),
    (broken("infinite-distance", distance=_distance(lambda d: np.where(d > 0, np.inf, d))),
     "check_distance_output", r"distance has \d+ NaN or infinite entries"),
    (broken("list-distance", distance=_distance(lambda d: d.tolist())),
     "check_distance_output", r"distance returned a list, expected a numpy array of numbers"),
    (broken("batch-scaled-distance", distance=_distance(lambda d: d / d.max())),
     "check_distance_rows", r"distance of query samples 2..3 is not those rows of distance of all 8: it differs by "
                            r"up to [0-9.e-]+; a row must depend on its query alone"),
    (broken("batch-centred", transform=_transform_centred_on_its_run),
     "check_transform_subset", r"transform\(run.subset\(\[7, 5, 3, 1\]\)\) is not those rows of transform\(run\): "
                               r"'projection' differs by up to"),
    (broken("forgetful", load_state=_load_state_forgetting_spread),
     "check_save_load_round_trip", r"after save and load, distance gives other values"),
    (broken("params-clobbering", save_state=_save_state_clobbering_params),
     "check_save_load_round_trip", r"load gave BrokenParamsClobbering with params ReferenceParams\(seed=0, "
                                   r"dims=\[2\]\), expected BrokenParamsClobbering with ReferenceParams\(seed=1, "),
    (broken("name-forgetting", __init__=_init_naming_features_raw, fit=_fit_naming_features,
            transform=_transform_with_fitted_name, distance=_distance_of_the_only_feature),
     "check_save_load_round_trip",
     r"after save and load, transform differs: keys \['raw'\] instead of \['projection'\]"),
    (broken("unguarded-transform",
            transform=lambda self, run: {"projection": self._raw(run) @ self.axes.reshape(4, -1)}),
     "check_transform_before_fit",
     r"transform before fit raised AttributeError: 'NoneType' object has no attribute 'reshape'; raise a clear error"),
    (broken("unguarded-distance", distance=_unguarded_distance),
     "check_distance_before_fit", r"distance before fit raised TypeError: .*raise a clear error instead"),
    (broken("silent-distance", __init__=_init_with_default_spread),
     "check_distance_before_fit", r"distance before fit returned a result unlike the fitted extractor's"),
    (broken("cryptic-distance", distance=_distance_refusing_cryptically),
     "check_distance_before_fit", r"distance before fit raised ValueError: no state; its message should say that fit"),
    (broken("unseeded", fit=_fit_without_seed),
     "check_same_seed_same_features", r"fitted twice with the same parameters, gives other features: 'projection' "),
    (broken("params-changing", fit=_fit_changing_params),
     "check_fit_leaves_params", r"fit changed self.params \(seed\)"),
    (broken("list-growing", fit=_fit_growing_a_list_param),
     "check_fit_leaves_params", r"fit changed self.params \(dims\)"),
    (broken("peeking", handles_missing=True),  # declares it, but its colour means read every frame
     "check_missing_modalities", r"declares handles_missing, but changing the data of the sensors samples lack "
                                 r"\(Run.lacks\) changed the features: 'projection' differs by up to"),
    (broken("given-changing", __init__=_init_keeping_the_given_params, fit=_fit_changing_the_given_params),
     "check_fit_leaves_params", r"fit changed the parameters it was given: \{'seed': 1, 'dims': \[2\]\} became "
                                r"\{'seed': 1, 'dims': \[2, 3\]\}"),
    (broken("odd-senses", modalities=classmethod(lambda cls, params: frozenset({"visual", "smell"}))),
     "check_declared_senses", r"modalities returned frozenset\(\{'.*'\}\), expected None \(unknown\) or a "
                              r"non-empty set of 'visual' and 'tactile'"),
    (broken("no-senses", modalities=classmethod(lambda cls, params: frozenset())),
     "check_declared_senses", r"modalities returned frozenset\(\), expected None"),
    (broken("listed-senses", modalities=classmethod(lambda cls, params: ["visual"])),
     "check_declared_senses", r"modalities returned \['visual'\], expected None"),
]


@pytest.mark.parametrize("extractor, check, message", BROKEN, ids=[extractor.name for extractor, _, _ in BROKEN])
def test_each_rule_bites(extractor, check, message):
    """The variant fails the whole suite at exactly its rule, with the check and extractor named."""
    with pytest.raises(ContractError, match=rf"^{check}: extractor '{extractor.name}' {message}"):
        check_extractor(extractor, {"seed": 1, "dims": [2]})


def test_each_check_has_a_variant_that_breaks_it():
    assert {check.__name__ for check in CHECKS} == {check for _, check, _ in BROKEN}


def test_a_class_that_is_not_an_extractor_is_refused():
    with pytest.raises(ContractError, match=r"^check_extractor: <class 'dict'> is not a FeatureExtractor subclass"):
        check_extractor(dict)
