"""``vitaplace export SCENARIO --out DIR``: the scenario's runs recorded (or found in the stage
cache) as ``vitaplace simulate`` records them, into a folder of their own (``--runs``, by
default ``runs/<scenario name>-export``), then written into ``--out`` in the layout VPR tools
read, as a checksummed package, or both (`vitaplace.engine.export`)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import vitaplace.engine.pipeline.plan as plan
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.export.common import ExportRun
from vitaplace.engine.export.folder import check_folder, write_export
from vitaplace.engine.export.package import PACKAGE
from vitaplace.engine.export.vpr import VPR
from vitaplace.engine.outputs import outdir
from vitaplace.engine.outputs.stale import held_stage
from vitaplace.engine.pipeline.orchestrate import run_stages
from vitaplace.engine.pipeline.provenance import provenance
from vitaplace.engine.pipeline.store import Store

#: ``--format`` -> the layouts written
FORMATS = {"vpr": (VPR,), "package": (PACKAGE,), "both": (VPR, PACKAGE)}


def stage_runs(scenario: Scenario, stage: Path) -> dict[str, ExportRun]:
    """The runs the simulate stage recorded into folder ``stage`` (its manifest: each run's key,
    seed and samples, a recorded run's file) with each query drop-out (`plan.dropout_of`)."""
    manifest = json.loads((stage / outdir.MANIFEST).read_text())
    runs = {}
    for label, key in manifest["datasets"].items():
        recorded = manifest["recorded"].get(label)
        path = Path(recorded) if recorded else outdir.dataset_file(outdir.cache_dir(stage), label, key)
        missing, dropout_seed = plan.dropout_of(scenario, label, manifest["runs"][label]["samples"])
        runs[label] = ExportRun(label, path, manifest["run_seeds"].get(label), missing, dropout_seed)
    return runs


def check_apart(stage: Path, out: Path) -> None:
    """The runs folder ``stage`` is a folder of its own: not the current folder (what an empty
    ``--runs`` names), not ``out``, neither inside the other (a run folder's claim cleans what
    interrupted writes left anywhere under it, and ``out`` must be empty or an export), not a
    folder holding a run's results; else one line naming the options."""
    if stage.resolve() == Path.cwd().resolve():
        raise UserError(f"--runs {stage}: an empty path or the current folder; expected a folder of their own "
                        "for the runs (default: runs/<scenario name>-export)")
    inner, outer = stage.resolve(), out.resolve()
    if inner.is_relative_to(outer) or outer.is_relative_to(inner):  # the same folder too
        raise UserError(f"--runs {stage}, --out {out}: the folder the runs are recorded into must lie apart from "
                        "--out, neither inside the other")
    held = held_stage(stage)
    if held is not None:  # recording this scenario's runs there would prune that run's results as stale
        shown = outdir.REPORT if held == "report" else outdir.RESULTS_JSON
        raise UserError(f"--runs {stage}: holds a run's results ({shown}); expected a folder for the recorded runs "
                        "alone (default: runs/<scenario name>-export)")


def export_scenario(name: str, overrides: list[str], out: Path, kind: str, runs: Path | None, progress: bool,
                    before_cleaning: Callable[[Path], None] | None = None) -> list[Path]:
    """Export scenario ``name`` (with ``overrides``) into ``out`` as ``kind`` (a key of
    `FORMATS`), its runs recorded or cached in ``runs`` (``before_cleaning``: `claimed`'s);
    returns what was written."""
    scenario, resolved = load_scenario(name, overrides)
    stage = Path(runs) if runs is not None else Path("runs") / f"{scenario.name}-export"
    check_apart(stage, Path(out))
    check_folder(Path(out), FORMATS[kind])  # before any simulation
    with outdir.claimed(stage, before_cleaning) as folder:
        run_stages(scenario, resolved, Store(folder, progress=progress), "simulate")
        found = stage_runs(scenario, folder)
    with outdir.claimed(Path(out)) as target:
        return write_export(target, scenario, resolved, found, FORMATS[kind], provenance())
