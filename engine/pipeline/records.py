"""What each stage of a run hands on: small records that the manifest (`manifest.manifest_of`),
the completion record (`RunRecord.finished_files`) and, through the manifest, the report read
instead of the `Pipeline` that made them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vitaplace.engine.outputs import completion, outdir


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
    output: str = ""  # its output, relative to the output directory when inside it


@dataclass(frozen=True)
class SimulateRecord:
    """The runs of a scenario, simulated or recorded."""

    datasets: dict[str, str]  # run label -> the key of its run file
    recorded: dict[str, str]  # run label -> the recorded file given for it (not simulated)
    run_seeds: dict[str, int]  # simulated run label -> its seed
    runs: dict[str, dict[str, int]]  # run label -> `vitaplace.engine.data.dataset.run_facts`
    #: query run label -> its drop-out: seed and the samples lacking each sensor (`Pipeline.dropout_record`)
    dropout: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class FitRecord:
    """How each method's training ended (`FeatureExtractor.training_summary`; methods that
    report nothing are left out)."""

    training: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class TransformRecord:
    """Per method and evaluation run, what its features hold (`feature_facts`)."""

    features: dict[str, dict[str, dict[str, Any]]]


@dataclass(frozen=True)
class EvaluateRecord:
    """The result rows, the complementarity of each vision-only / touch-only pair per
    evaluation and direction, and the files of each evaluation folder readers outside the
    pipeline use (its summary and PR curve)."""

    rows: list[dict[str, Any]]
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
    def rows(self) -> list[dict[str, Any]]:
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
