"""The committed study scenarios run what they ran: every learned method's parameters, as the
pipeline resolves them (the scenario's, then the plugin's defaults), are those recorded in
``tests/data/study_method_params.json`` before the MuPNet plugin's defaults became the
converging training and the settling solver (docs/MUPNET.md, "Defaults"), and for the third
study's files when it was pre-registered. A default that changes again cannot reach a
committed study unnoticed: the scenario must pin the old value.

Only the quickstart, its near-duplicate variant and the touch benchmark follow the plugin's
defaults (none of them has committed learned-method results)."""

import json
from pathlib import Path

import pytest

from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.extension.registry import discover
from vitaplace.engine.pipeline import plan

ROOT = Path(__file__).resolve().parents[2]
PINNED = json.loads((ROOT / "tests" / "data" / "study_method_params.json").read_text())
FOLLOW_DEFAULTS = {"quickstart", "near-duplicate", "touch-benchmark"}
LEARNED = ("mupnet", "autoencoder")


def resolved(name: str) -> dict[str, dict]:
    scenario, _ = load_scenario(name)
    settings = plan.method_settings(scenario, discover())
    return {m: {**s["defaults"], **s["params"]} for m, s in settings.items() if s["plugin"] in LEARNED}


def test_every_shipped_scenario_is_pinned_or_follows_the_defaults():
    shipped = {p.stem for p in (ROOT / "scenarios").glob("*.yaml")}
    assert set(PINNED) == shipped - FOLLOW_DEFAULTS


@pytest.mark.parametrize("name", sorted(PINNED))
def test_a_committed_study_resolves_to_what_it_ran(name):
    assert resolved(name) == PINNED[name]


def test_paper_yaml_pins_the_paper_s_algorithm():
    from vitaplace.plugins.mupnet.extractor import PAPER_ALGORITHM

    (params,) = resolved("paper").values()
    expected = {**PAPER_ALGORITHM, "epochs": 10000}  # the paper's schedule at full scale (a GPU's)
    assert {k: params[k] for k in expected} == expected
    assert params["batch_size"] == 150 and params["precision_weighting"] == "none"


def test_the_paper_s_algorithm_is_what_the_paper_prints():
    """The constant itself, by hand from the paper/code: 10 epochs of T = 20 plain steps and
    plain SGD on unconstrained weights, min-max touch, no prior, plain test-time steps to 3000."""
    from vitaplace.plugins.mupnet.extractor import PAPER_ALGORITHM, MupnetParams

    assert PAPER_ALGORITHM == {
        "tactile_scaling": "range", "epochs": 10, "converge_window": 0, "inference_steps": 20,
        "training_inference": "plain", "weight_optimizer": "sgd", "held_out": 0.0, "max_steps": 3000,
        "latent_prior": 0.0, "inference_solver": "gd", "inference_rtol": None, "weight_norm": "none"}
    params = MupnetParams(**PAPER_ALGORITHM)
    assert params.training_config().weight_optimizer == "sgd" and params.solver().rtol is None
    assert params.training_config().weight_norm == "none"


def test_the_touch_benchmark_trains_to_the_criterion_with_the_defaults():
    """Its learned methods leave the epoch cap, the training rule and the solver to the plugin."""
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    defaults = MupnetParams()
    for params in resolved("touch-benchmark").values():
        assert params["epochs"] == defaults.epochs and params["converge_window"] > 0
        assert params["training_inference"] == "solver" and params["held_out"] > 0
