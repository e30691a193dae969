"""Sweeps and their summary (its statistics: tests/components/test_summary.py): a failing seed that
leaves the others and a partial summary (process pool and Ray), jobs that read nothing from
the driver's files, and `vitaplace aggregate` reproducing a sweep from its seed folders."""

import csv
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import install_plugin, reseal

os.environ.setdefault("MUJOCO_GL", "egl")

import vitaplace.engine.cli.sweep as sweep  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"

#: Test-only extractor: features are the true positions (fast, exact); ``fit`` fails when the
#: method's seed is ``fail_for``, so one scenario seed of a sweep fails and the others do not.
FAILING_PLUGIN = '''
import numpy as np
from scipy.spatial.distance import cdist
from vitaplace.engine.extension.features import ExtractorParams, FeatureExtractor
from vitaplace.engine.extension.hookspecs import hookimpl


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
    from vitaplace.engine.pipeline.plan import seed_for

    # the runner gives the first method of scenario seed s the seed seed_for(s, 1000)
    fail_for = seed_for(fail_seed, 1000) if fail_seed >= 0 else -1
    return {
        "name": "tiny",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "O", "plugin": "fails-for-one-seed", "params": {"fail_for": fail_for}},
                    {"name": "H", "plugin": "handcrafted"}],
        "scoring": {"tau": 0.3},
    }


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory) -> dict:
    """The environment of a process that has the failing plugin installed."""
    site = tmp_path_factory.mktemp("site")
    install_plugin(site, "vitaplace_failing_plugin", FAILING_PLUGIN, "vitaplace-failing-plugin", "0.0.1",
                   "fails-for-one-seed")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}


def vitaplace(args: list[str], env: dict, prelude: str = "", postlude: str = "") -> subprocess.CompletedProcess:
    """The CLI in a fresh process, between ``prelude`` and ``postlude`` (Python code)."""
    code = (f"import sys\n{prelude}\nfrom vitaplace.engine.cli.main import main\n"
            f"rc = main(sys.argv[1:])\n{postlude}\nsys.exit(rc)")
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
    assert {(r["method"], r["n"]) for r in rows if r["metric"] == "max_f1"} == {("O", str(len(ok))),
                                                                                ("H", str(len(ok)))}
    # the within-seed block bootstrap found every seed's saved matrices
    assert all(r["block_low"] != "nan" for r in rows if r["kind"] == "metric")
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


def test_a_seed_written_before_the_scoring_rename_aggregates_with_one_after(local_sweep, tmp_path):
    """A seed folder whose resolved scenario still says `evaluation:` (written before the key
    became `scoring:`) is the same scenario as one that says `scoring:`."""
    out, _ = local_sweep
    old = tmp_path / "old"
    shutil.copytree(out / "seed-2", old)
    resolved = yaml.safe_load((old / "scenario.resolved.yaml").read_text())
    resolved = {("evaluation" if key == "scoring" else key): value for key, value in resolved.items()}
    (old / "scenario.resolved.yaml").write_text(yaml.safe_dump(resolved))
    reseal(old)
    assert main(["aggregate", str(out / "seed-0"), str(old), "--out", str(tmp_path / "summary")]) == 0
    assert (tmp_path / "summary" / "sweep.csv").read_bytes() == (out / "sweep.csv").read_bytes()


def test_aggregate_refuses_other_scenarios_and_unfinished_runs(local_sweep, tmp_path, capsys):
    out, _ = local_sweep
    other = tmp_path / "other"
    shutil.copytree(out / "seed-2", other)
    resolved = yaml.safe_load((other / "scenario.resolved.yaml").read_text())
    resolved["scoring"]["tau"] = 0.4
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


def documented_slurm_command() -> list[str]:
    """The arguments of the `vitaplace sweep --slurm` command docs/SCALE.md shows, after
    checking that the rest of its shell block only sets MUJOCO_GL."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "SCALE.md").read_text()
    (block,) = [b for b in re.findall(r"```bash\n(.*?)```", text, re.S) if "--slurm" in b]
    lines = [line for line in block.replace("\\\n", " ").splitlines() if line.strip()]
    assert lines[:-1] == ["export MUJOCO_GL=egl"], lines
    args = shlex.split(lines[-1])
    assert args[:2] == ["vitaplace", "sweep"], args
    return args[2:]


def test_the_documented_slurm_command_runs_and_reports_a_failed_seed_in_one_line(tmp_path, plugin_env):
    """docs/SCALE.md's command, every option as written, on submitit's local executor
    (``--slurm local``) with a test scenario and seeds 0 1 of which 1 fails: one line for
    seed 1, seed 0 summarised, scripts and logs under OUT/slurm."""
    pytest.importorskip("submitit", reason="submitit is not installed (pip install 'vitaplace[slurm]')")
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(tiny_scenario(fail_seed=1)))
    out = tmp_path / "out"
    args = documented_slurm_command()
    args[0] = str(path)
    seeds = args.index("--seeds")
    end = next(i for i in range(seeds + 1, len(args)) if args[i].startswith("--"))
    args[seeds + 1:end] = ["0", "1"]
    args[args.index("--out") + 1] = str(out)
    args.insert(args.index("--slurm") + 1, "local")
    result = vitaplace(["sweep", *args], plugin_env)
    check_partial_sweep(out, result, [0], 1)
    assert "missing from the summary: 1;" in result.stderr
    assert re.search(rf"SLURM \(local\): job .*2 task\(s\); scripts and logs in {re.escape(str(out / 'slurm'))}",
                     result.stderr)
    assert len(list((out / "slurm").glob("*_log.err"))) == 2


def test_slurm_options_are_checked_before_anything_runs(tmp_path, capsys):
    import vitaplace.engine.cli.slurm as slurm

    assert [slurm.parse_time(t) for t in ("90", "1:30", "04:00:00", "1-0", "0-01:00:01", "2-03:04")] == [
        90, 2, 240, 1440, 61, 2 * 1440 + 3 * 60 + 4]
    assert slurm.parse_sbatch(["account=proj", "--exclusive", "mail-type=END,FAIL"]) == {
        "account": "proj", "exclusive": True, "mail-type": "END,FAIL"}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(tiny_scenario()))
    base = ["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out")]
    cases = {
        "--slurm needs --time": ["--slurm"],
        "--time 4h: expected a time limit": ["--slurm", "--time", "4h"],
        "--partition --mem: only with --slurm": ["--partition", "gpu", "--mem", "4G"],
        "--sbatch time=5: use --time instead": ["--slurm", "--time", "5", "--sbatch", "time=5"],
        "--cpus-per-job 1.5: SLURM allots whole CPUs": ["--slurm", "--time", "5", "--cpus-per-job", "1.5"],
        "--slurm and --ray: choose one": ["--slurm", "--time", "5", "--ray", "auto"],
        "--gpus-per-job: applies to --ray and --slurm": ["--gpus-per-job", "1"],
        "--workers: applies to sweeps on this machine": ["--slurm", "local", "--time", "5", "--workers", "2"],
    }
    for message, extra in cases.items():
        assert main([*base, *extra]) == 2, extra
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (extra, lines)
    assert not (tmp_path / "out").exists()


def test_slurm_settings_reach_the_sbatch_script(tmp_path, monkeypatch):
    """What sbatch would read for docs/SCALE.md's command: the array of seeds, the time in
    minutes, CPUs, GPUs, partition, memory and the passed-through options (submitit's own
    script text, nothing submitted)."""
    submitit = pytest.importorskip("submitit")
    from submitit.slurm.slurm import _make_sbatch_string

    import vitaplace.engine.cli.slurm as slurm
    from vitaplace.engine.base.errors import UserError
    from vitaplace.engine.cli.main import build_parser

    settings = slurm.settings_from_args(build_parser().parse_args(["sweep", *documented_slurm_command(),
                                                                    "--sbatch", "exclusive"]))
    if shutil.which("srun") is None:
        with pytest.raises(UserError, match="--slurm: Could not detect \"srun\".*--slurm local runs"):
            slurm.executor(settings, tmp_path, "vitaplace-tiny")
    monkeypatch.setattr(submitit.SlurmExecutor, "affinity", classmethod(lambda cls: 2))  # as if srun were here
    executor = slurm.executor(settings, tmp_path, "vitaplace-tiny")
    script = _make_sbatch_string(command="run", folder=tmp_path, map_count=3, **executor._executor.parameters)
    for line in ("--array=0-2%3", "--time=240", "--cpus-per-task=4", "--gpus-per-node=1", "--partition=gpu",
                 "--mem=16G", "--account=myproject", "--exclusive", "--job-name=vitaplace-tiny"):
        assert f"#SBATCH {line}\n" in script, (line, script)


class FakeTask:
    """Stands in for a submitit job: ended or not, with a result or not."""

    def __init__(self, job_id, result=None, ended=True):
        self.job_id, self._result, self.ended, self.cancelled = job_id, result, ended, False
        self.state = "FAILED" if result is None else "COMPLETED"
        self.paths = type("Paths", (), {"stderr": Path(f"/out/slurm/{job_id}_0_log.err")})()

    def done(self, force_check=False):
        return self.ended

    def result(self):
        if self._result is None:
            raise RuntimeError("Job 12_1 has not produced any output (state: FAILED)")
        return self._result

    def cancel(self, check=True):
        self.cancelled = True


def test_a_slurm_task_without_a_result_is_one_line_and_an_interrupt_cancels_the_rest():
    pytest.importorskip("submitit")
    import vitaplace.engine.cli.slurm as slurm

    tasks = [FakeTask("12_0", {"seed": 0, "rows": []}), FakeTask("12_1"),
             FakeTask("12_2", {"seed": 2, "failure": "E: x"})]
    ended = list(slurm._wait(tasks, ["job0", "job1", "job2"], 0.01))
    assert ended == [("job0", {"seed": 0, "rows": []}, None),
                     ("job1", None, "its task 12_1 ended without a result (FAILED); log: /out/slurm/12_1_0_log.err"),
                     ("job2", None, "E: x")]
    assert not any(t.cancelled for t in tasks)
    tasks = [FakeTask("13_0", {"seed": 0, "rows": []}), FakeTask("13_1", ended=False)]
    waiting = slurm._wait(tasks, ["job0", "job1"], 0.01)
    next(waiting)
    waiting.close()  # what Ctrl-C in the driver's loop does to the iterator
    assert [t.cancelled for t in tasks] == [False, True]


@pytest.fixture
def own_ray(tmp_path_factory, plugin_env):
    """A prelude that starts a Ray of the test's own (``address="local"``: never a running
    cluster), with its own short temp dir (socket paths) and namespace, and the env without
    RAY_ADDRESS; the temp dir is removed afterwards."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'vitaplace[ray]')")
    temp = tempfile.mkdtemp(prefix="vp-ray-", dir="/tmp")
    prelude = ("import ray, uuid\n"
               f"ray.init(address='local', num_cpus=2, num_gpus=0, log_to_driver=False, _temp_dir={temp!r}, "
               "namespace='vitaplace-test-' + uuid.uuid4().hex)")
    env = {k: v for k, v in plugin_env.items() if k != "RAY_ADDRESS"}
    yield prelude, env
    shutil.rmtree(temp, ignore_errors=True)


#: what `ray list tasks` shows of this process's own cluster (its address given: with another
#: cluster on the machine, Ray's auto-detection may pick that one); a task appears once per
#: attempt, so names are deduplicated
LIST_TASKS = """
import time
from ray.util.state import list_tasks
for _ in range(40):  # task events reach the state API within a second or two
    names = sorted({t.name for t in list_tasks(address=ray.get_runtime_context().gcs_address) if " seed " in t.name})
    if len(names) >= 2:
        break
    time.sleep(0.25)
print("TASKS", names)
"""


def test_ray_sweep_keeps_going_past_a_failed_seed(tmp_path, own_ray):
    prelude, env = own_ray
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(tiny_scenario(fail_seed=1)))
    out = tmp_path / "out"
    args = ["sweep", str(path), "--seeds", "0", "1", "--out", str(out), "--ray", "auto", "--no-progress"]
    result = vitaplace(args, env, prelude, LIST_TASKS)
    check_partial_sweep(out, result, [0], 1)
    assert "TASKS ['tiny seed 0', 'tiny seed 1']" in result.stdout, result.stdout
    assert re.search(r"Ray: using the runtime this process already started, cluster [\w.-]+:\d+\n", result.stderr)
    assert "Ray: 1 node(s) run vitaplace " in result.stderr
    assert "(n=1)" in (out / "sweep.md").read_text()
    assert not list(out.glob(".sweep-marker-*"))


#: the driver claims another vitaplace version than its workers have; then, with its own
#: version back, asks for a GPU
CLAIM_OTHER_VERSION = """
import vitaplace.engine
real, vitaplace.engine.__version__ = vitaplace.engine.__version__, "0.0.0+driver"
"""
ASK_FOR_A_GPU = """
print("RC", rc, file=sys.stderr)
vitaplace.engine.__version__ = real
rc = main([*sys.argv[1:], "--gpus-per-job", "1"])
"""


def test_ray_refuses_workers_with_other_code_and_resources_no_node_has(tmp_path, own_ray):
    from vitaplace.engine import __version__

    prelude, env = own_ray
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(tiny_scenario()))
    out = tmp_path / "out"
    args = ["sweep", str(path), "--seeds", "0", "--out", str(out), "--ray", "auto", "--no-progress"]
    result = vitaplace(args, env, prelude + CLAIM_OTHER_VERSION, ASK_FOR_A_GPU)
    assert "RC 2" in result.stderr and result.returncode == 2, result.stderr[-3000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("vitaplace: error:")]
    assert len(errors) == 2 and "Traceback" not in result.stderr, result.stderr[-3000:]
    version, gpus = errors
    assert re.search(rf"node \S+ runs vitaplace {re.escape(__version__)} \(commit .*\) but this driver runs "
                     r"vitaplace 0\.0\.0\+driver \(commit .*fails-for-one-seed=vitaplace-failing-plugin==0\.0\.1",
                     version)
    assert "--gpus-per-job 1: no node of the Ray cluster" in gpus and "2 CPUs/0 GPUs" in gpus
    assert not list(out.glob("seed-*"))


def test_an_unreachable_ray_address_fails_at_once_in_one_line(tmp_path, capsys):
    pytest.importorskip("ray")
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**tiny_scenario(),
                                                     "methods": [{"name": "H", "plugin": "handcrafted"}]}))
    assert main(["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--ray", f"127.0.0.1:{port}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"--ray 127.0.0.1:{port}: nothing answers at 127.0.0.1:{port}" in lines[0], lines


def rows_for(values: dict[str, list[float]], seeds: list[int]) -> list[dict]:
    return [
        {"seed": s, "environment": "E1", "method": m, "direction": "q", "max_f1": v[i], "tau": 0.3,
         "auc_method": "average_precision_stepwise", "recall_at_k": {"1": v[i] / 2}, "delta_at_max_f1": None}
        for m, v in values.items() for i, s in enumerate(seeds)
    ]


# ---------------------------------------------------------------------- jobs and the driver


def test_a_job_reads_nothing_from_the_driver_s_files(tmp_path, monkeypatch):
    """The job carries the resolved scenario and environments: with the scenario, its
    environment file and the working directory gone, it still runs; --force reaches it."""
    from vitaplace.engine.config.loading import load_scenario

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
    assert written["seed"] == 4
    assert written["train"]["environment"] == "environments/arena.yaml"  # the seed folder's copy, from there
    assert sweep.run_seed(forced)["sees_out"] is True
    stages = json.loads((tmp_path / "out" / "seed-4" / "manifest.json").read_text())["stages"]
    assert {r["stage"] for r in stages if r["status"] == "ran"} == {"evaluate"}


def test_bad_seeds_and_stages_are_user_errors_before_any_job(tmp_path):
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.config.scenario import ScenarioError

    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**tiny_scenario(),
                                                     "methods": [{"name": "H", "plugin": "handcrafted"}]}))
    scenario, resolved = load_scenario(tmp_path / "s.yaml")
    for seeds, force, message in (([1, 2, 1], [], r"--seeds: the value 1 is given more than once \(1, 1\)"),
                                  ([-1], [], "not a valid scenario seed"),
                                  ([1], ["fitt"], "unknown stage")):
        with pytest.raises(ScenarioError, match=message):
            sweep.seed_jobs(scenario, resolved, seeds, tmp_path / "out", force)


@pytest.mark.parametrize("seeds, message", [
    (["1", "1"], "--seeds: the value 1 is given more than once (1, 1)"),
    (["4294967296"], "--seeds: 4294967296 is not a valid scenario seed (0 <= seed < 4294967296)"),
])
def test_bad_seeds_are_refused_before_the_output_folder_is_made(tmp_path, monkeypatch, capsys, seeds, message):
    monkeypatch.chdir(tmp_path)
    scenario = {**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}
    Path("tiny.yaml").write_text(yaml.safe_dump(scenario))
    assert main(["-q", "sweep", "tiny.yaml", "--seeds", *seeds, "--out", "out", "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == f"vitaplace: error: {message}"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("given, expected", [
    (None, {"figures": "summary"}), ({"pdf": True}, {"figures": "summary", "pdf": True}),
    ({"figures": "all"}, {"figures": "all"}), ({"figures": "none", "pdf": False}, {"figures": "none", "pdf": False}),
])
def test_a_seed_s_report_draws_the_summary_unless_the_scenario_says(tmp_path, given, expected):
    from vitaplace.engine.config.loading import load_scenario

    data = {**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data if given is None else {**data, "report": given}))
    scenario, resolved = load_scenario(tmp_path / "s.yaml")
    jobs = sweep.seed_jobs(scenario, resolved, [1, 2], tmp_path / "out")
    assert [job.scenario["report"] for job in jobs] == [expected, expected]
    assert "report" not in resolved or resolved["report"] == given  # the driver's mapping is left as it was


def test_recorded_run_files_reach_jobs_as_absolute_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    resolved = {"train": {"dataset": "train.h5"},
                "evaluations": [{"name": "E1", "datasets": {"query": "q.h5", "reference": "/data/r.h5"}}]}
    fixed = sweep._absolute_files(resolved)
    assert fixed["train"]["dataset"] == str(tmp_path / "train.h5")
    assert fixed["evaluations"][0]["datasets"] == {"query": str(tmp_path / "q.h5"), "reference": "/data/r.h5"}
    assert resolved["train"]["dataset"] == "train.h5"  # the caller's mapping is left alone


def test_the_driver_warns_once_about_unshared_storage_and_reports_failures(tmp_path, monkeypatch, caplog):
    from vitaplace.engine.config.loading import load_scenario

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
    from vitaplace.engine.config.loading import load_scenario

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
    from vitaplace.engine.evaluation.evaluate import PRCurve

    r, p = np.asarray(recall, float), np.asarray(precision, float)
    f1 = np.where(p + r > 0, 2 * p * r / np.maximum(p + r, 1e-12), 0.0)
    z = np.zeros(len(r))
    return PRCurve(np.arange(len(r), dtype=float), p, r, f1, z, z, z, 10, 10)


def test_interpolated_precision_is_the_best_precision_at_or_beyond_each_recall():
    from vitaplace.engine.report.figures import interpolated_precision

    # points (recall, precision): (0.2, 1.0), (0.5, 0.8), (0.5, 0.9), (1.0, 0.5), in threshold order
    curve = _curve([0.5, 0.2, 1.0, 0.5], [0.8, 1.0, 0.5, 0.9])
    got = interpolated_precision(curve, np.array([0.0, 0.2, 0.3, 0.5, 0.6, 1.0]))
    np.testing.assert_allclose(got, [1.0, 1.0, 0.9, 0.9, 0.5, 0.5])
    short = _curve([0.1, 0.4], [1.0, 0.7])  # never reaches recall 0.5: precision 0 there
    np.testing.assert_allclose(interpolated_precision(short, np.array([0.4, 0.5])), [0.7, 0.0])


def test_pr_band_figures_are_written_per_environment_from_the_seed_folders(tmp_path):
    import dataclasses

    from vitaplace.engine.report.figures import write_pr_bands

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


@pytest.mark.slow  # the runner's cache and recovery, not a dependency's version
def test_a_seed_whose_worker_process_dies_fails_alone(tmp_path, plugin_env):
    """A worker killed mid-job breaks the process pool and the jobs beside it; those run again,
    each in its own pool: the dying seed fails in one line, the others finish."""
    from vitaplace.engine.pipeline.plan import seed_for

    data = tiny_scenario()
    data["methods"][0]["params"] = {"exit_for": seed_for(1, 1000)}
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    result = vitaplace(["sweep", str(path), "--seeds", "0", "1", "2", "--workers", "2", "--out", str(out),
                        "--no-progress"], plugin_env)
    assert result.returncode == 1, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if "seed 1 failed" in line]
    assert len(lines) == 1 and "worker process died" in lines[0] and "traceback in" not in lines[0], (
        result.stderr[-3000:])
    record = json.loads((out / "sweep.json").read_text())
    assert record["seeds"] == [0, 2] and list(record["failed"]) == ["1"]


# --------------------------------------------------------------------------- run folders that prove they are finished


def _rows(folder: Path, change) -> None:
    path = folder / "results.json"
    rows = json.loads(path.read_text())
    change(rows)
    path.write_text(json.dumps(rows))


CURVE = "evaluations/E1/O/query-to-reference/pr_curve.npz"
UNFINISHED = {
    "results edited after the run": (lambda f: _rows(f, lambda r: r[0].update(max_f1=0.5)), False,
                                     r"seed-copy: not a finished run: "
                                     r"results\.json is not the file its finished run recorded"),
    "a truncated PR curve": (lambda f: (f / CURVE).write_bytes((f / CURVE).read_bytes()[:50]), False,
                             rf"not a finished run: {CURVE} is not the file its finished run recorded"),
    "a truncated PR curve, recorded so": (lambda f: (f / CURVE).write_bytes((f / CURVE).read_bytes()[:50]), True,
                                          rf"{CURVE}: unreadable PR curve"),
    "no result rows": (lambda f: (f / "results.json").write_text("[]"), True,
                       r"results\.json: holds no result rows, expected a non-empty list"),
    "a metric as text": (lambda f: _rows(f, lambda r: r[0].update(auc="high")), True,
                         r"results\.json: row 0: field 'auc' is 'high', expected a finite number$"),
    "max F1 missing": (lambda f: _rows(f, lambda r: r[1].pop("max_f1")), True,
                       r"results\.json: row 1: field 'max_f1' is None, expected a finite number"),
    "recall@K as text": (lambda f: _rows(f, lambda r: r[0]["recall_at_k"].update({"5": "x"})), True,
                         r"results\.json: row 0: field 'recall_at_k\.5' is 'x', expected a finite number$"),
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
    """Finish seed 2, rerun it with another tau and kill the rerun once it has started replacing
    the results (`orchestrate.unfinish`; killed before, the folder is left finished as it was):
    the folder holds the old results beside the new resolved scenario, and no completion record."""
    from vitaplace.engine.config.scenario import Scenario
    from vitaplace.engine.outputs import outdir
    from vitaplace.engine.pipeline import orchestrate
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store

    out, _ = local_sweep
    folder = tmp_path / "seed-2"
    shutil.copytree(out / "seed-2", folder)
    record = (folder / outdir.COMPLETED).read_text()
    resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
    resolved["scoring"]["tau"] = 0.4

    def killed(store, scenario):  # as if killed once the rerun started replacing the results
        orchestrate.unfinish(folder, resolved)
        raise KeyboardInterrupt

    monkeypatch.setattr(orchestrate, "simulate", killed)
    with pytest.raises(KeyboardInterrupt):
        run_stages(Scenario.model_validate(resolved), resolved, Store(folder, cache=tmp_path / "cache"))
    assert (folder / "results.json").is_file() and (folder / "manifest.json").is_file()  # the old run's
    summary = tmp_path / "summary"
    assert main(["aggregate", str(out / "seed-0"), str(folder), "--out", str(summary)]) == 2
    line = capsys.readouterr().err.strip()
    assert line == f"vitaplace: error: {folder}: incomplete run folder (no {outdir.COMPLETED}); did its run finish?"
    # even with the old record put back, it does not match the new resolved scenario
    (folder / outdir.COMPLETED).write_text(record)
    assert main(["aggregate", str(out / "seed-0"), str(folder), "--out", str(summary)]) == 2
    assert "scenario.resolved.yaml is not the scenario its finished run recorded" in capsys.readouterr().err
    assert not summary.exists()


def test_aggregate_counts_the_seeds_that_contribute(local_sweep, tmp_path, capsys):
    out, _ = local_sweep
    assert main(["aggregate", str(out / "seed-0"), str(out / "seed-2"), "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out.startswith("summary of 2 seeds")
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert record["seeds"] == [0, 2] and {r["seed"] for r in record["runs"]} == {0, 2}


@pytest.mark.parametrize("text, minutes", [
    ("30", 30), ("1:30", 2), ("0:0:1", 1), ("2:00:00", 120), ("1-2", 26 * 60), ("1-2:30", 26 * 60 + 30),
    ("1-0:0:30", 24 * 60 + 1),  # a day and 30 s: rounded up to the next whole minute
])
def test_slurm_time_limits_by_hand(text, minutes):
    from vitaplace.engine.cli.slurm import parse_time

    assert parse_time(text) == minutes


def test_aggregate_out_that_cannot_be_written_is_one_line(local_sweep, tmp_path, capsys):
    """--out an existing file or a folder under one: one line naming it, before anything is written."""
    out, _ = local_sweep
    blocker = tmp_path / "file"
    blocker.write_text("")
    for target in (blocker, blocker / "sub"):
        assert main(["aggregate", str(out / "seed-0"), "--out", str(target)]) == 2
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in err and f"--out {target}" in lines[0], lines
    assert blocker.read_text() == ""


def test_a_sweeps_files_name_its_folder_relatively_and_still_read_after_a_move(tmp_path, monkeypatch):
    """No file of a sweep holds the absolute path of its output folder: the seed's resolved
    scenario names its environment copies from the seed folder, the manifest its cache files
    from there (../cache/...); after the folder moves, both still name existing files."""
    from vitaplace.engine.config.loading import load_scenario

    monkeypatch.chdir(tmp_path)
    scenario = {**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}
    Path("tiny.yaml").write_text(yaml.safe_dump(scenario))
    assert main(["-q", "sweep", "tiny.yaml", "--seeds", "0", "--workers", "1", "--out", "out", "--no-progress"]) == 0
    absolute = str(tmp_path / "out").encode()
    holding = [str(p) for p in (tmp_path / "out").rglob("*") if p.is_file() and absolute in p.read_bytes()]
    assert holding == []
    (tmp_path / "out").rename(tmp_path / "moved")
    seed = tmp_path / "moved" / "seed-0"
    resolved = yaml.safe_load((seed / "scenario.resolved.yaml").read_text())
    assert resolved["train"]["environment"] == "environments/e1.yaml"
    scenario, _ = load_scenario(seed / "scenario.resolved.yaml")
    assert scenario.train.environment == seed / "environments" / "e1.yaml"
    outputs = [stage["output"] for stage in json.loads((seed / "manifest.json").read_text())["stages"]]
    assert "../cache/datasets" in "\n".join(outputs)
    assert outputs and all((seed / output).exists() for output in outputs), outputs


def test_a_sweep_run_again_removes_the_sensitivity_of_the_sweep_before(tmp_path, monkeypatch):
    """`vitaplace sensitivity` of a sweep rescored its seeds' evaluations as they were: a sweep
    that writes its summary again into the folder (here another scenario's, over the same seed)
    removes those files rather than leave them beside a summary they do not describe."""
    monkeypatch.chdir(tmp_path)
    scenario = {**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}
    Path("tiny.yaml").write_text(yaml.safe_dump(scenario))
    assert main(["-q", "sweep", "tiny.yaml", "--seeds", "0", "--workers", "1", "--out", "out", "--no-progress"]) == 0
    assert main(["-q", "sensitivity", "out", "--tau", "0.4"]) == 0
    assert sorted(p.name for p in Path("out").glob("sensitivity.*")) == ["sensitivity.csv", "sensitivity.json",
                                                                        "sensitivity.md"]
    Path("other.yaml").write_text(yaml.safe_dump({**scenario, "name": "other"}))
    assert main(["-q", "sweep", "other.yaml", "--seeds", "0", "--workers", "1", "--out", "out", "--no-progress"]) == 0
    assert list(Path("out").glob("sensitivity.*")) == []
    assert "other" in Path("out/sweep.md").read_text().splitlines()[0]
