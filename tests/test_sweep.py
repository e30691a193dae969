"""Sweeps and their summary: statistics against hand-computed values, a failing seed that
leaves the others and a partial summary (process pool and Ray), jobs that read nothing from
the driver's files, and `vitaplace aggregate` reproducing a sweep from its seed folders."""

import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine import summary, sweep  # noqa: E402
from vitaplace.engine.cli import main  # noqa: E402

ENV_E1 = Path(__file__).resolve().parent.parent / "scenarios" / "environments" / "e1.yaml"
#: t(0.975, 2) and t(0.975, 1) from a printed table of Student's t quantiles
T_2, T_1 = 4.302653, 12.706205

#: Test-only extractor: features are the true positions (fast, exact); ``fit`` fails when the
#: method's seed is ``fail_for``, so one scenario seed of a sweep fails and the others do not.
FAILING_PLUGIN = '''
import numpy as np
from scipy.spatial.distance import cdist
from vitaplace.engine.features import ExtractorParams, FeatureExtractor
from vitaplace.engine.hookspecs import hookimpl


class Params(ExtractorParams):
    seed: int = 0
    fail_for: int = -1
    exit_for: int = -1


class FailsForOneSeed(FeatureExtractor):
    """Test-only: true positions as features; fit fails for one method seed."""
    name = "fails-for-one-seed"
    Params = Params
    def fit(self, train):
        if self.params.seed == self.params.exit_for:
            import os
            os._exit(3)  # the worker process dies, as when the OOM killer strikes
        if self.params.seed == self.params.fail_for:
            raise ValueError("\\x1b[31minjected failure\\x1b[0m\\nsecond line of the message")
    def transform(self, run): return {"xy": np.asarray(run.poses[:, :2], dtype=np.float64)}
    def distance(self, query, reference): return cdist(query["xy"], reference["xy"])
    def save_state(self, directory): pass
    def load_state(self, directory): pass


@hookimpl
def vitaplace_register_features(register):
    register(FailsForOneSeed)
'''


def tiny_scenario(fail_seed: int = -1) -> dict:
    """Two methods, 5-sample runs: one seed takes a second or two."""
    from vitaplace.engine.runner import seed_for

    # the runner gives the first method of scenario seed s the seed seed_for(s, 1000)
    fail_for = seed_for(fail_seed, 1000) if fail_seed >= 0 else -1
    return {
        "name": "tiny",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "O", "plugin": "fails-for-one-seed", "params": {"fail_for": fail_for}},
                    {"name": "H", "plugin": "handcrafted"}],
        "evaluation": {"tau": 0.3},
    }


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory) -> dict:
    """The environment of a process that has the failing plugin installed."""
    site = tmp_path_factory.mktemp("site")
    (site / "vitaplace_failing_plugin.py").write_text(FAILING_PLUGIN)
    dist = site / "vitaplace_failing_plugin-0.0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: vitaplace-failing-plugin\nVersion: 0.0.1\n")
    (dist / "entry_points.txt").write_text("[vitaplace.features]\nfails-for-one-seed = vitaplace_failing_plugin\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}


def vitaplace(args: list[str], env: dict, prelude: str = "", postlude: str = "") -> subprocess.CompletedProcess:
    """The CLI in a fresh process, between ``prelude`` and ``postlude`` (Python code)."""
    code = f"import sys\n{prelude}\nfrom vitaplace.engine.cli import main\nrc = main(sys.argv[1:])\n{postlude}\nsys.exit(rc)"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300, env=env)


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def check_partial_sweep(out: Path, result: subprocess.CompletedProcess, ok: list[int], failed: int) -> None:
    """Exit 1, the failure in one line naming the seed (type and message, no traceback, no
    colour codes), and the summary written from the seeds that succeeded."""
    assert result.returncode == 1, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if f"seed {failed} failed" in line]
    assert len(lines) == 1, result.stderr[-3000:]
    assert re.search(rf"seed {failed} failed: ValueError: injected failure second line of the message", lines[0])
    assert "\x1b" not in lines[0] and "Traceback" not in result.stderr
    assert "Traceback" in (out / f"seed-{failed}" / "error.txt").read_text()
    record = json.loads((out / "sweep.json").read_text())
    assert record["seeds"] == ok and list(record["failed"]) == [str(failed)]
    assert {r["seed"] for r in record["runs"]} == set(ok)
    rows = read_csv(out / "sweep.csv")
    assert {(r["method"], r["n"]) for r in rows if r["metric"] == "max_f1"} == {("O", str(len(ok))), ("H", str(len(ok)))}
    # oracle features: a perfect score on every seed that ran
    assert all(float(r["mean"]) == 1.0 for r in rows if r["method"] == "O" and r["metric"] in ("max_f1", "auc"))


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory, plugin_env):
    """Seeds 0, 1, 2 on two local processes; seed 1 fails."""
    tmp = tmp_path_factory.mktemp("local")
    path = tmp / "tiny.yaml"
    path.write_text(yaml.safe_dump(tiny_scenario(fail_seed=1)))
    out = tmp / "out"
    args = ["sweep", str(path), "--seeds", "0", "1", "2", "--workers", "2", "--out", str(out), "--no-progress"]
    return out, vitaplace(args, plugin_env)


def test_local_sweep_keeps_going_past_a_failed_seed(local_sweep):
    out, result = local_sweep
    check_partial_sweep(out, result, [0, 2], 1)
    assert (out / "seed-0" / "report.md").is_file() and (out / "seed-2" / "report.md").is_file()
    assert f"summary of the others in {out / 'sweep.md'}" in result.stderr


def test_aggregate_reproduces_the_sweep_summary(local_sweep, tmp_path):
    out, _ = local_sweep
    assert main(["aggregate", str(out / "seed-2"), str(out / "seed-0"), "--out", str(tmp_path)]) == 0
    for name in ("sweep-seeds.csv", "sweep.csv", "sweep-diff.csv", "sweep.md", "sweep.tex"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name


def test_aggregate_refuses_other_scenarios_and_unfinished_runs(local_sweep, tmp_path, capsys):
    out, _ = local_sweep
    other = tmp_path / "other"
    shutil.copytree(out / "seed-2", other)
    resolved = yaml.safe_load((other / "scenario.resolved.yaml").read_text())
    resolved["evaluation"]["tau"] = 0.4
    (other / "scenario.resolved.yaml").write_text(yaml.safe_dump(resolved))
    reseal(other)  # a finished run of another scenario
    cases = {
        "differs from": [str(out / "seed-0"), str(other)],
        "incomplete run folder": [str(out / "seed-0"), str(out / "seed-1")],  # the seed that failed
        "seed 0 again": [str(out / "seed-0"), str(out / "seed-0")],
    }
    for message, folders in cases.items():
        assert main(["aggregate", *folders, "--out", str(tmp_path / "summary")]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and folders[1] in lines[0], lines
    assert not (tmp_path / "summary" / "sweep.csv").exists()


LIST_TASKS = """
import time
from ray.util.state import list_tasks
for _ in range(40):  # task events reach the state API within a second or two
    names = sorted(task.name for task in list_tasks())
    if len(names) >= 2:
        break
    time.sleep(0.25)
print("TASKS", names)
"""


def test_ray_sweep_keeps_going_past_a_failed_seed(tmp_path, plugin_env):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'vitaplace[ray]')")
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(tiny_scenario(fail_seed=1)))
    out = tmp_path / "out"
    prelude = "import ray\nray.init(num_cpus=2, log_to_driver=False)"
    postlude = LIST_TASKS  # what `ray list tasks` shows
    args = ["sweep", str(path), "--seeds", "0", "1", "--out", str(out), "--ray", "auto", "--no-progress"]
    result = vitaplace(args, plugin_env, prelude, postlude)
    check_partial_sweep(out, result, [0], 1)
    assert "TASKS ['tiny seed 0', 'tiny seed 1']" in result.stdout, result.stdout
    assert "Ray: using the runtime this process already started" in result.stderr
    assert "(n=1)" in (out / "sweep.md").read_text()
    assert not list(out.glob(".sweep-marker-*"))


# ---------------------------------------------------------------------- statistics


def test_describe_matches_hand_computed_statistics():
    # 0.5, 0.7, 0.9: mean 0.7; deviations -0.2, 0, 0.2: s^2 = 0.08 / 2, s = 0.2;
    # half-width t(0.975, 2) * 0.2 / sqrt(3)
    stats = summary.describe([0.5, 0.7, 0.9])
    half = T_2 * 0.2 / math.sqrt(3)
    assert stats["n"] == 3
    assert stats["mean"] == pytest.approx(0.7) and stats["std"] == pytest.approx(0.2)
    assert stats["ci_low"] == pytest.approx(0.7 - half, abs=1e-6) and stats["ci_high"] == pytest.approx(0.7 + half, abs=1e-6)
    # two values 1 and 3: mean 2, s = sqrt(2), half-width t(0.975, 1) * sqrt(2) / sqrt(2)
    two = summary.describe([1.0, 3.0])
    assert two["std"] == pytest.approx(math.sqrt(2)) and two["ci_high"] == pytest.approx(2 + T_1, abs=1e-5)


def test_one_seed_has_no_interval_and_says_so():
    stats = summary.describe([0.6])
    assert stats["n"] == 1 and stats["mean"] == 0.6
    assert all(math.isnan(stats[k]) for k in ("std", "ci_low", "ci_high"))
    row = {"environment": "E1", "method": "L", "direction": "q", "metric": "max_f1", **stats}
    assert summary.cell(row) == "0.600 (n=1)"
    assert "0.600 (n=1)" in summary.markdown([row], [], "t") and "0.600 (n=1)" in summary.latex([row], [])


def rows_for(values: dict[str, list[float]], seeds: list[int]) -> list[dict]:
    return [
        {"seed": s, "environment": "E1", "method": m, "direction": "q", "max_f1": v[i], "tau": 0.3,
         "auc_method": "average_precision_stepwise", "recall_at_k": {"1": v[i] / 2}, "delta_at_max_f1": None}
        for m, v in values.items() for i, s in enumerate(seeds)
    ]


def test_paired_differences_are_per_seed():
    # seeds 1, 2, 3: L = 0.8, 0.7, 0.9 and H = 0.6, 0.2, 0.5, so L - H = 0.2, 0.5, 0.4 (seed 4: L only)
    # mean 11/30, deviations -5/30, 4/30, 1/30: s^2 = (25 + 16 + 1) / 900 / 2 = 7/300
    rows = rows_for({"L": [0.9, 0.8, 0.7, 0.1]}, [3, 1, 2, 4]) + rows_for({"H": [0.6, 0.2, 0.5]}, [1, 2, 3])
    diffs = summary.paired_differences(summary.seed_rows(rows))
    (f1,) = [d for d in diffs if d["metric"] == "max_f1"]
    assert (f1["method_a"], f1["method_b"], f1["n"]) == ("L", "H", 3)
    std = math.sqrt(7 / 300)
    assert f1["mean"] == pytest.approx(11 / 30) and f1["std"] == pytest.approx(std)
    assert f1["ci_low"] == pytest.approx(11 / 30 - T_2 * std / math.sqrt(3), abs=1e-6)


def test_every_numeric_metric_is_summarised_and_settings_are_not():
    rows = rows_for({"L": [0.9, 0.8, 0.7]}, [0, 1, 2])
    rows[0]["delta_at_max_f1"] = 2.0  # finite on one seed only
    table = {r["metric"]: r for r in summary.summarise(summary.seed_rows(rows))}
    assert set(table) == {"max_f1", "recall@1", "delta_at_max_f1"}  # not tau, not the text, not the None
    assert table["recall@1"]["mean"] == pytest.approx(0.4) and table["recall@1"]["std"] == pytest.approx(0.05)
    assert table["delta_at_max_f1"]["n"] == 1


def test_summary_files_are_written_with_nan_as_null(tmp_path):
    rows = rows_for({"L": [0.9], "H": [0.5]}, [7])
    summary.write_summary(tmp_path, rows, "t", {"scenario": "t"})
    record = json.loads((tmp_path / "sweep.json").read_text())  # strict JSON: no NaN
    assert record["summary"][0]["std"] is None
    assert [r["value"] for r in read_csv(tmp_path / "sweep-seeds.csv") if r["metric"] == "max_f1"] == ["0.9", "0.5"]
    assert read_csv(tmp_path / "sweep-diff.csv")[0]["mean"] == str(0.9 - 0.5)


# ---------------------------------------------------------------------- jobs and the driver


def test_a_job_reads_nothing_from_the_driver_s_files(tmp_path, monkeypatch):
    """The job carries the resolved scenario and environments: with the scenario, its
    environment file and the working directory gone, it still runs; --force reaches it."""
    from vitaplace.engine.scenario import load_scenario

    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(ENV_E1, src / "arena.yaml")
    shutil.copy(ENV_E1.parent / "base.yaml", src / "base.yaml")  # e1 extends base
    data = tiny_scenario()
    data["methods"] = [{"name": "H", "plugin": "handcrafted"}]
    data["train"]["environment"] = data["evaluations"][0]["environment"] = "arena.yaml"  # relative to the file
    (src / "tiny.yaml").write_text(yaml.safe_dump(data))
    scenario, resolved = load_scenario(src / "tiny.yaml")
    (job,) = sweep.seed_jobs(scenario, resolved, [4], tmp_path / "out", marker=str(tmp_path / "not-there"))
    (forced,) = sweep.seed_jobs(scenario, resolved, [4], tmp_path / "out", force=["evaluate"])
    shutil.rmtree(src)
    monkeypatch.chdir(tmp_path)
    result = sweep.run_seed(job)
    assert result["sees_out"] is False and result["rows"][0]["seed"] == 4
    written = yaml.safe_load((tmp_path / "out" / "seed-4" / "scenario.resolved.yaml").read_text())
    assert written["seed"] == 4 and written["train"]["environment"] == str(tmp_path / "out" / "seed-4" / "environments" / "arena.yaml")
    assert sweep.run_seed(forced)["sees_out"] is True
    stages = json.loads((tmp_path / "out" / "seed-4" / "manifest.json").read_text())["stages"]
    assert {r["stage"] for r in stages if r["status"] == "ran"} == {"evaluate"}


def test_bad_seeds_and_stages_are_user_errors_before_any_job(tmp_path):
    from vitaplace.engine.scenario import ScenarioError, load_scenario

    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}))
    scenario, resolved = load_scenario(tmp_path / "s.yaml")
    for seeds, force, message in (([1, 1], [], "each seed once"), ([-1], [], "not a valid scenario seed"),
                                  ([1], ["fitt"], "unknown stage")):
        with pytest.raises(ScenarioError, match=message):
            sweep.seed_jobs(scenario, resolved, seeds, tmp_path / "out", force)


def test_recorded_run_files_reach_jobs_as_absolute_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    resolved = {"train": {"dataset": "train.h5"},
                "evaluations": [{"name": "E1", "datasets": {"query": "q.h5", "reference": "/data/r.h5"}}]}
    fixed = sweep._absolute_files(resolved)
    assert fixed["train"]["dataset"] == str(tmp_path / "train.h5")
    assert fixed["evaluations"][0]["datasets"] == {"query": str(tmp_path / "q.h5"), "reference": "/data/r.h5"}
    assert resolved["train"]["dataset"] == "train.h5"  # the caller's mapping is left alone


def test_the_driver_warns_once_about_unshared_storage_and_reports_failures(tmp_path, monkeypatch, caplog):
    from vitaplace.engine.scenario import load_scenario

    data = tiny_scenario()
    data["methods"] = [{"name": "H", "plugin": "handcrafted"}]
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(data))
    scenario, resolved = load_scenario(tmp_path / "tiny.yaml")

    def ended(jobs, workers):  # stands in for the pool: two seeds on a node without OUT, one failed
        rows = rows_for({"H": [0.5]}, [0])
        yield jobs[0], {"seed": 0, "rows": rows, "host": "node-a", "sees_out": False}, None
        yield jobs[1], {"seed": 1, "rows": rows_for({"H": [0.7]}, [1]), "host": "node-a", "sees_out": False}, None
        yield jobs[2], None, sweep.describe_failure(sweep.SeedFailed("MemoryError", "out of memory"))

    monkeypatch.setattr(sweep, "_local", ended)
    outcome = sweep.run_sweep(scenario, resolved, [0, 1, 2], tmp_path / "out", progress=False)
    assert outcome.failed == {2: "MemoryError: out of memory"}
    warnings = [r.getMessage() for r in caplog.records if "not on storage the workers share" in r.getMessage()]
    assert len(warnings) == 1 and "node-a" in warnings[0]
    (f1,) = [r for r in outcome.summary if r["metric"] == "max_f1"]
    assert f1["n"] == 2 and f1["mean"] == pytest.approx(0.6)


def test_failures_of_ray_tasks_read_as_one_line():
    class RayTaskError(Exception):  # how Ray hands over a task's exception: .cause, remote traceback in str
        cause = sweep.SeedFailed("StageError", "transform L E1/query: NaN")

        def __str__(self):
            return "\x1b[36mray::tiny seed 3()\x1b[39m (pid=1)\n  File \"x.py\", line 1\nStageError: ..."

    assert sweep.describe_failure(RayTaskError()) == "StageError: transform L E1/query: NaN"
    crash = RuntimeError("\x1b[31mThe worker died unexpectedly\x1b[0m\nwhile executing this task")
    assert sweep.describe_failure(crash) == "RuntimeError: The worker died unexpectedly"


def test_gpu_jobs_select_the_gpu_backend_where_a_method_has_one(tmp_path):
    from vitaplace.engine.scenario import load_scenario

    data = tiny_scenario()
    data["methods"] = [{"name": "L", "plugin": "mupnet"}, {"name": "H", "plugin": "handcrafted"},
                       {"name": "N", "plugin": "mupnet", "params": {"backend": "numpy"}}]
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    scenario, _ = load_scenario(tmp_path / "s.yaml")
    assert sweep.gpu_overrides(scenario) == ["methods.0.params.backend=warp"]
    gpu, resolved = sweep.load_sweep_scenario(str(tmp_path / "s.yaml"), [], gpus_per_job=1)
    assert gpu.methods[0].params["backend"] == "warp" and resolved["methods"][0]["params"]["backend"] == "warp"
    assert "backend" not in sweep.load_sweep_scenario(str(tmp_path / "s.yaml"), [], 0)[0].methods[0].params


def _curve(recall, precision):
    from vitaplace.engine.evaluate import PRCurve

    r, p = np.asarray(recall, float), np.asarray(precision, float)
    f1 = np.where(p + r > 0, 2 * p * r / np.maximum(p + r, 1e-12), 0.0)
    z = np.zeros(len(r))
    return PRCurve(np.arange(len(r), dtype=float), p, r, f1, z, z, z, 10, 10)


def test_interpolated_precision_is_the_best_precision_at_or_beyond_each_recall():
    from vitaplace.engine.figures import interpolated_precision

    # points (recall, precision): (0.2, 1.0), (0.5, 0.8), (0.5, 0.9), (1.0, 0.5), in threshold order
    curve = _curve([0.5, 0.2, 1.0, 0.5], [0.8, 1.0, 0.5, 0.9])
    got = interpolated_precision(curve, np.array([0.0, 0.2, 0.3, 0.5, 0.6, 1.0]))
    np.testing.assert_allclose(got, [1.0, 1.0, 0.9, 0.9, 0.5, 0.5])
    short = _curve([0.1, 0.4], [1.0, 0.7])  # never reaches recall 0.5: precision 0 there
    np.testing.assert_allclose(interpolated_precision(short, np.array([0.4, 0.5])), [0.7, 0.0])


def test_pr_band_figures_are_written_per_environment_from_the_seed_folders(tmp_path):
    import dataclasses

    from vitaplace.engine.figures import write_pr_bands

    rows = []
    for seed in (0, 1):
        for method in ("L", "H"):
            folder = tmp_path / f"seed-{seed}" / "evaluations" / "E1" / method / "query-to-reference"
            folder.mkdir(parents=True)
            c = _curve([0.2, 0.6, 1.0], [1.0, 0.9 - 0.1 * seed, 0.5])
            np.savez(folder / "pr_curve.npz", **{k: np.asarray(v) for k, v in dataclasses.asdict(c).items()})
            rows.append({"seed": seed, "environment": "E1", "method": method, "direction": "query-to-reference"})
    written = write_pr_bands(tmp_path, {0: tmp_path / "seed-0", 1: tmp_path / "seed-1"}, rows)
    assert {p.name for p in written} == {"pr-bands-E1-query-to-reference.png", "pr-bands-E1-query-to-reference.pdf"}
    assert all(p.stat().st_size > 1000 for p in written)


def test_a_seed_whose_worker_process_dies_fails_alone(tmp_path, plugin_env):
    """A worker killed mid-job breaks the process pool and the jobs beside it; those run again,
    each in its own pool: the dying seed fails in one line, the others finish."""
    from vitaplace.engine.runner import seed_for

    data = tiny_scenario()
    data["methods"][0]["params"] = {"exit_for": seed_for(1, 1000)}
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    result = vitaplace(["sweep", str(path), "--seeds", "0", "1", "2", "--workers", "2", "--out", str(out),
                        "--no-progress"], plugin_env)
    assert result.returncode == 1, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if "seed 1 failed" in line]
    assert len(lines) == 1 and "worker process died" in lines[0] and "traceback in" not in lines[0], result.stderr[-3000:]
    record = json.loads((out / "sweep.json").read_text())
    assert record["seeds"] == [0, 2] and list(record["failed"]) == ["1"]


# --------------------------------------------------------------------------- run folders that prove they are finished


def reseal(folder: Path) -> None:
    """Write the folder's completion record anew over what it holds now: as if its own run had
    produced the damaged files (a buggy plugin, a bad disk), so the row checks must catch them."""
    from vitaplace.engine import completion

    files = json.loads((folder / completion.RECORD).read_text())["files"]
    completion.write(folder, [folder / name for name in files])


def _rows(folder: Path, change) -> None:
    path = folder / "results.json"
    rows = json.loads(path.read_text())
    change(rows)
    path.write_text(json.dumps(rows))


CURVE = "evaluations/E1/O/query-to-reference/pr_curve.npz"
UNFINISHED = {
    "results edited after the run": (lambda f: _rows(f, lambda r: r[0].update(max_f1=0.5)), False,
                                     r"seed-copy: not a finished run: results\.json is not the file its finished run recorded"),
    "a truncated PR curve": (lambda f: (f / CURVE).write_bytes((f / CURVE).read_bytes()[:50]), False,
                             rf"not a finished run: {CURVE} is not the file its finished run recorded"),
    "a truncated PR curve, recorded so": (lambda f: (f / CURVE).write_bytes((f / CURVE).read_bytes()[:50]), True,
                                          rf"{CURVE}: unreadable PR curve"),
    "no result rows": (lambda f: (f / "results.json").write_text("[]"), True,
                       r"results\.json: holds no result rows, expected a non-empty list"),
    "a metric as text": (lambda f: _rows(f, lambda r: r[0].update(auc="high")), True,
                         r"results\.json: row 0: field 'auc' is 'high', expected a finite number or null"),
    "max F1 missing": (lambda f: _rows(f, lambda r: r[1].pop("max_f1")), True,
                       r"results\.json: row 1: field 'max_f1' is None, expected a finite number"),
    "recall@K as text": (lambda f: _rows(f, lambda r: r[0]["recall_at_k"].update({"5": "x"})), True,
                         r"results\.json: row 0: field 'recall_at_k\.5' is 'x', expected a finite number or null"),
    "a row that is a list": (lambda f: _rows(f, lambda r: r.append([1, 2])), True,
                             r"results\.json: row 2: a list, expected a result row"),
    "no environment": (lambda f: _rows(f, lambda r: r[0].pop("environment")), True,
                       r"results\.json: row 0: field 'environment' is None, expected a non-empty name"),
}


@pytest.mark.parametrize("case", sorted(UNFINISHED))
def test_aggregate_refuses_folders_it_cannot_trust_before_writing_anything(local_sweep, tmp_path, capsys, case):
    import re

    out, _ = local_sweep
    folder = tmp_path / "seed-copy"
    shutil.copytree(out / "seed-2", folder)
    damage, recorded, message = UNFINISHED[case]
    damage(folder)
    if recorded:
        reseal(folder)
    summary = tmp_path / "summary"
    assert main(["aggregate", str(out / "seed-0"), str(folder), "--out", str(summary)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and re.search(message, lines[0]), lines
    assert str(folder) in lines[0]
    assert not summary.exists() or not any(summary.iterdir())  # nothing written


def test_aggregate_refuses_a_folder_whose_rerun_was_killed(local_sweep, tmp_path, capsys, monkeypatch):
    """Finish seed 2, rerun it with another tau and kill the rerun during simulate: the folder
    holds the old results beside the new resolved scenario, and no completion record."""
    from vitaplace.engine import completion
    from vitaplace.engine.runner import Pipeline
    from vitaplace.engine.scenario import Scenario

    out, _ = local_sweep
    folder = tmp_path / "seed-2"
    shutil.copytree(out / "seed-2", folder)
    record = (folder / completion.RECORD).read_text()
    resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
    resolved["evaluation"]["tau"] = 0.4

    def killed(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(Pipeline, "simulate", killed)
    with pytest.raises(KeyboardInterrupt):
        Pipeline(Scenario.model_validate(resolved), resolved, folder, cache=tmp_path / "cache").run()
    assert (folder / "results.json").is_file() and (folder / "manifest.json").is_file()  # the old run's
    summary = tmp_path / "summary"
    assert main(["aggregate", str(out / "seed-0"), str(folder), "--out", str(summary)]) == 2
    line = capsys.readouterr().err.strip()
    assert line == f"vitaplace: error: {folder}: incomplete run folder (no {completion.RECORD}); did its run finish?"
    # even with the old record put back, it does not match the new resolved scenario
    (folder / completion.RECORD).write_text(record)
    assert main(["aggregate", str(out / "seed-0"), str(folder), "--out", str(summary)]) == 2
    assert "scenario.resolved.yaml is not the scenario its finished run recorded" in capsys.readouterr().err
    assert not summary.exists()


def test_aggregate_counts_the_seeds_that_contribute(local_sweep, tmp_path, capsys):
    out, _ = local_sweep
    assert main(["aggregate", str(out / "seed-0"), str(out / "seed-2"), "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.startswith("summary of 2 seeds")
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert record["seeds"] == [0, 2] and {r["seed"] for r in record["runs"]} == {0, 2}
