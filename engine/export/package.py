"""The package: a scenario's runs as a versioned, checksummed folder that a third party can
load and cite, and its reader, `read_package`.

``package/`` holds ``runs/train.h5`` and ``runs/EVALUATION/{query,reference}.h5`` (the run
files as the pipeline recorded them: docs/DATA.md), ``ground_truth/EVALUATION.npz``
(``gtm``: queries x references in metres, +inf where the headings differ by more than the
tolerance; ``true_match``: ``gtm <= tau``; ``query_lacks_camera`` and
``query_lacks_whiskers``: the query samples a drop-out took the sensor from),
``datasheet.json`` and ``datasheet.md`` (the generator's version and commit, the resolved
scenario, seeds, sample counts, sensors, tau and the heading tolerance, the licence) and,
written last, ``SHA256SUMS``: the SHA-256 of every other file, as ``sha256sum -c`` reads it.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.data.dataset import Run, open_run, recorded_tactile_model, run_facts
from vitaplace.engine.export.common import FORMAT_VERSION, ExportError, ExportRun, copy_file, ground_truth, write_npz
from vitaplace.engine.outputs.checksum import digest

PACKAGE = "package"
SUMS = "SHA256SUMS"
DATASHEET_JSON, DATASHEET_MD = "datasheet.json", "datasheet.md"
LICENCE = ("MIT, as the vitaplace software that generated the runs (its LICENSE file); cite vitaplace, its "
           "version and commit, and this package's SHA256SUMS")
_SUM_LINE = re.compile(r"^([0-9a-f]{64})  (\S.*)$")


@dataclass(frozen=True)
class Package:
    """A package read back (`read_package`): its datasheet, its runs by label (``train``,
    ``EVALUATION/query``, ``EVALUATION/reference``) and, per evaluation, its ground truth
    (``gtm``, ``true_match``, ``query_lacks_camera``, ``query_lacks_whiskers``)."""

    folder: Path
    datasheet: dict[str, Any]
    runs: dict[str, Run]
    ground_truth: dict[str, dict[str, np.ndarray]]


def run_path(label: str) -> str:
    """Where run ``label`` lies in a package: ``runs/train.h5``, ``runs/E1/query.h5``."""
    return f"runs/{label}.h5"


def _run_sheet(run: ExportRun, opened: Run) -> dict[str, Any]:
    """What the datasheet says of one run."""
    return {"file": run_path(run.label), "seed": run.seed, "recorded": run.seed is None, **run_facts(opened),
            "image_shape": list(opened.image_shape), "whiskers": opened.n_whiskers,
            "tactile_model": recorded_tactile_model(opened)}


def datasheet(scenario: Scenario, resolved: Mapping[str, Any], runs: Mapping[str, ExportRun],
              opened: Mapping[str, Run], truths: Mapping[str, np.ndarray],
              provenance: Mapping[str, Any]) -> dict[str, Any]:
    """datasheet.json: the format version, the generator, the resolved scenario, the runs and
    each evaluation's ground truth rule and counts (``truths``: its true-match matrix)."""
    evaluations = {}
    for e in scenario.evaluations:
        query = runs[f"{e.name}/query"]
        true = truths[e.name]
        evaluations[e.name] = {
            "query": f"{e.name}/query", "reference": f"{e.name}/reference",
            "ground_truth": f"ground_truth/{e.name}.npz",
            "true_matches": int(true.sum()), "queries_with_a_true_match": int(true.any(axis=1).sum()),
            "query_condition": e.query_condition.model_dump(mode="json") if e.query_condition is not None else None,
            "query_dropout": None if e.query_dropout is None else {**e.query_dropout.model_dump(mode="json"),
                                                                   "seed": query.dropout_seed},
        }
    return {
        "format_version": FORMAT_VERSION, "scenario": scenario.name, "description": scenario.description.strip(),
        "generator": {key: provenance.get(key) for key in ("vitaplace_version", "git_commit", "git_dirty",
                                                            "packages")},
        "seed": scenario.seed,
        "ground_truth_rule": {"tau_m": scenario.scoring.tau,
                              "heading_tolerance_deg": scenario.scoring.heading_tolerance_deg},
        "runs": {label: _run_sheet(run, opened[label]) for label, run in runs.items()},
        "evaluations": evaluations, "licence": LICENCE, "settings": dict(resolved),
    }


def datasheet_markdown(sheet: Mapping[str, Any]) -> str:
    """datasheet.md: datasheet.json for a reader."""
    rule = sheet["ground_truth_rule"]
    heading = ("any heading" if rule["heading_tolerance_deg"] is None
               else f"a heading within {rule['heading_tolerance_deg']:g} degrees (wrapped yaw difference)")
    generator = sheet["generator"]
    lines = [
        f"# {sheet['scenario']}: a vitaplace benchmark package (format {sheet['format_version']})", "",
        sheet["description"] or "(no description)", "",
        f"Generated by vitaplace {generator['vitaplace_version']} (commit {generator['git_commit'] or 'unknown'}"
        f"{', with uncommitted changes' if generator['git_dirty'] else ''}) from scenario seed {sheet['seed']}; "
        "the resolved scenario is `settings` in datasheet.json.", "",
        "| run | file | samples | seed | image | whiskers | deflection samples | contacts | tactile model |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, run in sheet["runs"].items():
        seed = run["seed"] if run["seed"] is not None else "recorded"
        image = "x".join(map(str, run["image_shape"]))
        lines.append(f"| {label} | `{run['file']}` | {run['samples']} | {seed} | {image} | {run['whiskers']}"
                     f" | {run['deflection_samples']} | {run['whisker_contacts']}"
                     f" | {run['tactile_model'] or 'not recorded'} |")
    lines += ["", f"Ground truth: a reference is a true match of a query within {rule['tau_m']:g} m and {heading}.", "",
              "| evaluation | ground truth | true matches | queries with a true match | condition | drop-out |",
              "|---|---|---|---|---|---|"]
    for name, e in sheet["evaluations"].items():
        dropout = json.dumps(e["query_dropout"]) if e["query_dropout"] else "-"
        lines.append(f"| {name} | `{e['ground_truth']}` | {e['true_matches']} | {e['queries_with_a_true_match']} | "
                     f"{'yes' if e['query_condition'] else '-'} | {dropout} |")
    lines += ["", f"Licence: {sheet['licence']}.", "",
              "Read it with `vitaplace.engine.export.read_package(folder)`, which checks every file against "
              f"`{SUMS}` first (or `sha256sum -c {SUMS}` in the folder).", ""]
    return "\n".join(lines)


def write_package(out: Path, scenario: Scenario, resolved: Mapping[str, Any], runs: Mapping[str, ExportRun],
                  provenance: Mapping[str, Any]) -> Path:
    """``scenario``'s runs as a package in ``out/package`` (module docstring); returns the folder."""
    folder = out / PACKAGE
    files = [copy_file(run.path, folder / run_path(label)) for label, run in runs.items()]
    opened = {label: open_run(folder / run_path(label)) for label in runs}
    truths = {}
    for e in scenario.evaluations:
        q, r = opened[f"{e.name}/query"], opened[f"{e.name}/reference"]
        gtm, truths[e.name] = ground_truth(scenario, q.poses, r.poses)
        query = runs[f"{e.name}/query"]
        files.append(write_npz(folder / "ground_truth" / f"{e.name}.npz", gtm=gtm, true_match=truths[e.name],
                               query_lacks_camera=query.lacks("camera", len(q)),
                               query_lacks_whiskers=query.lacks("whiskers", len(q))))
    sheet = datasheet(scenario, resolved, runs, opened, truths, provenance)
    write_text_atomic(folder / DATASHEET_JSON, json.dumps(sheet, indent=2))
    write_text_atomic(folder / DATASHEET_MD, datasheet_markdown(sheet))
    files += [folder / DATASHEET_JSON, folder / DATASHEET_MD]
    sums = "".join(f"{digest(f)}  {f.relative_to(folder).as_posix()}\n" for f in sorted(files))
    write_text_atomic(folder / SUMS, sums)
    return folder


def verified(folder: Path) -> set[str]:
    """The files ``SHA256SUMS`` lists (relative names), each checked against its digest; a
    missing list, a malformed line, a missing file or a changed one is an ExportError naming it."""
    sums = folder / SUMS
    if not sums.is_file():
        raise ExportError(f"{sums}: missing; not a vitaplace package, or its export did not finish")
    listed = set()
    for number, line in enumerate(sums.read_text().splitlines(), 1):
        match = _SUM_LINE.match(line)
        if match is None or PurePosixPath(match.group(2)).is_absolute() or ".." in PurePosixPath(match.group(2)).parts:
            raise ExportError(f"{sums}: line {number} is not '<sha256>  <file in the package>'")
        name = PurePosixPath(match.group(2))
        path = folder / name
        if not path.is_file():
            raise ExportError(f"{path}: listed in {SUMS} but missing")
        if digest(path) != match.group(1):
            raise ExportError(f"{path}: its SHA-256 differs from {SUMS}: the file changed or is damaged")
        listed.add(name.as_posix())
    return listed


def read_package(folder: str | Path) -> Package:
    """The package in ``folder`` (written by ``vitaplace export --format package``), every file
    first checked against its ``SHA256SUMS``: its datasheet, runs and ground truth (`Package`).
    A missing, changed or unlisted file (any file of the folder but ``SHA256SUMS`` itself), or
    another format version, is an ExportError naming it."""
    if not isinstance(folder, (str, os.PathLike)):
        raise ExportError(f"folder={folder!r:.80}: expected the path of a package folder (text or a Path)")
    folder = Path(folder)
    listed = verified(folder)
    unlisted_files = sorted(path for path in folder.rglob("*") if path.is_file() and path != folder / SUMS
                            and path.relative_to(folder).as_posix() not in listed)
    if unlisted_files:  # SHA256SUMS holds every other file: one it lacks was added or left out
        raise ExportError(f"{unlisted_files[0]}: not listed in {folder / SUMS}")
    sheet_path = folder / DATASHEET_JSON
    if DATASHEET_JSON not in listed:
        raise ExportError(f"{sheet_path}: not listed in {folder / SUMS}")
    sheet = json.loads(sheet_path.read_text())
    if sheet.get("format_version") != FORMAT_VERSION:
        raise ExportError(f"{sheet_path}: format_version {sheet.get('format_version')!r}, this vitaplace reads "
                          f"{FORMAT_VERSION}")
    needed = [run["file"] for run in sheet["runs"].values()]
    needed += [e["ground_truth"] for e in sheet["evaluations"].values()]
    unlisted = [name for name in needed if name not in listed]
    if unlisted:
        raise ExportError(f"{folder / unlisted[0]}: not listed in {folder / SUMS}")
    runs = {label: open_run(folder / run["file"]) for label, run in sheet["runs"].items()}
    truths = {}
    for name, e in sheet["evaluations"].items():
        with np.load(folder / e["ground_truth"]) as arrays:
            truths[name] = {key: arrays[key] for key in arrays.files}
    return Package(folder, sheet, runs, truths)
