"""The documentation against the code: generated references are current, and nothing points
outside the repository."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: How a file would cite the design brief and its folder that live outside the repository
#: (built from parts, so this test does not match itself).
OUTSIDE_CITATIONS = ("/".join(["..", "shared", ""]), " ".join(["DESIGN", "§"]))


def test_scenario_reference_is_current():
    from vitaplace.engine.config import schema_docs

    committed = (ROOT / "docs" / "SCENARIOS.md").read_text()
    assert committed == schema_docs.markdown(), (
        "docs/SCENARIOS.md is out of date: python -m vitaplace.engine.config.schema_docs docs/SCENARIOS.md"
    )


def test_every_schema_field_has_a_meaning():
    from vitaplace.engine.config import schema_docs

    undocumented = [line for line in schema_docs.markdown().splitlines() if line.startswith("| `") and line.endswith("|  |")]
    assert not undocumented, undocumented


def test_nothing_cites_documents_outside_the_repository():
    listing = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if listing.returncode != 0:
        pytest.skip("not a git checkout")
    files = listing.stdout.split()
    offenders = []
    for name in files:
        path = ROOT / name
        if path.suffix not in {".py", ".md", ".yaml", ".toml", ".sh", ".txt"} or not path.is_file():
            continue
        text = path.read_text(errors="replace")
        for needle in OUTSIDE_CITATIONS:
            if needle in text:
                offenders.append(f"{name}: {needle}")
    assert not offenders, offenders
