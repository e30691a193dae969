"""The study's scenarios (docs/RESULTS.md, "Pre-registration"): six methods on the same runs
per touch model, and a seed that redraws every run and every network's initialisation."""

from pathlib import Path

from vitaplace.engine.pipeline.runner import Pipeline
from vitaplace.engine.config.loading import load_scenario

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
SIX = ["L", "L-V", "L-T", "H", "H-V", "H-T"]


def pipeline(name: str, seed: int) -> Pipeline:
    scenario, resolved = load_scenario(str(SCENARIOS / name), [f"seed={seed}"])
    return Pipeline(scenario, resolved, Path("unused"))


def test_each_touch_model_runs_the_six_methods_on_one_set_of_runs():
    for name, touch in (("paper-cpu.yaml", "penetration"), ("paper-cpu-physical.yaml", "physical")):
        scenario = pipeline(name, 0).scenario
        assert [m.name for m in scenario.methods] == SIX
        assert scenario.robot.tactile_model == touch
        assert scenario.scoring.direction == "both"
        modalities = {m.name: m.params.get("modalities") for m in scenario.methods if m.plugin == "mupnet"}
        assert modalities == {"L": None, "L-V": ["visual"], "L-T": ["tactile"]}


def test_a_seed_redraws_the_training_run_both_drives_and_each_network():
    first, second = pipeline("paper-cpu.yaml", 0), pipeline("paper-cpu.yaml", 1)
    runs = {label: seed for label, (_, seed) in first.runs().items()}
    other = {label: seed for label, (_, seed) in second.runs().items()}
    assert sorted(runs) == ["E1/query", "E1/reference", "E2/query", "E2/reference", "E3/query", "E3/reference", "train"]
    assert all(runs[label] != other[label] for label in runs)
    assert len(set(runs.values())) == len(runs)  # both drives of a world differ too
    learned = [m for m in first.scenario.methods if m.plugin == "mupnet"]
    inits = [first.params_for(m)["seed"] for m in learned]
    assert len(set(inits)) == len(inits)
    assert all(first.params_for(m)["seed"] != second.params_for(m)["seed"] for m in learned)
