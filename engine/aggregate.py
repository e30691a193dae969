"""`vitaplace aggregate`: the sweep summary from run folders made by independent jobs.

Each folder is the output of one ``vitaplace run --set seed=N --out DIR`` (or a sweep's
``seed-N``): ``manifest.json`` (written last, so its presence means the run finished),
``results.json`` and ``scenario.resolved.yaml``. Folders must hold one scenario: the same
name in the manifest and the same resolved scenario apart from its seed (environment files
compared by file name, since a sweep job keeps its own copies), and each seed once.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.errors import UserError
from vitaplace.engine.scenario import content_hash
from vitaplace.engine.figures import write_pr_bands
from vitaplace.engine.summary import write_summary

REQUIRED = ("manifest.json", "results.json", "scenario.resolved.yaml")


class AggregateError(UserError):
    """Run folders that cannot be summarised together; the message names the folder."""


def scenario_identity(resolved: dict[str, Any]) -> str:
    """A hash of the resolved scenario without its seed, environments by file name."""
    data = copy.deepcopy({k: v for k, v in resolved.items() if k != "seed"})
    for key in ("train", "evaluations"):
        entries = data.get(key)
        entries = entries if isinstance(entries, list) else [entries]
        for entry in entries:
            if isinstance(entry, dict) and isinstance(entry.get("environment"), str):
                entry["environment"] = Path(entry["environment"]).name
    return content_hash(data)


def read_run(folder: Path) -> tuple[dict[str, Any], str, list[dict[str, Any]]]:
    """(manifest, scenario identity, result rows tagged with the seed) of a finished run folder."""
    missing = [name for name in REQUIRED if not (folder / name).is_file()]
    if missing:
        raise AggregateError(f"{folder}: incomplete run folder (no {', '.join(missing)}); did its run finish?")
    try:
        manifest = json.loads((folder / "manifest.json").read_text())
        rows = json.loads((folder / "results.json").read_text())
        resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise AggregateError(f"{folder}: unreadable run files ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    if not (isinstance(manifest, dict) and isinstance(rows, list) and isinstance(resolved, dict)
            and isinstance(manifest.get("seed"), int) and all(isinstance(r, dict) for r in rows)):
        raise AggregateError(f"{folder}: manifest.json, results.json or scenario.resolved.yaml is not a vitaplace run's")
    return manifest, scenario_identity(resolved), [{"seed": manifest["seed"], **row} for row in rows]


def aggregate_runs(folders: Sequence[Path], out: Path | None = None) -> tuple[Path, dict[str, Any]]:
    """Check that ``folders`` are finished runs of one scenario with distinct seeds and write
    their summary into ``out`` (default: their common parent folder). Returns (out, sweep.json)."""
    folders = [Path(f) for f in folders]
    runs = [(folder, *read_run(folder)) for folder in folders]
    first_folder, first_manifest, first_identity, _ = runs[0]
    seen: dict[int, Path] = {}
    for folder, manifest, identity, _ in runs:
        if manifest.get("scenario") != first_manifest.get("scenario") or identity != first_identity:
            raise AggregateError(
                f"{folder}: scenario '{manifest.get('scenario')}' differs from {first_folder}'s "
                f"'{first_manifest.get('scenario')}' (beyond the seed); aggregate runs of one scenario only"
            )
        if manifest["seed"] in seen:
            raise AggregateError(f"{folder}: seed {manifest['seed']} again (also {seen[manifest['seed']]})")
        seen[manifest["seed"]] = folder
    if out is None:
        parents = {folder.resolve().parent for folder in folders}
        if len(parents) != 1:
            raise AggregateError("the run folders are in different parent folders: give --out")
        out = parents.pop()
    rows = [row for *_, run_rows in runs for row in run_rows]
    name = first_manifest.get("scenario", "scenario")
    info = {"scenario": name, "seeds": sorted(seen), "failed": {}, "folders": {str(s): str(f) for s, f in sorted(seen.items())}}
    record = write_summary(out, rows, f"{name}: {len(seen)} seed(s)", info, seen)
    write_pr_bands(out, seen, rows)
    return out, record
