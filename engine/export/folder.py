"""The export folder: claimed only when empty or an export of the same formats (its
``export.json`` says which), then written in the layouts asked for."""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.export.common import FORMAT_VERSION, ExportError, ExportRun
from vitaplace.engine.export.package import PACKAGE, write_package
from vitaplace.engine.export.vpr import VPR, write_vpr

#: what says a folder holds an export, and of which formats
MARKER = "export.json"
FORMATS = (VPR, PACKAGE)


def _kind(out: Path) -> list[str] | None:
    """The formats of the export in ``out`` (its `MARKER`), None when it holds none."""
    try:
        formats = json.loads((out / MARKER).read_text()).get("formats")
    except (OSError, ValueError, AttributeError):
        return None
    return formats if isinstance(formats, list) else None


def check_folder(out: Path, formats: Sequence[str]) -> None:
    """``out`` may take an export of ``formats``: absent, empty (but for a lock) or an export of
    the same formats; else one line naming ``--out``."""
    if out.exists() and not out.is_dir():
        raise ExportError(f"--out {out}: exists and is not a folder")
    held = [p for p in out.iterdir() if not p.name.startswith(".vitaplace")] if out.is_dir() else []
    if held and _kind(out) != list(formats):
        raise ExportError(f"--out {out}: not empty and not a vitaplace export of format {'+'.join(formats)} "
                          f"({MARKER}); choose an empty folder")


def write_export(out: Path, scenario: Scenario, resolved: Mapping[str, Any], runs: Mapping[str, ExportRun],
                 formats: Sequence[str], provenance: Mapping[str, Any]) -> list[Path]:
    """``scenario``'s runs exported into ``out`` in ``formats`` (of `FORMATS`), replacing the
    export of the same formats there; returns what it wrote (evaluation folders, the package)."""
    check_folder(out, formats)
    for name in formats:
        shutil.rmtree(out / name, ignore_errors=True)
    write_text_atomic(out / MARKER, json.dumps({"format_version": FORMAT_VERSION, "formats": list(formats),
                                                "scenario": scenario.name}, indent=2))
    written = []
    if VPR in formats:
        written += write_vpr(out, scenario, runs)
    if PACKAGE in formats:
        written.append(write_package(out, scenario, resolved, runs, provenance))
    return written
