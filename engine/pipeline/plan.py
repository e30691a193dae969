"""What a scenario asks the stages for, derived from its settings alone (nothing is run or
read): its runs and their seeds, the run files it gives instead of simulations, each
method's parameters, the scoring directions and the query drop-outs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.config.scenario import EvaluationPair, Method, Scenario, TrainingData
from vitaplace.engine.data.dataset import dropout_masks
from vitaplace.engine.extension.registry import Registry

#: a scoring direction: its name, the side whose samples are the queries, the other side
Direction = tuple[str, str, str]
DIRECTIONS: tuple[Direction, ...] = (("query-to-reference", "query", "reference"),
                                     ("reference-to-query", "reference", "query"))


def seed_for(scenario_seed: int, *path: int) -> int:
    """Independent, reproducible seeds for the runs of a scenario (numpy SeedSequence)."""
    return int(np.random.SeedSequence([scenario_seed, *path]).generate_state(1)[0])


def runs(scenario: Scenario) -> dict[str, tuple[TrainingData | EvaluationPair, int]]:
    """Every run of the scenario: label (``train``, ``E1/query``) -> (its settings, its seed)."""
    found: dict[str, tuple[TrainingData | EvaluationPair, int]] = {
        "train": (scenario.train, seed_for(scenario.seed, 0))}
    for i, e in enumerate(scenario.evaluations):
        found[f"{e.name}/query"] = (e, seed_for(scenario.seed, i + 1, 1))
        found[f"{e.name}/reference"] = (e, seed_for(scenario.seed, i + 1, 2))
    return found


def recorded_files(scenario: Scenario) -> dict[str, Path]:
    """Run label -> the recorded run file the scenario gives for it (not simulated)."""
    files = {"train": scenario.train.dataset} if scenario.train.dataset is not None else {}
    for e in scenario.evaluations:
        files.update({f"{e.name}/{side}": file for side, file in e.recorded().items()})
    return files


def dropout_seed(scenario: Scenario, index: int) -> int:
    """The seed that draws the query drop-out of evaluation ``index`` (its runs' are 1 and 2)."""
    return seed_for(scenario.seed, index + 1, 3)


def dropout_of(scenario: Scenario, label: str, samples: int) -> tuple[dict[str, np.ndarray], int | None]:
    """The drop-out masks of run ``label`` of ``samples`` samples (`dropout_masks`) and the seed
    that drew them: for the query run of an evaluation with a ``query_dropout``, drawn from a
    seed of the scenario seed and the evaluation's place; none for every other run."""
    for i, e in enumerate(scenario.evaluations):
        if e.query_dropout is not None and label == f"{e.name}/query":
            seed = dropout_seed(scenario, i)
            return dropout_masks(samples, e.query_dropout.model_dump(), seed), seed
    return {}, None


def params_for(scenario: Scenario, registry: Registry, method: Method) -> dict[str, Any]:
    """The parameters handed to the method's plugin: the scenario's, with ``seed`` derived from
    the scenario seed when the extractor takes one and the scenario does not set it (so every
    scenario seed also changes the method's initialisation)."""
    params = dict(method.params)
    if "seed" not in params and "seed" in registry.get(method.plugin).Params.model_fields:
        index = [m.name for m in scenario.methods].index(method.name)
        params["seed"] = seed_for(scenario.seed, 1000 + index)
    return params


def method_settings(scenario: Scenario, registry: Registry) -> dict[str, dict[str, Any]]:
    """Per method, as the manifest records it: its plugin, the parameters handed to it
    (`params_for`) and the plugin's defaults for the others."""
    out = {}
    for method in scenario.methods:
        given = params_for(scenario, registry, method)
        full = registry.get(method.plugin).validate_params(given).model_dump(mode="json")
        out[method.name] = {"plugin": method.plugin, "params": {k: full[k] for k in full if k in given},
                            "defaults": {k: v for k, v in full.items() if k not in given}}
    return out


def directions(scenario: Scenario) -> list[Direction]:
    """The scoring directions the scenario asks for (`DIRECTIONS`, one or both)."""
    asked = scenario.scoring.direction
    return [d for d in DIRECTIONS if asked in (d[0], "both")]
