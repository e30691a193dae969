"""A run from start to end: the stages of a `Pipeline` in order up to the one asked for, the
result files, the report, the manifest, and last the completion record."""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import yaml

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.report.report import report_files, report_key_inputs, write_report
from vitaplace.engine.outputs import completion
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.manifest import write_manifest
from vitaplace.engine.pipeline.results import write_results
from vitaplace.engine.outputs.keys import content_hash
from vitaplace.engine.pipeline.records import ReportRecord, RunRecord
from vitaplace.engine.pipeline.runner import STAGE_VERSION, STAGES, Pipeline
from vitaplace.engine.extension.registry import announce_run_finished


def run_stages(pipeline: Pipeline, until: str = "report") -> list[dict[str, Any]]:
    """Run ``pipeline``'s stages up to and including ``until``; return the result rows (if evaluated)."""
    out = pipeline.out
    out.mkdir(parents=True, exist_ok=True)
    completion.clear(out)  # first: until the new record, the folder holds no finished run
    write_text_atomic(out / completion.SCENARIO, yaml.safe_dump(pipeline.resolved, sort_keys=False))
    started = time.perf_counter()
    stop = STAGES.index(until)
    record = pipeline.run_record(until, pipeline.simulate())
    if stop >= STAGES.index("fit"):
        record.fit = pipeline.fit()
    if stop >= STAGES.index("transform"):
        record.transform = pipeline.transform()
    if stop >= STAGES.index("evaluate"):
        record.evaluate = pipeline.evaluate()
        write_results(out, record.evaluate.rows, record.evaluate.complementarity)
    if stop >= STAGES.index("report"):
        record.report = report_stage(pipeline, record, started)
    write_manifest(pipeline.close_record(record, time.perf_counter() - started))
    announce_run_finished(pipeline.registry, out, pipeline.scenario, record.rows, until)
    completion.write(out, record.finished_files())
    return record.rows


def report_stage(pipeline: Pipeline, record: RunRecord, started: float) -> ReportRecord:
    """The report stage: first what the report reads besides the results (the poses, arenas,
    training curves, the manifest so far), then report.md and the figures from the output
    folder alone (`vitaplace.engine.report.report.write_report`)."""
    pipeline.write_report_inputs()
    write_manifest(pipeline.close_record(record, time.perf_counter() - started))
    key = content_hash("report", STAGE_VERSION["report"], report_key_inputs(pipeline.out))
    pipeline.stage("report", "report", key, pipeline.out / outdir.REPORT, partial(write_report, pipeline.out))
    return ReportRecord([pipeline.out / outdir.REPORT, *report_files(pipeline.out, record.rows, list(record.methods))])
