"""The report stage: first what the report reads besides the results (each evaluation's
poses and, when simulated, its world's top view; each method's training curves; the manifest
so far), then report.md and the figures (those of an earlier report removed first) from the output
folder alone (`vitaplace.engine.report.report.write_report`)."""

from __future__ import annotations

import json
import shutil
from functools import partial
from pathlib import Path

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.extension.features import save_features
from vitaplace.engine.outputs import outdir
from vitaplace.engine.pipeline.keys import report_key
from vitaplace.engine.pipeline.manifest import write_manifest
from vitaplace.engine.pipeline.records import ReportRecord, RunRecord
from vitaplace.engine.pipeline.store import Store
from vitaplace.engine.report.report import report_files, report_key_inputs, write_report
from vitaplace.engine.sim.environment import load_environment


def _drawn_anew(out: Path) -> None:
    """`write_report` into ``out`` with its figures drawn anew: none of an earlier report's is left."""
    shutil.rmtree(out / outdir.FIGURES, ignore_errors=True)
    write_report(out)


def report(store: Store, scenario: Scenario, record: RunRecord) -> ReportRecord:
    """report.md of the run ``record`` holds so far, and every file it is built from."""
    for e in scenario.evaluations:
        save_features(outdir.poses_path(store.out, e.name),
                      {side: store.run(record.simulate.runs[f"{e.name}/{side}"]).poses
                       for side in ("query", "reference")})
        if e.environment is not None:
            write_text_atomic(outdir.arena_path(store.out, e.name),
                              json.dumps(load_environment(e.environment).top_view()))
    for method, history in (record.fit.histories if record.fit is not None else {}).items():
        write_text_atomic(outdir.training_path(store.out, method), json.dumps(history))
    write_manifest(record)
    key = report_key(scenario, report_key_inputs(store.out))
    store.stage("report", "report", key, store.out / outdir.REPORT, partial(_drawn_anew, store.out))
    return ReportRecord([store.out / outdir.REPORT, *report_files(store.out, record.rows, list(record.methods))])
