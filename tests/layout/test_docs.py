"""The documentation against the code: generated references are current, and nothing points
outside the repository."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: How a file would cite the design brief and its folder that live outside the repository
#: (built from parts, so this test does not match itself).
OUTSIDE_CITATIONS = ("/".join(["..", "shared", ""]), " ".join(["DESIGN", "§"]))


def test_scenario_reference_is_current():
    from vitaplace.engine.cli import schema_docs
    committed = (ROOT / "docs" / "SCENARIOS.md").read_text()
    assert committed == schema_docs.markdown(), (
        "docs/SCENARIOS.md is out of date: python -m vitaplace.engine.cli.schema_docs docs/SCENARIOS.md"
    )


def test_every_schema_field_has_a_description():
    """One way to document a schema field: Field(description=...), read by the generator."""
    from vitaplace.engine.cli import schema_docs
    undocumented = [f"{model.__name__}.{name}" for _, model, _ in schema_docs.SECTIONS
                    for name, field in model.model_fields.items() if not field.description]
    assert not undocumented, undocumented


def test_the_generator_refuses_a_field_without_description():
    import pydantic

    from vitaplace.engine.cli import schema_docs
    class Documented(pydantic.BaseModel):
        size: int = pydantic.Field(3, gt=0, description="how big | how many")

    assert schema_docs.model_table(Documented).splitlines()[-1] == "| `size` | int | `3` | > 0 | how big \\| how many |"

    class Undocumented(pydantic.BaseModel):
        size: int = 3  #: a comment is no description

    with pytest.raises(ValueError, match=r"Undocumented\.size: a schema field needs Field\(description=\.\.\.\)"):
        schema_docs.model_table(Undocumented)


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
