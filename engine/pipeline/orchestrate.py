"""A run from start to end: the stages of a `Pipeline` in order up to the one asked for, the
result files, the report, the manifest, and last the completion record."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.evaluation.report import write_report
from vitaplace.engine.pipeline import completion, outdir
from vitaplace.engine.pipeline.manifest import write_manifest
from vitaplace.engine.pipeline.results import write_results
from vitaplace.engine.pipeline.runner import STAGES, Pipeline
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
        pipeline.stage("report", "report", pipeline.report_key(rows), out / outdir.REPORT,
                       partial(write_report, pipeline, rows))
    write_manifest(pipeline, time.perf_counter() - started)
    announce_run_finished(pipeline.registry, out, pipeline.scenario, rows, until)
    completion.write(out, finished_files(pipeline, until))
    return rows


def finished_files(pipeline: Pipeline, until: str) -> list[Path]:
    """What a run up to ``until`` wrote for readers outside the pipeline (the completion record
    covers them): the manifest, results and report, each evaluation's summary and PR curve."""
    names = [outdir.MANIFEST]
    if STAGES.index(until) >= STAGES.index("evaluate"):
        names += [outdir.RESULTS_JSON, outdir.RESULTS_CSV]
        names += [str(pipeline.evaluation_dir(e.name, m.name, d).relative_to(pipeline.out) / f)
                  for e in pipeline.scenario.evaluations for m in pipeline.scenario.methods
                  for d, *_ in pipeline.directions() for f in (outdir.SUMMARY, outdir.PR_CURVE)]
    if until == "report":
        names.append(outdir.REPORT)
    return [pipeline.out / name for name in names]
