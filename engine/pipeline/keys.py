"""The stages' cache keys, each a function of the scenario's settings and the records of the
outputs the stage reads (their keys and content digests, as DVC keys a stage by the hashes
of its dependencies): a re-run skips finished stages, and a changed input re-runs exactly
what reads it. Bump `STAGE_VERSION` when a stage's output format or algorithm changes."""

from __future__ import annotations

from typing import Any

from vitaplace.engine.config.scenario import EvaluationPair, Fusion, Scenario, TrainingData
from vitaplace.engine.data.dataset import SCHEMA_VERSION
from vitaplace.engine.outputs.keys import content_hash
from vitaplace.engine.pipeline.records import FeaturesFile, ModelFile, RunFile
from vitaplace.engine.sim import SIMULATOR_VERSION
from vitaplace.engine.sim.controllers import key_form
from vitaplace.engine.sim.environment import load_environment

STAGES = ("simulate", "fit", "transform", "evaluate", "report")
#: Bump when a stage's output format or algorithm changes, to invalidate old caches.
STAGE_VERSION = {"simulate": SCHEMA_VERSION, "fit": 3, "transform": 4, "evaluate": 9, "report": 15}
#: the version of a late fusion's evaluation (part of its key)
FUSION_VERSION = 2


def simulate_key(scenario: Scenario, entry: TrainingData | EvaluationPair, label: str, seed: int) -> str:
    """The key of simulated run ``label``: its world, its run settings (in the version-6 key
    form, so keys stay valid), the robot and its seed."""
    assert entry.environment is not None and entry.run is not None  # validated: simulated
    run = entry.run_for(label.rsplit("/", 1)[1]) if isinstance(entry, EvaluationPair) else entry.run
    spec = [load_environment(entry.environment).model_dump(mode="json"), key_form(run)]
    return content_hash("simulate", STAGE_VERSION["simulate"], SIMULATOR_VERSION, spec,
                        scenario.robot.model_dump(mode="json"), seed)


def recorded_key(digest: str) -> str:
    """The key of a recorded run file: its content's SHA-256, so a changed file re-runs what reads it."""
    return content_hash("recorded", STAGE_VERSION["simulate"], digest)


def fit_key(plugin: str, plugin_version: str, code_digest: str, params: dict[str, Any], train: RunFile) -> str:
    """The key of a method's model: its plugin (version and code), the parameters handed to
    it, and the training run."""
    return content_hash("fit", STAGE_VERSION["fit"], plugin, plugin_version, code_digest, params, train.key,
                        train.digest)


def features_key(model: ModelFile, run: RunFile) -> str:
    """The key of one run's features: the model's and the run's, and the run's drop-out when it has one."""
    dropout = [run.dropout_lists()] if run.missing else []
    return content_hash("transform", STAGE_VERSION["transform"], model.key, model.digest, run.key, run.digest, *dropout)


def evaluate_key(model: ModelFile, query: tuple[FeaturesFile, RunFile], reference: tuple[FeaturesFile, RunFile],
                 scenario: Scenario) -> str:
    """The key of one method's evaluation in one direction: the model, both sides' features
    and runs (the poses score them), and the scoring settings."""
    (qf, qrun), (rf, rrun) = query, reference
    return content_hash("evaluate", STAGE_VERSION["evaluate"], model.key, qf.path.name, rf.path.name,
                        [qf.digest, rf.digest], [qrun.digest, rrun.digest],
                        scenario.scoring.model_dump(exclude={"complementarity"}))  # pairs methods, scores none


def fusion_key(fusion: Fusion, chosen_on: str, scenario: Scenario, members: list[str]) -> str:
    """The key of one late fusion's evaluation: its settings, the evaluation its weight is
    chosen on, the scoring settings and the digests of the method evaluations it reads
    (``members``: this evaluation's two and the selection evaluation's two)."""
    return content_hash("evaluate-fusion", FUSION_VERSION, fusion.model_dump(), chosen_on,
                        scenario.scoring.model_dump(exclude={"complementarity"}), members)


def report_key(scenario: Scenario, inputs: dict[str, Any]) -> str:
    """The key of the report: the figures its settings ask for (``report``) and what it reads
    (`vitaplace.engine.report.report.report_key_inputs`)."""
    return content_hash("report", STAGE_VERSION["report"], scenario.report.model_dump(), inputs)
