"""What each stage of a run hands on: records that the next stages key their work by (each
output's path, key and content digest, so every cache key is a function of records alone),
that the manifest (`manifest.manifest_of`), the completion record
(`RunRecord.finished_files`) and, through the manifest, the report read."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.outputs import completion, outdir
from vitaplace.engine.outputs.rows import ResultRow


@dataclass
class StageRecord:
    """One stage of one item: what keyed it (the keys of its inputs), where its output is,
    and whether it ran, came from the cache or is a recorded file."""

    stage: str
    item: str
    key: str
    status: str  # "ran", "cached" or "recorded"
    seconds: float
    inputs: list[str] = field(default_factory=list)  # keys of the upstream outputs it was made from
    output: str = ""  # its output, relative to the output directory when inside the folder holding it


@dataclass(frozen=True)
class RunFile:
    """One run of the scenario as its stages read it: its file, the key it was made (or
    given) for, the SHA-256 of its content, and its query drop-out."""

    label: str  # ``train``, ``E1/query``
    path: Path
    key: str
    digest: str
    recorded: bool  # a run file the scenario gives, not a simulation
    seed: int | None  # the simulation's seed (None for a recorded run)
    facts: dict[str, int]  # `vitaplace.engine.data.dataset.run_facts`
    #: sensor -> samples that lack it (`vitaplace.engine.data.dataset.dropout_masks`); empty without drop-out
    missing: dict[str, np.ndarray] = field(default_factory=dict)
    dropout_seed: int | None = None  # the seed that drew ``missing``

    def dropout_lists(self) -> dict[str, list[int]]:
        """The samples that lack each sensor, as lists of sample indices."""
        return {sensor: np.flatnonzero(mask).tolist() for sensor, mask in self.missing.items()}


@dataclass(frozen=True)
class SimulateRecord:
    """The runs of a scenario, simulated or recorded, by label in the scenario's order."""

    runs: dict[str, RunFile]

    @property
    def datasets(self) -> dict[str, str]:
        """Run label -> the key of its run file."""
        return {label: run.key for label, run in self.runs.items()}

    @property
    def recorded(self) -> dict[str, str]:
        """Run label -> the recorded file given for it (not simulated)."""
        return {label: str(run.path) for label, run in self.runs.items() if run.recorded}

    @property
    def run_seeds(self) -> dict[str, int]:
        """Simulated run label -> its seed."""
        return {label: run.seed for label, run in self.runs.items() if run.seed is not None}

    @property
    def facts(self) -> dict[str, dict[str, int]]:
        """Run label -> `vitaplace.engine.data.dataset.run_facts`."""
        return {label: run.facts for label, run in self.runs.items()}

    @property
    def dropout(self) -> dict[str, dict[str, Any]]:
        """Query run label -> its drop-out: the seed and the samples that lack each sensor."""
        return {label: {"seed": run.dropout_seed, **run.dropout_lists()}
                for label, run in self.runs.items() if run.dropout_seed is not None}


@dataclass(frozen=True)
class ModelFile:
    """One fitted method: its plugin, its model folder, key and content digest."""

    method: str
    plugin: str
    folder: Path
    key: str
    digest: str


@dataclass(frozen=True)
class FitRecord:
    """The fitted models by method, and how each one's training went: per-epoch curves
    (``histories``) and how it ended (``training``, `FeatureExtractor.training_summary`);
    methods that report nothing are left out of both."""

    models: dict[str, ModelFile]
    training: dict[str, dict[str, Any]]
    histories: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class FeaturesFile:
    """The features one method extracted from one run: file, key, content digest."""

    path: Path
    key: str
    digest: str


@dataclass(frozen=True)
class TransformRecord:
    """Per method and evaluation run, its features file and what its features hold
    (`feature_facts`)."""

    files: dict[str, dict[str, FeaturesFile]]
    features: dict[str, dict[str, dict[str, Any]]]


@dataclass(frozen=True)
class EvaluateRecord:
    """The result rows; the content digest of each evaluation folder by (evaluation, method
    or fusion, direction); the files of each evaluation folder readers outside the pipeline
    use (its summary and PR curve); and, once every evaluation is scored, the complementarity
    of each vision-only / touch-only pair per evaluation and direction."""

    rows: list[ResultRow]
    folders: dict[tuple[str, str, str], str]
    files: list[Path]
    complementarity: list[dict[str, Any]] = field(default_factory=list)


@dataclass(frozen=True)
class ReportRecord:
    """report.md and every file it was built from."""

    files: list[Path]


@dataclass
class RunRecord:
    """One run of a scenario up to stage ``until``: who ran what (the settings of its methods,
    the training world), the records of the stages it reached, every stage item's
    `StageRecord`, the warnings its runs raised and how long it took."""

    out: Path
    scenario: str
    seed: int
    until: str
    methods: dict[str, dict[str, Any]]  # method -> plugin, params set, the plugin's defaults
    training_world: str  # which evaluation's threshold f1_at_e1_threshold uses, or why none
    plugins: dict[str, Any]
    simulate: SimulateRecord
    fit: FitRecord | None = None
    transform: TransformRecord | None = None
    evaluate: EvaluateRecord | None = None
    report: ReportRecord | None = None
    stages: list[StageRecord] = field(default_factory=list)
    warnings: dict[str, dict[str, str]] = field(default_factory=dict)  # run label -> feature -> message
    seconds: float = 0.0

    @property
    def rows(self) -> list[ResultRow]:
        """The result rows; none before the evaluate stage."""
        return self.evaluate.rows if self.evaluate is not None else []

    def finished_files(self) -> list[Path]:
        """What the run wrote for readers outside the pipeline (the completion record covers
        them): the manifest, from the evaluate stage on the results and each evaluation's
        summary and PR curve, and after the report stage report.md and every file it is built
        from (`vitaplace.engine.report.report.report_files`)."""
        files = [self.out / outdir.MANIFEST]
        if self.evaluate is not None:
            files += [self.out / outdir.RESULTS_JSON, self.out / outdir.RESULTS_CSV, self.out / outdir.COMPLEMENTARITY,
                      *self.evaluate.files]
        if self.report is not None:
            files += self.report.files
        return [f for f in dict.fromkeys(files) if f.name != completion.SCENARIO]
