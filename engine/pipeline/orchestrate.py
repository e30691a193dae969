"""A run from start to end: the stages of a `Pipeline` in order up to the one asked for, the
result files, the report, the manifest, and last the completion record."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.evaluation.report import report_files, report_key_inputs, write_report
from vitaplace.engine.pipeline import completion, outdir
from vitaplace.engine.pipeline.manifest import write_manifest
from vitaplace.engine.pipeline.results import write_results
from vitaplace.engine.pipeline.keys import content_hash
from vitaplace.engine.pipeline.runner import STAGE_VERSION, STAGES, Pipeline
from vitaplace.engine.plugins import announce_run_finished


def run_stages(pipeline: Pipeline, until: str = "report") -> list[dict[str, Any]]:
    """Run ``pipeline``'s stages up to and including ``until``; return the result rows (if evaluated)."""
    out = pipeline.out
    out.mkdir(parents=True, exist_ok=True)
    completion.clear(out)  # first: until the new record, the folder holds no finished run
    write_text_atomic(out / completion.SCENARIO, yaml.safe_dump(pipeline.resolved, sort_keys=False))
    started = time.perf_counter()
    rows: list[dict[str, Any]] = []
    stop = STAGES.index(until)
    pipeline.simulate()
    if stop >= STAGES.index("fit"):
        pipeline.fit()
    if stop >= STAGES.index("transform"):
        pipeline.transform()
    if stop >= STAGES.index("evaluate"):
        rows = pipeline.evaluate()
        write_results(out, rows)
    if stop >= STAGES.index("report"):
        report_stage(pipeline, started)
    write_manifest(pipeline, time.perf_counter() - started, until)
    announce_run_finished(pipeline.registry, out, pipeline.scenario, rows, until)
    completion.write(out, finished_files(pipeline, until, rows))
    return rows


def report_stage(pipeline: Pipeline, started: float) -> None:
    """The report stage: first what the report reads besides the results (the poses, arenas,
    training curves, the manifest so far), then report.md and the figures from the output
    folder alone (`vitaplace.engine.evaluation.report.write_report`)."""
    pipeline.write_report_inputs()
    write_manifest(pipeline, time.perf_counter() - started, "report")
    key = content_hash("report", STAGE_VERSION["report"], report_key_inputs(pipeline.out))
    pipeline.stage("report", "report", key, pipeline.out / outdir.REPORT, partial(write_report, pipeline.out))


def finished_files(pipeline: Pipeline, until: str, rows: list[dict[str, Any]]) -> list[Path]:
    """What a run up to ``until`` wrote for readers outside the pipeline (the completion record
    covers them): the manifest, results and report, each evaluation's summary and PR curve,
    and every file the report is built from (`report_files`)."""
    out = pipeline.out
    files = [out / outdir.MANIFEST]
    if STAGES.index(until) >= STAGES.index("evaluate"):
        files += [out / outdir.RESULTS_JSON, out / outdir.RESULTS_CSV]
        files += [outdir.evaluation_dir(out, e.name, m.name, d) / f
                  for e in pipeline.scenario.evaluations for m in pipeline.scenario.methods
                  for d, *_ in pipeline.directions() for f in (outdir.SUMMARY, outdir.PR_CURVE)]
    if until == "report":
        files += [out / outdir.REPORT, *report_files(out, rows, [m.name for m in pipeline.scenario.methods])]
    return [f for f in dict.fromkeys(files) if f.name != completion.SCENARIO]
