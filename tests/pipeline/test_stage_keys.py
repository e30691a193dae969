"""Every stage key of every shipped scenario, pinned: the contract of issue 47's rewrite of the
stages (records instead of a hub) is that no cache key changed, so existing caches stay valid.

``tests/data/stage_keys_ad309c2.json`` holds the keys that commit ad309c2's ``Pipeline``
computed (its own ``model_key``, ``features_key`` and the ``content_hash`` calls of its
evaluate and fusion stages) from fixed stand-ins for everything a key reads from outputs:
each run file 50 samples long with content digest ``digest:<label>``, each plugin's version
``1`` and code digest ``code:<plugin>``, each model folder's digest ``digest:model:<method>``,
each features file's ``digest:features:<method> <label>`` and each evaluation folder's
``digest:evaluation:<evaluation> <method> <direction>``. The same stand-ins are handed to
today's key functions as records here. (Simulate keys are real: they read no output.)

Since then the scenario files changed on purpose, and only so: when the MuPNet plugin's
defaults became the converging training and the settling solver, the committed study
scenarios (and paper.yaml) were given the then-defaults explicitly, so that they still run
what they ran, and the touch benchmark left its 90-epoch cap to the new default's criterion.
`conftest.SINCE_AD309C2` lists those edits; they are undone on the given parameters before the fit key
is computed, so every other part of every key is still checked against ad309c2's. The
evaluate stage's version went from ad309c2's 7 to 8 when its tie rule changed (a tied best
match counted in proportion, not by its lowest index), so that every cached evaluation is
scored again: the keys are computed with version 7 here, and today's version is checked to
differ. Scenarios added since (the third study's) are pinned from the commit that added them
(``tests/data/stage_keys_study3.json``), and the three arms again when its design change and
fusion-weight calibration set L-paper's cap, the fusions' weights and the reduced arms before
any study seed ran (docs/RESULTS.md)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from conftest import ad309c2_params  # noqa: E402
from vitaplace.engine.config.loading import load_scenario  # noqa: E402
from vitaplace.engine.extension.registry import discover  # noqa: E402
from vitaplace.engine.outputs import outdir  # noqa: E402
from vitaplace.engine.pipeline import plan  # noqa: E402
from vitaplace.engine.pipeline.keys import (  # noqa: E402
    STAGE_VERSION,
    evaluate_key,
    features_key,
    fit_key,
    fusion_key,
    recorded_key,
    simulate_key,
)
from vitaplace.engine.pipeline.records import FeaturesFile, ModelFile, RunFile  # noqa: E402
from vitaplace.engine.pipeline.stages.fuse import selection  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PINNED = json.loads((ROOT / "tests" / "data" / "stage_keys_ad309c2.json").read_text())
#: scenarios shipped after ad309c2, pinned when each was first committed (the same stand-ins
#: and evaluate version): the third study's, at its calibration
PINNED.update(json.loads((ROOT / "tests" / "data" / "stage_keys_study3.json").read_text()))
SAMPLES = 50
CACHE = Path("unused") / "cache"
#: the evaluate stage's and a fusion's versions at ad309c2 (and when study3 was pinned)
AD309C2_EVALUATE_VERSION = 7
PINNED_FUSION_VERSION = 1


def stage_keys(name: str) -> dict[str, str]:
    """Every stage key of shipped scenario ``name`` from the stand-in records (module docstring)."""
    scenario, _ = load_scenario(name)
    registry = discover()
    keys, runs = {}, {}
    recorded = plan.recorded_files(scenario)
    for label, (entry, seed) in plan.runs(scenario).items():
        digest = f"digest:{label}"
        key = recorded_key(digest) if label in recorded else simulate_key(scenario, entry, label, seed)
        missing, dropout_seed = plan.dropout_of(scenario, label, SAMPLES)
        runs[label] = RunFile(label, Path(label), key, digest, label in recorded, seed, {}, missing, dropout_seed)
        keys[f"simulate:{label}"] = key
    features = {}
    for m in scenario.methods:
        params = ad309c2_params(name, m.plugin, plan.params_for(scenario, registry, m))
        key = fit_key(m.plugin, "1", f"code:{m.plugin}", params, runs["train"])
        keys[f"fit:{m.name}"] = key
        model = ModelFile(m.name, m.plugin, Path(m.name), key, f"digest:model:{m.name}")
        for label, run in runs.items():
            if label != "train":
                key = keys[f"transform:{m.name} {label}"] = features_key(model, run)
                path = outdir.features_file(CACHE, m.name, label, key)
                features[(m.name, label)] = (FeaturesFile(path, key, f"digest:features:{m.name} {label}"), run)
        for e in scenario.evaluations:
            for direction, q, r in plan.directions(scenario):
                keys[f"evaluate:{e.name} {m.name} {direction}"] = evaluate_key(
                    model, features[(m.name, f"{e.name}/{q}")], features[(m.name, f"{e.name}/{r}")], scenario)
    for fusion in scenario.fusions:
        chosen_on = selection(scenario, fusion)
        for direction, _, _ in plan.directions(scenario):
            for e in scenario.evaluations:
                members = [f"digest:evaluation:{env} {m} {direction}" for env in (e.name, chosen_on)
                           for m in (fusion.vision, fusion.touch)]
                keys[f"evaluate:{e.name} {fusion.name} {direction}"] = fusion_key(fusion, chosen_on, scenario, members)
    return keys


def test_every_shipped_scenario_is_pinned():
    assert sorted(PINNED) == sorted(p.stem for p in (ROOT / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("name", sorted(PINNED))
def test_the_stage_keys_of_a_shipped_scenario_are_unchanged(name, monkeypatch):
    import vitaplace.engine.pipeline.keys as keys

    monkeypatch.setitem(STAGE_VERSION, "evaluate", AD309C2_EVALUATE_VERSION)
    monkeypatch.setattr(keys, "FUSION_VERSION", PINNED_FUSION_VERSION)
    assert stage_keys(name) == PINNED[name]


def test_the_sequence_rule_changed_every_fusion_key():
    """Sequences that leave the reference run stopped being candidates (evaluate 9, fusion 2):
    every cached evaluation, a fusion's too, is scored again."""
    today = stage_keys("study3")
    fused = [k for k in PINNED["study3"] if k.startswith("evaluate:") and k in today and "-F " in k]
    assert fused and all(today[k] != PINNED["study3"][k] for k in fused)


def test_the_tie_rule_changed_every_evaluate_key():
    assert STAGE_VERSION["evaluate"] > AD309C2_EVALUATE_VERSION
    today = stage_keys("quickstart")
    assert all(today[k] != v for k, v in PINNED["quickstart"].items() if k.startswith("evaluate:"))
