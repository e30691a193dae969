"""The study's scenarios (docs/RESULTS.md, "Pre-registration"): six methods on the same runs
per touch model, and a seed that redraws every run and every network's initialisation."""

from pathlib import Path

from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.extension.registry import discover
from vitaplace.engine.pipeline import plan

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
SIX = ["L", "L-V", "L-T", "H", "H-V", "H-T"]


def scenario_of(name: str, seed: int) -> Scenario:
    return load_scenario(str(SCENARIOS / name), [f"seed={seed}"])[0]


def test_each_touch_model_runs_the_six_methods_on_one_set_of_runs():
    for name, touch in (("paper-cpu.yaml", "penetration"), ("paper-cpu-physical.yaml", "physical")):
        scenario = scenario_of(name, 0)
        assert [m.name for m in scenario.methods] == SIX
        assert scenario.robot.tactile_model == touch
        assert scenario.scoring.direction == "both"
        modalities = {m.name: m.params.get("modalities") for m in scenario.methods if m.plugin == "mupnet"}
        assert modalities == {"L": None, "L-V": ["visual"], "L-T": ["tactile"]}


def test_a_seed_redraws_the_training_run_both_drives_and_each_network():
    first, second = scenario_of("paper-cpu.yaml", 0), scenario_of("paper-cpu.yaml", 1)
    registry = discover()
    runs = {label: seed for label, (_, seed) in plan.runs(first).items()}
    other = {label: seed for label, (_, seed) in plan.runs(second).items()}
    assert sorted(runs) == ["E1/query", "E1/reference", "E2/query", "E2/reference", "E3/query", "E3/reference", "train"]
    assert all(runs[label] != other[label] for label in runs)
    assert len(set(runs.values())) == len(runs)  # both drives of a world differ too
    learned = [m for m in first.methods if m.plugin == "mupnet"]
    inits = [plan.params_for(first, registry, m)["seed"] for m in learned]
    assert len(set(inits)) == len(inits)
    assert all(plan.params_for(first, registry, m)["seed"] != plan.params_for(second, registry, m)["seed"]
               for m in learned)
