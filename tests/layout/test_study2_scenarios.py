"""The second study's scenario files against its pre-registration (docs/RESULTS.md, "Second
study: pre-registration"): every file validates as `vitaplace validate` checks it, holds the
pre-registered methods and late fusions (the same parameters, in the same order, wherever a
file repeats them), the settling test-time solver and the sequence settings the text fixes,
and the text's commands run every arm over the same >= 8 seeds, so that neither can drift
from the other unnoticed."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from vitaplace.engine.config.loading import load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"
TEXT = (ROOT / "docs" / "RESULTS.md").read_text()
PREREG = TEXT[TEXT.index("## Second study: pre-registration"):]
PREREG = PREREG[:PREREG.index("\n## ", 1)] if "\n## " in PREREG[1:] else PREREG
PREREG = " ".join(PREREG.split())  # line breaks as spaces
METHODS = ["L", "L-V", "L-T", "H", "H-V", "H-T", "L-cycle", "A"]
SETTLE = {"inference_solver": "nesterov", "latent_prior": 1.0, "inference_rtol": 3.0e-5, "max_steps": 1000}
ARMS = {"study2": (METHODS, "alike-shapes", 24), "study2-dropout": (METHODS[:-1], "alike-shapes", 24),
        "study2-faithful": (METHODS, "E1", 50)}
SEQUENCE_LENGTH = 16


def scenario(name: str):
    return load_scenario(SCENARIOS / f"{name}.yaml")[0]


def params(name: str) -> dict[str, dict]:
    return {m.name: dict(m.params) for m in scenario(name).methods}


@pytest.mark.parametrize("name", [*ARMS, "study2-budget"])
def test_each_study2_file_validates(name):
    done = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli", "validate", str(SCENARIOS / f"{name}.yaml"),
                           "--set", f"scoring.sequence.length={SEQUENCE_LENGTH}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("name", ARMS)
def test_each_arm_holds_the_preregistered_methods_and_fusions(name):
    methods, select_on, window = ARMS[name]
    s = scenario(name)
    assert [m.name for m in s.methods] == methods
    assert {m.name: m.plugin for m in s.methods} == {n: {"H": "handcrafted", "A": "autoencoder"}.get(n[0], "mupnet")
                                                    for n in methods}
    assert [(f.name, f.vision, f.touch, f.select_on) for f in s.fusions] == [
        ("L-F", "L-V", "L-T", select_on), ("H-F", "H-V", "H-T", select_on)]
    assert s.scoring.sequence.length == 1 and s.scoring.sequence.window == window
    assert s.scoring.direction == "both"
    assert f"`window: {window}`" in PREREG


def test_the_mupnet_methods_settle_and_differ_from_L_only_by_their_ablation():
    p = params("study2")
    for name in ("L", "L-V", "L-T", "L-cycle"):
        assert {k: p[name][k] for k in SETTLE} == SETTLE
    assert ("`inference_solver: nesterov`, `latent_prior: 1.0`, `inference_rtol: 3.0e-5`, `max_steps: 1000`"
            in PREREG)
    assert p["L-V"] == {**p["L"], "modalities": ["visual"]}
    assert p["L-T"] == {**p["L"], "modalities": ["tactile"]}
    assert p["L-cycle"] == {**p["L"], "tactile_input": "cycle"}
    assert {k: p["A"][k] for k in p["A"]} == {k: p["L"][k] for k in p["A"]}  # same architecture and epochs
    assert p["H"] == {} and p["H-V"] == {"use_tactile": False} and p["H-T"] == {"use_visual": False}


def test_files_that_repeat_the_methods_repeat_them_exactly():
    p = params("study2")
    assert params("study2-faithful") == p
    assert params("study2-dropout") == {k: v for k, v in p.items() if k != "A"}
    assert params("study2-budget") == {k: p[k] for k in ("L", "L-V")}
    assert scenario("study2-faithful").robot.tactile_model == "penetration"
    assert scenario("study2").robot.tactile_model == "physical"


def test_the_touch_arms_hold_the_benchmark_conditions():
    touch = {e.name: e for e in scenario("study2").evaluations}
    assert list(touch) == ["alike-boxes", "alike-shapes", "distinct-boxes", "distinct-shapes", "distinct-shapes-dusk"]
    assert touch["distinct-shapes-dusk"].query_condition is not None
    dropout = {e.name: e for e in scenario("study2-dropout").evaluations}
    assert dropout["distinct-shapes-dropout"].query_dropout.camera == 0.25
    assert [e.name for e in scenario("study2-faithful").evaluations] == ["E1", "E2", "E3"]


def test_the_preregistered_commands_run_every_arm_over_the_same_eight_or_more_seeds():
    sweeps = re.findall(r"vitaplace sweep scenarios/(study2[\w-]*)\.yaml --seeds ([\d ]+?) --grid "
                        r"scoring\.sequence\.length=1,(\d+)", PREREG)
    assert {arm for arm, _, _ in sweeps} == set(ARMS)
    seeds = {tuple(s.split()) for _, s, _ in sweeps}
    assert len(seeds) == 1 and len(next(iter(seeds))) >= 8
    assert {int(n) for _, _, n in sweeps} == {SEQUENCE_LENGTH}
    assert re.search(r"vitaplace sweep scenarios/study2-budget\.yaml --seeds 0 ", PREREG)
    assert re.search(r"for E in 30 90 270", PREREG)
