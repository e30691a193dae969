"""One output folder through every command that writes into or reads from it, as a Hypothesis
state machine: ``run``, ``evaluate`` and ``train`` with a changed τ or method list,
``difficulty`` (into ``OUT/difficulty``), ``report OUT``, ``sensitivity OUT``, ``sweep``
and ``aggregate`` (into the folder: refused; beside it), in any order.

The invariant after every step: every file in the folder (and in its difficulty folder)
describes the same results - the completion record matches each file it lists, results.json,
results.csv, the evaluation folders, the manifest and the resolved scenario name the same
evaluations, methods and τ, the report's table and figures show those rows, and the
sensitivity rescoring at the folder's τ gives its numbers. Every command succeeds or
refuses in one line (exit 2).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.outputs import completion  # noqa: E402

ENV_E1 = str(Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml")
TAUS = (0.3, 0.5)
METHODS = {"both": [{"name": "H", "plugin": "handcrafted"},
                    {"name": "V", "plugin": "handcrafted", "params": {"use_tactile": False}}],
           "one": [{"name": "H", "plugin": "handcrafted"}]}


def scenario(methods: str) -> dict:
    return {
        "name": "folder-commands",
        "train": {"environment": ENV_E1, "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": ENV_E1, "run": {"kind": "route", "n_samples": 8}}],
        "methods": METHODS[methods],
        "robot": {"camera_width": 16, "camera_height": 12},
        "scoring": {"tau": TAUS[0]},
    }


def cli(*args: str) -> tuple[int, str]:
    """A vitaplace command in this process: (exit status, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["-q", *args])
    return status, err.getvalue()


def succeeded_or_refused(status: int, err: str) -> bool:
    return status == 0 or (status == 2 and len([line for line in err.splitlines() if line.strip()]) == 1)


def refused(status: int, err: str) -> bool:
    return status == 2 and len([line for line in err.splitlines() if line.strip()]) == 1 and "--out" in err


def report_table(report: str) -> set[tuple[str, str, str, str]]:
    """The (environment, method, direction, max F1 %) of the report's results table."""
    lines = report.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| environment | method | direction | max F1"))
    found = set()
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        found.add((cells[0], cells[1], cells[2], cells[3]))
    return found


def key(row: dict) -> tuple[str, str, str]:
    return row["environment"], row["method"], row["direction"]


def check_describes_the_same_results(folder: Path) -> None:
    """The invariant (module docstring) on one finished folder."""
    listed = completion.files_of(folder)
    assert completion.problem(folder, listed) is None, completion.problem(folder, listed)
    resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
    tau, methods = resolved["scoring"]["tau"], [m["name"] for m in resolved["methods"]]
    manifest = json.loads((folder / "manifest.json").read_text())
    assert list(manifest["methods"]) == methods
    if not (folder / "results.json").is_file():  # simulate or train alone: no result anywhere
        assert not any((folder / name).exists() for name in ("evaluations", "report.md", "figures", "results.csv"))
        return
    rows = json.loads((folder / "results.json").read_text())
    keys = {key(r) for r in rows}
    assert {r["method"] for r in rows} == set(methods) and {r["tau"] for r in rows} == {tau}
    on_disk = {tuple(p.parent.relative_to(folder / "evaluations").parts) for p in
               (folder / "evaluations").glob("*/*/*/summary.json")}
    assert on_disk == keys
    for r in rows:
        summary = json.loads((folder / "evaluations" / r["environment"] / r["method"] / r["direction"] /
                              "summary.json").read_text())
        assert (summary["max_f1"], summary["tau"]) == (r["max_f1"], tau)
    with open(folder / "results.csv", newline="") as f:
        assert {(c["environment"], c["method"], c["direction"], float(c["max_f1"])) for c in csv.DictReader(f)} == {
            (*key(r), r["max_f1"]) for r in rows}
    report = folder / "report.md"
    if report.is_file():
        text = report.read_text()
        assert report_table(text) == {(*key(r), f"{100 * r['max_f1']:.2f}") for r in rows}
        assert f"τ = {tau:g} m" in text
        drawn = {p.stem.split("-", 1)[1] for p in (folder / "figures").glob("matrices-*.png")}
        assert drawn == {"-".join(k) for k in keys}
    else:
        assert not (folder / "figures").exists() and not (folder / "poses").exists()
    sensitivity = folder / "sensitivity.json"
    if sensitivity.is_file():
        own = {key(r): r["max_f1"] for r in json.loads(sensitivity.read_text())["rows"]
               if r["tau"] == tau and r["heading_tolerance_deg"] is not None}
        assert own == {key(r): r["max_f1"] for r in rows}


class FolderCommands(RuleBasedStateMachine):
    """One output folder through a random sequence of commands (see the module docstring)."""

    root: Path

    def __init__(self) -> None:
        super().__init__()
        self.work = Path(self.root) / f"life-{time.monotonic_ns()}"
        self.work.mkdir()
        self.out = self.work / "out"
        for name in METHODS:
            (self.work / f"{name}.yaml").write_text(yaml.safe_dump(scenario(name)))

    def stages(self, command: str, tau: float, methods: str) -> None:
        status, err = cli(command, str(self.work / f"{methods}.yaml"), "--out", str(self.out), "--no-progress",
                          "--set", f"scoring.tau={tau}")
        assert status == 0, err[-2000:]

    @initialize()
    def first_run(self) -> None:
        self.stages("run", TAUS[0], "both")
        self.command_difficulty(TAUS[1])  # every life has a difficulty folder beside the run's files

    @rule(command=st.sampled_from(["run", "evaluate", "train"]), tau=st.sampled_from(TAUS),
          methods=st.sampled_from(sorted(METHODS)))
    def command_stages(self, command: str, tau: float, methods: str) -> None:
        self.stages(command, tau, methods)

    @rule(tau=st.sampled_from(TAUS))
    def command_difficulty(self, tau: float) -> None:
        status, err = cli("difficulty", str(self.work / "one.yaml"), "--out", str(self.out), "--no-progress",
                          "--set", f"scoring.tau={tau}")
        assert status == 0, err[-2000:]
        status, err = cli("evaluate", str(self.work / "one.yaml"), "--out", str(self.out / "difficulty"))
        assert refused(status, err), err[-2000:]  # a run never writes into the difficulty folder

    @rule()
    def command_report(self) -> None:
        assert succeeded_or_refused(*cli("report", str(self.out)))

    @rule()
    def command_sensitivity(self) -> None:
        assert succeeded_or_refused(*cli("sensitivity", str(self.out), "--tau", *map(str, TAUS)))

    @rule(into=st.sampled_from(["out", "difficulty"]))
    def command_sweep_into_the_folder(self, into: str) -> None:
        folder = self.out if into == "out" else self.out / "difficulty"
        if completion.holder(folder) is None:
            return  # nothing finished there: a sweep may write it (not what this machine is about)
        status, err = cli("sweep", str(self.work / "one.yaml"), "--seeds", "0", "--out", str(folder))
        assert refused(status, err), err[-2000:]

    @rule(into=st.sampled_from(["out", "beside"]))
    def command_aggregate(self, into: str) -> None:
        status, err = cli("aggregate", str(self.out), "--out", str(self.out if into == "out" else self.work / "agg"))
        assert refused(status, err) if into == "out" else succeeded_or_refused(status, err), err[-2000:]

    @invariant()
    def every_file_describes_the_same_results(self) -> None:
        for folder in (self.out, self.out / "difficulty"):
            if (folder / "completed.json").is_file():
                check_describes_the_same_results(folder)


def _run_machine(root: Path, examples: int, steps: int) -> None:
    FolderCommands.root = root
    machine = type(f"FolderCommands{examples}", (FolderCommands,), {})  # settings on a class of its own
    settings(max_examples=examples, stateful_step_count=steps, deadline=None, derandomize=True,
             suppress_health_check=list(HealthCheck))(machine)
    machine.TestCase().runTest()


def test_every_file_in_a_folder_describes_the_same_results(tmp_path):
    _run_machine(tmp_path, examples=2, steps=5)


@pytest.mark.slow
def test_thirty_lives_of_a_folder_keep_every_file_describing_the_same_results(tmp_path):
    _run_machine(tmp_path, examples=30, steps=8)


def write_scenarios(folder: Path) -> None:
    for name in METHODS:
        (folder / f"{name}.yaml").write_text(yaml.safe_dump(scenario(name)))


def test_evaluate_into_a_finished_run_remakes_its_report_and_prunes(tmp_path):
    """Issue 49 item 2: an evaluation with another τ and one method fewer into a finished run's
    folder left report.md saying τ 0.3 with the old rows, and the dropped method's files."""
    write_scenarios(tmp_path)
    out = tmp_path / "out"
    assert cli("run", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress")[0] == 0
    assert cli("sensitivity", str(out), "--tau", "0.3")[0] == 0
    assert (out / "figures" / "matrices-E1-V-query-to-reference.png").is_file()
    status, err = cli("evaluate", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress",
                      "--set", "scoring.tau=0.5")
    assert status == 0, err
    check_describes_the_same_results(out)
    assert "τ = 0.5 m" in (out / "report.md").read_text() and "report.md" in completion.files_of(out)
    assert not (out / "evaluations" / "E1" / "V").exists() and not list((out / "figures").glob("*-V-*"))
    assert not (out / "sensitivity.json").exists()  # it rescored the evaluations that are gone


def test_a_rerun_of_the_same_results_keeps_the_sensitivity_rescoring(tmp_path):
    write_scenarios(tmp_path)
    out = tmp_path / "out"
    assert cli("run", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress")[0] == 0
    assert cli("sensitivity", str(out), "--tau", "0.3")[0] == 0
    assert cli("evaluate", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress")[0] == 0
    assert (out / "sensitivity.json").is_file() and (out / "report.md").is_file()
    check_describes_the_same_results(out)


def test_difficulty_after_a_run_reuses_its_stages_and_leaves_its_results_alone(tmp_path):
    """Issue 49 item 2 and issue 50 item 4: `difficulty --out DIR` on a finished run replaced
    its results, and by default it simulated every run again in a folder of its own."""
    write_scenarios(tmp_path)
    out = tmp_path / "out"
    assert cli("run", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress")[0] == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and "cache" not in p.parts}
    status, err = cli("difficulty", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress")
    assert status == 0, err
    assert {p: p.read_bytes() for p in before if p.is_file()} == before  # not one byte of the run changed
    check_describes_the_same_results(out)
    check_describes_the_same_results(out / "difficulty")
    stages = json.loads((out / "difficulty" / "manifest.json").read_text())["stages"]
    status_of = {(s["stage"], s["item"]): s["status"] for s in stages}
    assert {item for (stage, item), s in status_of.items() if stage == "simulate"} == {
        "train", "E1/query", "E1/reference"}
    assert all(s == "cached" for (stage, _), s in status_of.items() if stage == "simulate")
    assert status_of[("fit", "H")] == "cached" and status_of[("fit", "H-V")] == "ran"  # the run fitted H alone
    assert not (out / "difficulty" / "cache").exists()  # its stages are cached in the run's folder
    assert cli("report", str(out))[0] == 0
    # re-scored on the settings difficulty measured: silent; at another tau: difficulty/ is said to be stale
    status, err = cli("evaluate", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress",
                      "--set", "description=the same run, other words")  # a key difficulty does not read
    assert status == 0 and "measured on other settings" not in err, err
    status, err = cli("evaluate", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress",
                      "--set", f"scoring.tau={TAUS[1]}")
    assert status == 0, err
    assert f"{out / 'difficulty'} was measured on other settings than these results (scoring.tau)" in err, err


def test_a_sweeps_seed_folder_has_its_report_rebuilt(tmp_path):
    """`vitaplace report SWEEP/seed-S`: a seed folder holds its finished run (completed.json)
    but no claim of its own (the sweep held its folder's): it was refused as "not a folder
    vitaplace wrote". It is rebuilt as the sweep wrote it."""
    write_scenarios(tmp_path)
    sweep = tmp_path / "sweep"
    assert cli("sweep", str(tmp_path / "one.yaml"), "--seeds", "3", "--out", str(sweep), "--no-progress")[0] == 0
    seed = sweep / "seed-3"
    assert not (seed / ".vitaplace.lock").exists()
    written = (seed / "report.md").read_text()
    (seed / "report.md").unlink()
    status, err = cli("report", str(seed))
    assert status == 0, err
    assert (seed / "report.md").read_text() == written


@pytest.mark.parametrize("command", [
    ["evaluate", "{one}", "--out", "{out}/difficulty"],  # a run into the difficulty folder
    ["difficulty", "{one}", "--out", "{out}/difficulty"],  # difficulty given its own folder as --out
    ["sweep", "{one}", "--seeds", "0", "--out", "{out}"],  # a sweep into a run's folder
    ["aggregate", "{out}", "--out", "{out}"],  # a summary into a run's folder
    ["sensitivity", "{out}", "--out", "{out}/difficulty"],  # one folder's rescoring into another's
])
def test_a_command_refuses_a_folder_holding_another_commands_output_in_one_line(tmp_path, command):
    write_scenarios(tmp_path)
    out = tmp_path / "out"
    assert cli("difficulty", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress")[0] == 0
    assert cli("evaluate", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress")[0] == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name not in ("log.txt", ".vitaplace.lock")}
    status, err = cli(*(part.format(one=tmp_path / "one.yaml", out=out) for part in command))
    assert refused(status, err), err
    assert {p: p.read_bytes() for p in before if p.is_file()} == before


def finished_files(folder: Path) -> dict[Path, bytes]:
    """Every file of ``folder`` a reader may read: all but the stage cache, the log and the lock."""
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()
            and "cache" not in p.relative_to(folder).parts and p.name not in ("log.txt", ".vitaplace.lock")}


def test_a_rerun_that_fails_leaves_a_finished_folder_as_it_was(tmp_path, monkeypatch):
    """A rerun into a finished run's folder that stopped at its fit (a one-line user error) had
    removed completed.json and written its own scenario.resolved.yaml beside the earlier run's
    results: `report OUT` and `aggregate` then refused the folder, a finished result lost by a
    failed command. Each command below fails before it writes into the folder itself (outside
    its cache), by a user error at the fit or by Ctrl-C at the transform, and not one byte a
    reader reads changes."""
    write_scenarios(tmp_path)
    mupnet = {**scenario("one"), "methods": [{"name": "M", "plugin": "mupnet", "params": {"epochs": 1}}]}
    (tmp_path / "mupnet.yaml").write_text(yaml.safe_dump(mupnet))  # its fit refuses a run that touches nothing
    out = tmp_path / "out"
    assert cli("run", str(tmp_path / "both.yaml"), "--out", str(out), "--no-progress")[0] == 0
    assert cli("difficulty", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress")[0] == 0
    before, difficulty = finished_files(out), finished_files(out / "difficulty")
    for command in ("run", "evaluate", "report", "train"):
        status, err = cli(command, str(tmp_path / "mupnet.yaml"), "--out", str(out), "--no-progress")
        assert status == 2 and err.count("vitaplace: error:") == 1 and "touches anything" in err, err[-2000:]
        assert finished_files(out) == before, command
    import vitaplace.engine.pipeline.orchestrate as orchestrate

    def interrupted(*args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(orchestrate, "transform", interrupted)
    for command in ("run", "evaluate"):
        status, err = cli(command, str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress",
                          "--set", "scoring.tau=0.5")
        assert status == 130, err[-2000:]
        assert finished_files(out) == before, command
    status, err = cli("difficulty", str(tmp_path / "one.yaml"), "--out", str(out), "--no-progress",
                      "--set", "scoring.tau=0.5")
    assert status == 130 and finished_files(out / "difficulty") == difficulty, err[-2000:]
    monkeypatch.undo()
    check_describes_the_same_results(out)
    check_describes_the_same_results(out / "difficulty")
    assert cli("report", str(out))[0] == 0 and cli("aggregate", str(out), "--out", str(tmp_path / "agg"))[0] == 0
