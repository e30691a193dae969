"""Whose finished output a folder holds (`completion.holder`, `refuse_other`) and what a run
removes from its folder (`stale`), on folders laid out by hand."""

import json
from pathlib import Path

import pytest

from vitaplace.engine.outputs import completion, stale
from vitaplace.engine.outputs.outdir import OutputDirError


def lay(folder: Path, *names: str) -> list[Path]:
    """Empty files ``names`` (relative paths) in ``folder``."""
    paths = [folder / name for name in names]
    for path in paths:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(path.name)
    return paths


def record(folder: Path, **fields) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "completed.json").write_text(json.dumps({"scenario": "0" * 64, "files": {}, **fields}))


@pytest.mark.parametrize("layout, expected", [
    ({}, None),  # nothing there
    ({"record": {"command": "difficulty"}}, "difficulty"),
    ({"record": {"command": "run"}}, "run"),
    ({"record": {}}, "run"),  # a record of a version before commands were recorded: a run's
    ({"record": {"command": "who knows"}}, "run"),
    ({"files": ["sweep.json"]}, "summary"),
    ({"files": ["grid.json"], "record": {"command": "run"}}, "summary"),  # a summary's files decide
    ({"files": ["manifest.json", "results.json", "scenario.resolved.yaml"]}, None),  # interrupted: not finished
    ({"files": ["completed.json"]}, None),  # unreadable record ("completed.json" as text)
])
def test_holder_by_hand(tmp_path, layout, expected):
    lay(tmp_path, *layout.get("files", []))
    if "record" in layout:
        record(tmp_path, **layout["record"])
    assert completion.holder(tmp_path) == expected


def test_refuse_other_names_the_option_and_both_kinds_in_one_line(tmp_path):
    record(tmp_path, command="difficulty")
    completion.refuse_other(tmp_path, "difficulty")  # its own kind: no refusal
    completion.refuse_other(tmp_path / "absent", "run")  # nothing finished there: no refusal
    with pytest.raises(OutputDirError) as raised:
        completion.refuse_other(tmp_path, "run", "--into")
    message = str(raised.value)
    assert message.startswith(f"--into {tmp_path}: ") and "\n" not in message
    assert completion.KINDS["difficulty"] in message and completion.KINDS["run"] in message


def test_the_record_names_its_command_and_its_files(tmp_path):
    files = lay(tmp_path, "scenario.resolved.yaml", "results.json", "evaluations/E/M/d/summary.json")
    completion.write(tmp_path, files[1:], "difficulty")
    written = json.loads((tmp_path / "completed.json").read_text())
    assert written["command"] == "difficulty" and completion.holder(tmp_path) == "difficulty"
    import hashlib
    assert completion.files_of(tmp_path) == {
        "results.json": hashlib.sha256(b"results.json").hexdigest(),
        "evaluations/E/M/d/summary.json": hashlib.sha256(b"summary.json").hexdigest()}
    assert completion.files_of(tmp_path / "absent") == {}


@pytest.mark.parametrize("files, expected", [
    ([], None), (["results.json"], "evaluate"), (["report.md"], "report"), (["results.json", "report.md"], "report"),
    (["manifest.json", "complementarity.json"], None),
])
def test_held_stage_by_hand(tmp_path, files, expected):
    lay(tmp_path, *files)
    assert stale.held_stage(tmp_path) == expected


EVALUATION = "evaluations/E1/H/query-to-reference"
GONE = "evaluations/E1/L/query-to-reference"


def test_prune_removes_what_the_run_did_not_write_and_keeps_its_evaluations_whole(tmp_path):
    kept = lay(tmp_path, "manifest.json", "results.json", "results.csv", f"{EVALUATION}/summary.json",
               "poses/E1.npz", "training/H.json")
    beside = lay(tmp_path, f"{EVALUATION}/decisions.csv", f"{EVALUATION}.seal", f"{EVALUATION}.warnings.json",
                 "scenario.resolved.yaml", "log.txt", "cache/models/L-1.seal", "sensitivity.json")
    gone = lay(tmp_path, "report.md", "complementarity.json", f"{GONE}/summary.json", f"{GONE}.seal",
               "evaluations/E2/H/query-to-reference/matrices.npz", f"{EVALUATION}-old.seal",
               "poses/E2.npz", "arenas/E1.json",
               "training/L.json")
    figures = lay(tmp_path, "figures/pr-E1.png")
    removed = stale.prune(tmp_path, kept)
    assert sorted(removed) == sorted([*gone, tmp_path / "figures"])
    assert all(p.is_file() for p in kept + beside) and not any(p.exists() for p in gone + figures)
    # folders left empty go too; those still holding a kept file stay
    assert not (tmp_path / "evaluations" / "E2").exists() and not (tmp_path / "evaluations" / "E1" / "L").exists()
    assert not (tmp_path / "arenas").exists() and (tmp_path / "evaluations" / "E1" / "H").is_dir()


def test_prune_keeps_the_figures_of_a_kept_report(tmp_path):
    kept = lay(tmp_path, "report.md", "results.json")
    figures = lay(tmp_path, "figures/pr-E1.png")
    assert stale.prune(tmp_path, kept) == [] and figures[0].is_file()


SUMMARY, CURVE = f"{EVALUATION}/summary.json", f"{EVALUATION}/pr_curve.npz"


@pytest.mark.parametrize("before, after, dropped", [
    ({SUMMARY: "a", CURVE: "b"}, {SUMMARY: "a", CURVE: "b", "results.json": "x"}, False),  # evaluations the same
    ({SUMMARY: "a"}, {SUMMARY: "a", CURVE: "b"}, False),  # a file one record lists: the others agree
    ({SUMMARY: "a", CURVE: "b"}, {SUMMARY: "a", CURVE: "c"}, True),  # one file changed
    ({SUMMARY: "a"}, {SUMMARY: "a", f"{GONE}/summary.json": "a"}, True),  # an evaluation more
    ({SUMMARY: "a", f"{GONE}/summary.json": "a"}, {SUMMARY: "a"}, True),  # an evaluation fewer
    ({}, {SUMMARY: "a"}, True),  # no finished run before: what it rescored is unknown
])
def test_drop_sensitivity_by_hand(tmp_path, before, after, dropped):
    files = lay(tmp_path, *stale.SENSITIVITY)
    removed = stale.drop_sensitivity(tmp_path, before, after)
    assert removed == (files if dropped else []) and all(p.exists() != dropped for p in files)
