"""The settings of a run (`RunSpec`): their cache keys, old inputs, the settings per kind.

The contract of issue 28's split of the settings per run kind is "keys unchanged": every
simulated run of every shipped scenario keeps its pipeline cache key and its run hash, so
existing caches and recorded run files stay valid. `SHIPPED_KEYS` were recorded from commit
c786d7a's code (one flat ``RunSpec`` whose dump left out the foraging gains at their
defaults), before anything was changed; ``tests/data/run_settings_c786d7a.json`` holds that
code's dumps (the flat dicts written into run files) and run hashes of a few runs set
away from the defaults."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.config.loading import load_scenario  # noqa: E402
from vitaplace.engine.config.scenario import EvaluationPair  # noqa: E402
from vitaplace.engine.pipeline.keys import content_hash  # noqa: E402
from vitaplace.engine.pipeline.runner import STAGE_VERSION, seed_for  # noqa: E402
from vitaplace.engine.sim import SIMULATOR_VERSION  # noqa: E402
from vitaplace.engine.sim.environment import load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import run_hash  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OLD = json.loads((ROOT / "tests" / "data" / "run_settings_c786d7a.json").read_text())

#: "scenario:run label" -> (the pipeline's simulate key, the run hash), recorded from commit
#: c786d7a's code: the contract is that they never change for the same inputs
SHIPPED_KEYS: dict[str, tuple[str, str]] = {
    "coloured-cpu:train": ("addcbb01425116bf", "8b48ad74b510bac6"),
    "coloured-cpu:E1c/query": ("1c667aecc3cd8dfd", "2f95f9662d75858f"),
    "coloured-cpu:E1c/reference": ("dfc9be6a4fc00141", "e93769820852abc1"),
    "near-duplicate:train": ("0c8a35af5f797e30", "7a9272b1af78b891"),
    "near-duplicate:E1/query": ("37deac1bd7f32fb1", "1e9a37cf5fdaca7f"),
    "near-duplicate:E1/reference": ("4bc502ebb53995f5", "384fda19ba336416"),
    "paper-cpu-physical:train": ("d66368adc610966d", "8a79d7f7b0491387"),
    "paper-cpu-physical:E1/query": ("7b33658161a3194b", "a86fd02121d2bffb"),
    "paper-cpu-physical:E1/reference": ("68e4b2ad8f22252c", "1d4874cf9d1ee4ea"),
    "paper-cpu-physical:E2/query": ("9473d3c2e29639af", "81ffc931b4e09db9"),
    "paper-cpu-physical:E2/reference": ("d49ba5be102c7a46", "f9ffd3d78f420328"),
    "paper-cpu-physical:E3/query": ("34826e8c071309cb", "2f107b03d506ae1a"),
    "paper-cpu-physical:E3/reference": ("b3f454e6b21e6c29", "3ae3f381ced93956"),
    "paper-cpu:train": ("e135e4304bf0b0cc", "f1bf39c866b00568"),
    "paper-cpu:E1/query": ("ed66df4fe4b68c33", "2a6f6fe4b715dee7"),
    "paper-cpu:E1/reference": ("49bc82a9169184a0", "85c15517226e3447"),
    "paper-cpu:E2/query": ("e10b19196de3dcbe", "a589313a5bd7f073"),
    "paper-cpu:E2/reference": ("8ed93d65c664308b", "9627e5abb698f563"),
    "paper-cpu:E3/query": ("5e74bf2b4850126a", "a72fcbcad3232cb5"),
    "paper-cpu:E3/reference": ("0c813d6eaa63f9e7", "dee6a6ac92dd6bd1"),
    "paper:train": ("f50d90a16d297d5c", "11fb4d1150ce1053"),
    "paper:E1/query": ("ed66df4fe4b68c33", "2a6f6fe4b715dee7"),
    "paper:E1/reference": ("49bc82a9169184a0", "85c15517226e3447"),
    "paper:E2/query": ("e10b19196de3dcbe", "a589313a5bd7f073"),
    "paper:E2/reference": ("8ed93d65c664308b", "9627e5abb698f563"),
    "paper:E3/query": ("5e74bf2b4850126a", "a72fcbcad3232cb5"),
    "paper:E3/reference": ("0c813d6eaa63f9e7", "dee6a6ac92dd6bd1"),
    "quickstart:train": ("0c8a35af5f797e30", "7a9272b1af78b891"),
    "quickstart:E1/query": ("3a5b0ecffc88412a", "35445e81e3cc8b71"),
    "quickstart:E1/reference": ("9eb15c1a1ce006a8", "b7db118f0550f96c"),
}


def settings(data: dict):
    from vitaplace.engine.sim import controllers

    return controllers.run_spec(data) if hasattr(controllers, "run_spec") else controllers.RunSpec(**data)


def shipped_keys() -> dict[str, tuple[str, str]]:
    """The keys of every simulated run of every shipped scenario, computed as the pipeline does."""
    keys = {}
    for path in sorted((ROOT / "scenarios").glob("*.yaml")):
        scenario, _ = load_scenario(path)
        runs = {"train": (scenario.train, seed_for(scenario.seed, 0))}
        for i, e in enumerate(scenario.evaluations):
            runs[f"{e.name}/query"] = (e, seed_for(scenario.seed, i + 1, 1))
            runs[f"{e.name}/reference"] = (e, seed_for(scenario.seed, i + 1, 2))
        for label, (entry, seed) in runs.items():
            env = load_environment(entry.environment)
            run = entry.run_for(label.rsplit("/", 1)[1]) if isinstance(entry, EvaluationPair) else entry.run
            dumped = run.canonical() if hasattr(run, "canonical") else run.model_dump(mode="json")
            key = content_hash("simulate", STAGE_VERSION["simulate"], SIMULATOR_VERSION,
                               [env.model_dump(mode="json"), dumped], scenario.robot.model_dump(mode="json"), seed)
            keys[f"{path.stem}:{label}"] = (key, run_hash(env, run, scenario.robot, seed))
    return keys


def test_the_runs_of_every_shipped_scenario_keep_their_cache_keys_and_run_hashes():
    assert shipped_keys() == SHIPPED_KEYS


@pytest.mark.parametrize("name", sorted(OLD))
def test_runs_set_away_from_the_defaults_keep_their_run_hashes(name):
    """The old code's run hash of each recorded example, for the same settings given today."""
    old = OLD[name]
    assert run_hash(load_environment("e1"), settings(old["given"]), RobotSpec(), 0) == old["run_hash_e1_seed0"]
