"""The life of an output folder, as a Hypothesis state machine: runs, reruns with a changed
setting, ``--force STAGE``, a run killed at a random moment, a rerun that fails (a user error
or Ctrl-C at a stage before it writes into the folder), an edited plugin, a corrupted file,
``aggregate``, ``sensitivity`` and ``read_results``, in any order.

The invariant after every step: any number a command returns or writes equals the number a
clean run of the scenario the folder holds gives (its ``scenario.resolved.yaml``, with the
plugin code of the run that completed it), or the command refuses in one line (exit 2, one
line on stderr; ``read_results``: a UserError). Clean references are computed once per
(setting, plugin code) in folders of their own.

The method is a test-only plugin whose features are the true positions (every query finds its
place) or, in its edited code, the query run's positions in reverse order (most do not), so
an edit changes every number; the scenario's setting is the revisit tolerance τ.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import pytest
import yaml
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from conftest import install_plugin

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.base.errors import UserError  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.pipeline import orchestrate  # noqa: E402

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"
MODULE = "vitaplace_folder_life"
PLUGIN = '''
import numpy as np
from scipy.spatial.distance import cdist
from vitaplace.engine.extension.features import FeatureExtractor
from vitaplace.engine.extension.hookspecs import hookimpl

REVERSED = False


class Positions(FeatureExtractor):
    """Test-only: the true positions as features (with REVERSED, the query run's reversed)."""
    name = "positions"
    def fit(self, train): pass
    def transform(self, run):
        xy = np.asarray(run.poses[:, :2], dtype=np.float64)
        return {"xy": xy[::-1].copy() if REVERSED and run.name.endswith("query") else xy}
    def distance(self, query, reference): return cdist(query["xy"], reference["xy"])
    def save_state(self, directory): pass
    def load_state(self, directory): pass


@hookimpl
def vitaplace_register_features(register):
    register(Positions)
'''
CODES = {"plain": PLUGIN, "reversed": PLUGIN.replace("REVERSED = False", "REVERSED = True")}
TAUS = (0.3, 0.5)
STAGES = ("simulate", "fit", "transform", "evaluate")


def scenario(tau: float) -> dict:
    return {
        "name": "folder-life",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 8}}],
        "methods": [{"name": "P", "plugin": "positions"}],
        "robot": {"camera_width": 16, "camera_height": 12},
        "scoring": {"tau": tau, "direction": "both"},
    }


def scores(rows: list[dict]) -> dict[tuple[str, str, str], tuple[float, float]]:
    return {(r["environment"], r["method"], r["direction"]): (r["max_f1"], r["recall_at_100_precision"]) for r in rows}


def cli(*args: str) -> tuple[int, str]:
    """A vitaplace command in this process: (exit status, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        status = main([*args, "-q"] if args[0] in ("run", "evaluate") else list(args))
    return status, err.getvalue()


def refused_in_one_line(status: int, err: str) -> bool:
    lines = [line for line in err.splitlines() if line.strip()]
    return status == 2 and len(lines) == 1


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The test plugin installed in a folder on this process's path (VITAPLACE_PLUGINS names it)."""
    folder = tmp_path_factory.mktemp("site")
    install_plugin(folder, MODULE, PLUGIN, "vitaplace-folder-life", "1.0", "positions")
    sys.path.insert(0, str(folder))
    old = os.environ.get("VITAPLACE_PLUGINS")
    os.environ["VITAPLACE_PLUGINS"] = "positions"
    yield folder
    sys.path.remove(str(folder))
    sys.modules.pop(MODULE, None)
    if old is None:
        os.environ.pop("VITAPLACE_PLUGINS", None)
    else:
        os.environ["VITAPLACE_PLUGINS"] = old


class FolderLife(RuleBasedStateMachine):
    """One output folder through a random sequence of commands (see the module docstring)."""

    site: Path
    root: Path
    references: dict[tuple[float, str], dict] = {}

    def __init__(self) -> None:
        super().__init__()
        self.work = Path(self.root) / f"life-{time.monotonic_ns()}"
        self.work.mkdir()
        self.out = self.work / "out"
        self.tau, self.code = TAUS[0], "plain"
        self.folder_code: str | None = None  # the plugin code of the run that completed the folder
        self.write_scenario()
        self.set_code("plain")

    # ---------------------------------------------------------------- helpers
    def write_scenario(self) -> None:
        (self.work / "s.yaml").write_text(yaml.safe_dump(scenario(self.tau)))

    def set_code(self, code: str) -> None:
        (Path(self.site) / f"{MODULE}.py").write_text(CODES[code])
        sys.modules.pop(MODULE, None)  # a user's next command is a new process: it imports the new code
        self.code = code

    def reference(self, tau: float, code: str) -> dict:
        key = (tau, code)
        if key not in self.references:
            current = self.code
            self.set_code(code)
            folder = Path(self.root) / f"reference-{tau}-{code}"
            (folder.parent / f"{folder.name}.yaml").write_text(yaml.safe_dump(scenario(tau)))
            assert main(["evaluate", str(folder.parent / f"{folder.name}.yaml"), "--out", str(folder), "-q"]) == 0
            self.references[key] = scores(json.loads((folder / "results.json").read_text()))
            self.set_code(current)
        return self.references[key]

    def expected(self) -> dict:
        """The clean numbers of the scenario the folder holds, with its completing run's code."""
        resolved = yaml.safe_load((self.out / "scenario.resolved.yaml").read_text())
        return self.reference(resolved["scoring"]["tau"], self.folder_code or self.code)

    def completion_mark(self) -> int | None:
        record = self.out / "completed.json"
        return record.stat().st_mtime_ns if record.exists() else None

    def after_run(self, before: int | None, code: str) -> None:
        if self.completion_mark() != before:
            self.folder_code = code

    # ---------------------------------------------------------------- rules
    @initialize()
    def first_run(self) -> None:
        self.command_run()

    @rule()
    def command_run(self) -> None:
        before = self.completion_mark()
        status, err = cli("evaluate", str(self.work / "s.yaml"), "--out", str(self.out), "--no-progress")
        assert status == 0 or refused_in_one_line(status, err), err[-2000:]
        self.after_run(before, self.code)
        if status == 0:
            assert scores(json.loads((self.out / "results.json").read_text())) == self.expected()

    @rule(tau=st.sampled_from(TAUS))
    def change_setting(self, tau: float) -> None:
        self.tau = tau
        self.write_scenario()

    @rule(stage=st.sampled_from(STAGES))
    def command_force(self, stage: str) -> None:
        before = self.completion_mark()
        status, err = cli("evaluate", str(self.work / "s.yaml"), "--out", str(self.out), "--no-progress", "--force",
                          stage)
        assert status == 0 or refused_in_one_line(status, err), err[-2000:]
        self.after_run(before, self.code)
        if status == 0:
            assert scores(json.loads((self.out / "results.json").read_text())) == self.expected()

    @rule(delay=st.sampled_from([0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0]))  # from before the first write to after the last
    def command_killed(self, delay: float) -> None:
        before = self.completion_mark()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(self.site), os.environ.get("PYTHONPATH", "")]),
               "PYTHONDONTWRITEBYTECODE": "1"}
        process = subprocess.Popen([sys.executable, "-m", "vitaplace.engine.cli.main", "evaluate",
                                    str(self.work / "s.yaml"),
                                    "--out", str(self.out), "-q", "--no-progress"], env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            process.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        self.after_run(before, self.code)

    @rule(stage=st.sampled_from(("simulate", "fit", "transform")), how=st.sampled_from(("user error", "Ctrl-C")))
    def command_fails(self, stage: str, how: str) -> None:
        """A rerun that stops at ``stage`` (its one-line user error, or Ctrl-C) before it
        writes into the folder itself leaves its completion record and resolved scenario as
        they were: a finished folder stays finished, with the numbers it had."""
        kept = [self.out / "completed.json", self.out / "scenario.resolved.yaml"]
        before = [p.read_bytes() if p.is_file() else None for p in kept]
        error = KeyboardInterrupt() if how == "Ctrl-C" else UserError(f"{stage}: refused")
        with mock.patch.object(orchestrate, stage, side_effect=error):
            status, err = cli("evaluate", str(self.work / "s.yaml"), "--out", str(self.out), "--no-progress")
        # the stages before ``stage`` run and may warn (e.g. a drive that touched a wall): the
        # refusal is the last line
        refused = status == 2 and err.strip().splitlines()[-1] == f"vitaplace: error: {stage}: refused"
        assert status == 130 if how == "Ctrl-C" else refused, err[-2000:]
        assert [p.read_bytes() if p.is_file() else None for p in kept] == before

    @rule(code=st.sampled_from(sorted(CODES)))
    def edit_plugin(self, code: str) -> None:
        self.set_code(code)

    @rule(name=st.sampled_from(["results.json", "manifest.json", "completed.json",
                                "evaluations/E1/P/query-to-reference/matrices.npz"]),
          how=st.sampled_from(["truncate", "flip"]))
    def corrupt(self, name: str, how: str) -> None:
        path = self.out / name
        if not path.is_file():
            return
        data = bytearray(path.read_bytes())
        if how == "truncate" or not data:
            data = data[: len(data) // 2]
        else:
            data[len(data) // 2] ^= 0x5A
        path.write_bytes(bytes(data))

    @precondition(lambda self: self.out.exists())
    @rule()
    def command_read_results(self) -> None:
        import vitaplace

        try:
            rows = vitaplace.read_results(self.out)
        except UserError as exc:
            assert "\n" not in str(exc)
            return
        assert scores(rows) == self.expected()

    @precondition(lambda self: self.out.exists())
    @rule()
    def command_aggregate(self) -> None:
        summary = self.work / "aggregate"
        status, err = cli("aggregate", str(self.out), "--out", str(summary))
        assert status == 0 or refused_in_one_line(status, err), err[-2000:]
        if status == 0:
            assert scores(json.loads((summary / "sweep.json").read_text())["runs"]) == self.expected()

    @precondition(lambda self: self.out.exists())
    @rule()
    def command_sensitivity(self) -> None:
        where = self.work / "sensitivity"
        resolved_tau = None
        with contextlib.suppress(OSError, yaml.YAMLError, TypeError, KeyError):
            resolved_tau = yaml.safe_load((self.out / "scenario.resolved.yaml").read_text())["scoring"]["tau"]
        status, err = cli("sensitivity", str(self.out), "--tau", *map(str, TAUS), "--out", str(where))
        assert status == 0 or refused_in_one_line(status, err), err[-2000:]
        if status == 0:
            rows = json.loads((where / "sensitivity.json").read_text())["rows"]
            own = [r for r in rows if r["tau"] == resolved_tau and r["heading_tolerance_deg"] is not None]
            expected = self.expected()
            for r in own:
                assert (r["max_f1"], r["recall_at_100_precision"]) == expected[("E1", "P", r["direction"])]

    @invariant()
    def nothing_half_written(self) -> None:
        # a finished folder's results are always whole JSON (every write is atomic)
        results = self.out / "results.json"
        if results.exists() and (self.out / "completed.json").exists():
            with contextlib.suppress(ValueError):
                json.loads(results.read_text())


def _run_machine(site: Path, root: Path, examples: int, steps: int) -> None:
    FolderLife.site, FolderLife.root, FolderLife.references = site, root, {}
    life = type(f"FolderLife{examples}", (FolderLife,), {})  # settings go on a class of its own, once
    machine = settings(max_examples=examples, stateful_step_count=steps, deadline=None, derandomize=True,
                       suppress_health_check=list(HealthCheck))(life).TestCase
    machine().runTest()


def test_a_folder_gives_the_clean_numbers_or_refuses_in_one_line(site, tmp_path):
    _run_machine(site, tmp_path, examples=6, steps=5)


@pytest.mark.slow
def test_fifty_lives_of_a_folder_give_the_clean_numbers_or_refuse_in_one_line(site, tmp_path):
    _run_machine(site, tmp_path, examples=50, steps=5)


def test_aggregate_refuses_matrices_changed_since_the_run_in_one_line(site, tmp_path):
    """Found by the state machine's longer runs: aggregate's block bootstrap read a corrupted
    matrices.npz and died with a BadZipFile traceback."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(scenario(0.3)))
    assert main(["evaluate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "-q"]) == 0
    matrices = tmp_path / "out" / "evaluations" / "E1" / "P" / "query-to-reference" / "matrices.npz"
    matrices.write_bytes(matrices.read_bytes()[: matrices.stat().st_size // 2])
    status, err = cli("aggregate", str(tmp_path / "out"), "--out", str(tmp_path / "summary"))
    assert refused_in_one_line(status, err) and "matrices.npz" in err, err
