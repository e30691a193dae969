"""The stage store (`vitaplace.engine.pipeline.store`): the one done rule, ``force``, and the
run warnings' ledger kept beside a stage's output for a cached rerun."""

from __future__ import annotations

from pathlib import Path

import pluggy
import pytest

from vitaplace.engine.config.scenario import ScenarioError
from vitaplace.engine.extension.registry import Registry
from vitaplace.engine.pipeline.store import Store, WarningLedger


def store(out: Path, *force: str) -> Store:
    return Store(out, force=force, progress=False, registry=Registry(pluggy.PluginManager("vitaplace")), workers=1)


def work_that_writes(output: Path, ledger: WarningLedger, warn: dict[str, dict[str, str]] | None = None):
    """A stage item's work: writes ``output``, raises the run warnings ``warn``, returns 'made'."""
    def work() -> str:
        for label, warnings in (warn or {}).items():
            ledger.of(label).update(warnings)
        output.write_text("made")
        return "made"
    return work


def test_a_stage_runs_once_then_is_cached_and_forced_runs_again(tmp_path):
    output = tmp_path / "a.txt"
    first = store(tmp_path)
    made = first.stage("fit", "m", "key-1", output, work_that_writes(output, first.warnings))
    assert made.result == "made" and [r.status for r in first.records] == ["ran"]
    second = store(tmp_path)
    cached = second.stage("fit", "m", "key-1", output, work_that_writes(output, second.warnings))
    assert cached.result is None and cached.digest == made.digest and second.records[-1].status == "cached"
    assert store(tmp_path).stage("fit", "m", "key-2", output, work_that_writes(output, first.warnings)).result == "made"
    forced = store(tmp_path, "fit")
    assert forced.stage("fit", "m", "key-2", output, work_that_writes(output, forced.warnings)).result == "made"


def test_the_warnings_a_stage_raised_come_back_when_it_is_cached(tmp_path):
    """Run E1/query had a warning before the stage (from the simulate stage, say): only what
    the stage's own work raised is kept beside its output and restored by a cached rerun."""
    output = tmp_path / "a.txt"
    first = store(tmp_path)
    first.warnings.of("E1/query")["earlier"] = "before the stage"
    first.stage("transform", "m E1/query", "k", output, work_that_writes(
        output, first.warnings, {"E1/query": {"PFH": "no contacts"}, "train": {"SDA": "one sample"}}))
    assert first.warnings.raised() == {"E1/query": {"earlier": "before the stage", "PFH": "no contacts"},
                                       "train": {"SDA": "one sample"}}
    second = store(tmp_path)
    second.warnings.of("train")  # opened first this time: the ledger keeps the order runs were opened in
    second.stage("transform", "m E1/query", "k", output, work_that_writes(output, second.warnings))
    assert second.records[-1].status == "cached"
    assert second.warnings.raised() == {"train": {"SDA": "one sample"}, "E1/query": {"PFH": "no contacts"}}


def test_a_stage_that_raises_nothing_leaves_no_warnings_file_behind(tmp_path):
    output = tmp_path / "a.txt"
    first = store(tmp_path)
    first.stage("fit", "m", "k", output, work_that_writes(output, first.warnings, {"train": {"x": "y"}}))
    assert output.with_name("a.txt.warnings.json").is_file()
    again = store(tmp_path, "fit")
    again.stage("fit", "m", "k", output, work_that_writes(output, again.warnings))
    assert not output.with_name("a.txt.warnings.json").exists()


def test_an_unknown_forced_stage_is_one_line():
    with pytest.raises(ScenarioError, match=r"^--force: unknown stage\(s\) fitt; stages: simulate, fit, transform, "
                                            r"evaluate, report$"):
        store(Path("unused"), "fitt")
