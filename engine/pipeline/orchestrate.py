"""A run from start to end: the stages (`vitaplace.engine.pipeline.stages`) in order up to the
one asked for, each handed the records of the stages before it; the result files, the
report, the manifest, the completion record, and last the plugins' `vitaplace_run_finished`
hooks (trackers; `vitaplace_run_started` before the first stage, `vitaplace_run_failed` when a
stage raises). This is the one place that sequences the stages."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import yaml

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.loading import load_raw, relative_paths
from vitaplace.engine.config.scenario import Scenario, ScenarioError, training_world_evaluation
from vitaplace.engine.extension.registry import (
    announce_run_failed,
    announce_run_finished,
    announce_run_started,
    plugin_distributions,
)
from vitaplace.engine.outputs import completion, stale
from vitaplace.engine.outputs.outdir import difficulty_dir
from vitaplace.engine.outputs.rows import ResultRow
from vitaplace.engine.pipeline.keys import STAGES
from vitaplace.engine.pipeline.manifest import write_manifest
from vitaplace.engine.pipeline.output_checks import PLUGIN_TRACEBACK
from vitaplace.engine.pipeline.records import RunRecord
from vitaplace.engine.pipeline.results import write_results
from vitaplace.engine.pipeline.stages.compare import compare
from vitaplace.engine.pipeline.stages.evaluate import evaluate
from vitaplace.engine.pipeline.stages.fit import fit
from vitaplace.engine.pipeline.stages.fuse import fuse
from vitaplace.engine.pipeline.stages.report import report
from vitaplace.engine.pipeline.stages.simulate import simulate
from vitaplace.engine.pipeline.stages.transform import transform
from vitaplace.engine.pipeline.store import Store

log = logging.getLogger("vitaplace")


def _say_replaced(out: Path, held: str | None, name: str) -> None:
    """Warn when ``out`` holds results (``held``: `stale.held_stage`) of a scenario of another
    name than ``name``: they are replaced (one set of results per folder), which a reader
    should hear of."""
    try:
        before = yaml.safe_load((out / completion.SCENARIO).read_text()).get("name") if held else None
    except (OSError, yaml.YAMLError, AttributeError):
        before = None
    if before is not None and before != name:
        log.warning("%s holds the results of scenario %r: this run of %r replaces them", out, before, name)


def _measured_elsewhere(resolved: dict[str, Any], folder: Path) -> list[str]:
    """The keys (dotted one level deep) in which the finished `vitaplace difficulty` output
    ``folder`` was run on other settings than ``resolved``, beyond the methods, fusions and
    complementarity pairs it replaces and the description and report settings it does not read;
    none when ``folder`` holds no such output."""
    if completion.holder(folder) != "difficulty":
        return []
    try:
        measured = load_raw(folder / completion.SCENARIO)
    except ScenarioError:
        return []
    sides = []
    for data in (resolved, measured):
        data = {k: v for k, v in data.items() if k not in ("methods", "fusions", "description", "report")}
        if isinstance(data.get("scoring"), dict):
            data["scoring"] = {k: v for k, v in data["scoring"].items() if k != "complementarity"}
        sides.append(data)
    ours, theirs = sides
    changed = []
    for key in sorted(set(ours) | set(theirs)):
        a, b = ours.get(key, {}), theirs.get(key, {})
        if isinstance(a, dict) and isinstance(b, dict):
            changed += [f"{key}.{k}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        elif a != b:
            changed.append(key)
    return changed


def run_stages(scenario: Scenario, resolved: dict[str, Any], store: Store, until: str = "report",
               command: str = "run", option: str = "--out") -> list[ResultRow]:
    """Run ``scenario``'s stages into ``store``'s output folder up to and including ``until``,
    and on to the latest stage whose output the folder holds (`stale.held_stage`), for a
    command of kind ``command`` (`completion.KINDS`; a folder holding another kind's
    finished output is refused, naming the folder as ``option``: the API's ``out``);
    ``resolved``: the scenario as read, written beside the results. What the folder held and
    this run did not make is removed at the end (`stale`). Return the result rows (if evaluated)."""
    out = store.out
    out.mkdir(parents=True, exist_ok=True)
    completion.refuse_other(out, command, option)
    held = stale.held_stage(out)
    _say_replaced(out, held, scenario.name)
    if held is not None and STAGES.index(held) > STAGES.index(until):
        log.info("%s holds the %s stage's output: carrying on to it, so that it describes these results", out, held)
        until = held
    before = completion.files_of(out)
    started = time.perf_counter()
    stop = STAGES.index(until)
    announce_run_started(store.registry, out, scenario)  # e.g. a tracker's run, RUNNING from here
    try:
        simulated = simulate(store, scenario)  # first: its runs are recorded before anything reads its methods
        record = RunRecord(out=out, scenario=scenario.name, seed=scenario.seed, until=until,
                           methods=plan.method_settings(scenario, store.registry),
                           training_world=training_world_evaluation(scenario)[1],
                           plugins=plugin_distributions(store.registry), simulate=simulated)
        if stop >= STAGES.index("fit"):
            record.fit = fit(store, scenario, record.simulate)
        if record.fit is not None and stop >= STAGES.index("transform"):
            record.transform = transform(store, scenario, record.simulate, record.fit)
        # the stages so far wrote only into the cache: a folder finished before stays so until here
        unfinish(out, resolved)
        if record.fit is not None and record.transform is not None and stop >= STAGES.index("evaluate"):
            evaluated = evaluate(store, scenario, record.simulate, record.fit, record.transform)
            fused = fuse(store, scenario, record.simulate, evaluated)
            record.evaluate = compare(store, scenario, record.simulate, fused)
            write_results(out, record.evaluate.rows, record.evaluate.complementarity)
        if stop >= STAGES.index("report"):
            record.report = report(store, scenario, closed(record, store, started))
        write_manifest(closed(record, store, started))
        finished = record.finished_files()
        pruned = stale.prune(out, finished)
        for path in pruned + stale.drop_sensitivity(out, before, completion.digests(out, finished)):
            log.info("removed %s: it described other results than this run's", path)
        completion.write(out, finished, command)  # before the plugins: a tracker that stalls loses nothing
        changed = _measured_elsewhere(resolved, difficulty_dir(out))
        if changed:
            log.warning("%s was measured on other settings than these results (%s); `vitaplace difficulty` "
                        "measures them again", difficulty_dir(out), ", ".join(changed))
    except Exception as exc:
        announce_run_failed(store.registry, out, scenario, " ".join(f"{type(exc).__name__}: {exc}".split()))
        raise
    announce_run_finished(store.registry, out, scenario, [row.dump() for row in record.rows], until)
    return record.rows


def unfinish(out: Path, resolved: dict[str, Any]) -> None:
    """Make ``out`` an unfinished run of ``resolved``, just before the first write into the
    folder itself (outside its cache): its completion record and an earlier plugin failure's
    traceback removed, then the resolved scenario written. Until this step a command that
    fails, however, leaves a folder it found finished as it was (but for its own error.txt);
    from it, until the new record, the folder holds no finished run (its results are being
    replaced)."""
    completion.clear(out)
    (out / PLUGIN_TRACEBACK).unlink(missing_ok=True)  # an earlier command's failed plugin call
    write_text_atomic(out / completion.SCENARIO, yaml.safe_dump(relative_paths(resolved, out), sort_keys=False))


def closed(record: RunRecord, store: Store, started: float) -> RunRecord:
    """``record`` with every stage item's record so far, the runs' warnings and the time since ``started``."""
    record.stages = list(store.records)
    record.warnings = store.warnings.raised()
    record.seconds = round(time.perf_counter() - started, 3)
    return record
